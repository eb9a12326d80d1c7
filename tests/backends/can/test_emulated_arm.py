"""The CAN emulator's arm moved by the robot model's dynamics (issue 28, item 4).

Under `simulate.dynamics: robot_model` the arm's actuators move one body (Pinocchio ABA of the
policy's robot model, with rotor inertia, friction, a seeded mass error and torque noise), so the
torques they report are the arm's: an arm held at rest with the gravity feed-forward reads g(q),
and a push of 30 N at the forearm changes its readings by −Jᵀ F, through direction −1 joints too.

Tolerances: the conformance tests run with the model error and the noise off (the feed-forward is
the policy's model, and the emulated body must match it to be judged against it), so what is left
is the RobStride torque encoding (16 bits over ±120 N·m: 0.004 N·m) and what the damping of the
last motion leaves at rest: 0.05 N·m. The arm is judged still at the conformance's own 2 mrad/s, not
the backend's coarser `rest_speed_rad_s`: a joint still creeping at 0.01 rad/s reads kd·v off g(q)
(0.7 N·m on joint 2 at the example's kd 70), and the RobStride velocity encoding resolves 0.3 mrad/s.
The start tolerance is the backend's own.
"""

from __future__ import annotations

import time
from typing import Any

import anyio
import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import pytest

from armwarden.backends import parse_backend_config
from armwarden.backends.can.backend import CanBackend, create_backend
from armwarden.backends.can.config import Config
from armwarden.backends.can.emulated_actuator import ActuatorSpec
from armwarden.backends.can.emulated_arm import ArmDynamics
from armwarden.backends.can.emulator import ActuatorEmulator, ArmSetup
from armwarden.core.errors import ConfigurationError
from tests.backends.can.polling import unique_channel
from tests.backends.can.test_can_backend import POLICY, ROBOT, config_document
from tests.backends.contract import wait_until
from tests.backends.joint_torque_conformance import Load, check_gravity_at_rest, gravity, push_torque, settled_state
from tests.helpers import run_opened

TOLERANCE_NM = 0.05
FOREARM = "fr3_link4"


def exact_arm(**simulate: Any) -> CanBackend:
    """The example's emulated arm with the model error, friction and noise off (and `simulate` over
    it): Coulomb friction holds a creeping arm off g(q) by up to its size, which is the point of it
    elsewhere but not in a check of sign and units."""
    document = config_document()
    document["simulate"] |= {"mass_error": 0.0, "torque_noise_nm": 0.0} | simulate
    for load in document["simulate"]["loads"].values():
        load |= {"damping_nms_per_rad": 0.0, "coulomb_friction_nm": 0.0} if "coulomb_friction_nm" in load else {}
    config = parse_backend_config("can", document)
    assert isinstance(config, Config)
    return create_backend(ROBOT, POLICY, config)


async def rung_out(backend: CanBackend) -> None:
    """Until the emulated body is still: the hold's gains on the FR3's inertia ring lightly (joint 2:
    ζ ≈ 0.2 at about 3 Hz) after enabling, slower than the velocity encoding can show."""
    emulator = backend.emulator
    assert emulator is not None and emulator.arm is not None
    arm = emulator.arm

    async def still() -> bool:
        return float(np.abs(arm.v).max()) < 1e-4  # kp·(v/ω) ≈ 0.005 N·m of ringing left

    await wait_until(still, timeout_s=20.0)


def test_the_arm_at_rest_with_gravity_feedforward_holds_its_home_and_reads_gravity() -> None:
    async def scenario(backend: CanBackend) -> None:
        await rung_out(backend)
        state = await check_gravity_at_rest(backend, ROBOT, TOLERANCE_NM)
        home = np.asarray(POLICY.robot.home_joint_positions, dtype=float)
        assert np.abs(state.positions - home).max() < backend.start_tolerance_rad

    run_opened(exact_arm, scenario)


def test_a_30_n_push_at_the_forearm_changes_the_reported_torques_by_minus_jt_f() -> None:
    """Judged once the body is still under the push (its ringing gone), at the pose it yielded to."""
    async def scenario(backend: CanBackend) -> None:
        emulator = backend.emulator
        assert emulator is not None
        await rung_out(backend)
        before = await settled_state(backend)
        force = (30.0, 0.0, 0.0)
        load = Load(FOREARM, force, apply=lambda: emulator.push(FOREARM, force), release=emulator.release_push)
        load.apply()
        try:
            await anyio.sleep(0.05)  # the push has moved the body: wait for it to come to rest again
            await rung_out(backend)
            pushed = await settled_state(backend, after_stamp=time.monotonic())
            true_external = emulator.true_external_torques()
        finally:
            load.release()
        assert before.efforts is not None and pushed.efforts is not None
        expected = push_torque(ROBOT, pushed.positions, load)
        assert np.abs(expected).max() > 2.0
        change = (pushed.efforts - gravity(ROBOT, pushed.positions)) - (before.efforts - gravity(ROBOT, before.positions))
        np.testing.assert_allclose(change, expected, rtol=0, atol=TOLERANCE_NM)
        np.testing.assert_allclose(true_external, -expected, rtol=0, atol=TOLERANCE_NM)
        assert backend.config.joints[1].direction == -1 and abs(change[1]) > 1.0  # through a direction −1 joint

    run_opened(exact_arm, scenario)


def test_a_push_moves_a_limp_arm_the_way_the_force_points() -> None:
    """Damping only (kp = 0): the push accelerates the arm along Jᵀ F (its true τ_ext read back)."""
    model = ROBOT.model
    q0 = np.asarray(POLICY.robot.home_joint_positions, dtype=float)
    specs = [ActuatorSpec(i + 1, "RS04", initial_position_rad=float(q)) for i, q in enumerate(q0)]
    setup = ArmSetup(model, tuple(range(1, 8)), (1.0,) * 7, (0.0,) * 7,
                     ArmDynamics((0.1,) * 7, (0.0,) * 7, (0.0,) * 7, brakes=False))
    emulator = ActuatorEmulator(unique_channel(), specs, rate_hz=1000.0, arm=setup)
    arm = emulator.arm
    assert arm is not None
    arm.model.gravity.linear = np.zeros(3)  # weightless: only the push moves it
    for actuator in arm.actuators:
        actuator.set_enabled(True)  # brakes off; its command is all zeros: limp
    emulator.push(FOREARM, (0.0, 0.0, 30.0))
    arm.advance(arm.wall_time + 0.05)
    fid = model.getFrameId(FOREARM)
    data = model.createData()
    jacobian = pin.computeFrameJacobian(model, data, arm.q, fid, pin.LOCAL_WORLD_ALIGNED)
    np.testing.assert_allclose(emulator.true_external_torques(), jacobian[:3].T @ np.array([0.0, 0.0, 30.0]),
                               atol=0.01)  # applied at the step before
    pin.framesForwardKinematics(model, data, arm.q)
    moved = data.oMf[fid].translation.copy()
    pin.framesForwardKinematics(model, data, q0)
    assert (moved - data.oMf[fid].translation)[2] > 1e-4  # it moved up, where the force points
    emulator.release_push()
    assert not emulator.true_external_torques().any()


def noisy_arm(seed: int) -> tuple[ActuatorEmulator, list[float]]:
    q0 = np.asarray(POLICY.robot.home_joint_positions, dtype=float)
    specs = [ActuatorSpec(i + 1, "RS04", initial_position_rad=float(q)) for i, q in enumerate(q0)]
    setup = ArmSetup(ROBOT.model, tuple(range(1, 8)), (1.0,) * 7, (0.0,) * 7,
                     ArmDynamics((0.1,) * 7, (0.1,) * 7, (0.3,) * 7, torque_noise_nm=0.1, mass_error=0.03, seed=seed,
                                 brakes=False))
    emulator = ActuatorEmulator(unique_channel(), specs, rate_hz=1000.0, arm=setup)
    arm = emulator.arm
    assert arm is not None
    for actuator in arm.actuators:
        actuator.set_enabled(True)  # limp: the arm falls under gravity against friction
    arm.advance(arm.wall_time + 0.02)
    noise = [a.torque_noise for a in arm.actuators]
    return emulator, noise


def test_mass_error_friction_and_noise_are_seeded_and_reproducible() -> None:
    first, noise_a = noisy_arm(7)
    again, noise_b = noisy_arm(7)
    other, noise_c = noisy_arm(8)
    assert first.arm is not None and again.arm is not None and other.arm is not None
    masses = [[i.mass for i in e.arm.model.inertias] for e in (first, again, other)]  # type: ignore[union-attr]
    assert masses[0] == masses[1] and masses[0] != masses[2]
    assert masses[0] != [i.mass for i in ROBOT.model.inertias]  # the emulated body is not the observer's model
    assert noise_a == noise_b and noise_a != noise_c and any(noise_a)
    np.testing.assert_array_equal(first.arm.q, again.arm.q)
    np.testing.assert_array_equal(first.arm.model.armature, np.full(7, 0.1))


def test_a_per_actuator_gravity_load_is_refused_under_robot_model_dynamics() -> None:
    """The robot model has the gravity: a 1-DOF gravity load on an arm joint would count it twice."""
    document = config_document()
    document["simulate"]["loads"]["fr3_joint2"]["gravity_torque_nm"] = 5.0
    with pytest.raises(ConfigurationError, match="gravity_torque_nm of fr3_joint2 must be 0 under dynamics robot_model"):
        parse_backend_config("can", document)


def test_an_undeclared_payload_weighs_on_the_emulated_arm_only() -> None:
    q0 = np.asarray(POLICY.robot.home_joint_positions, dtype=float)
    specs = [ActuatorSpec(i + 1, "RS04", initial_position_rad=float(q)) for i, q in enumerate(q0)]

    def gravity_with(payload_kg: float) -> np.ndarray:
        dynamics = ArmDynamics((0.1,) * 7, (0.0,) * 7, (0.0,) * 7, payload_kg=payload_kg, payload_frame=ROBOT.tcp_frame)
        emulator = ActuatorEmulator(unique_channel(), specs, arm=ArmSetup(ROBOT.model, tuple(range(1, 8)), (1.0,) * 7,
                                                                          (0.0,) * 7, dynamics))
        assert emulator.arm is not None
        return emulator.arm.gravity()

    masses = [i.mass for i in ROBOT.model.inertias]
    extra = gravity_with(1.0) - gravity_with(0.0)
    assert np.abs(extra).max() > 1.0  # 1 kg at the TCP of the FR3 at home: several N·m on joints 2 and 4
    assert [i.mass for i in ROBOT.model.inertias] == masses  # the policy's (the observer's) model untouched
