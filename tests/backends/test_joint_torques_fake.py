"""The fake backend's measured joint torques: the model's own inverse dynamics of the commanded
motion, a test's push, noise and fault injections (issue 28).

The fake computes with the same robot model as the test, so its conformance tolerance is
numerical (1e-9 N·m): any larger difference is a wiring error (sign, frame, joint order).
"""

from __future__ import annotations

import time

import anyio
import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import pytest

from armwarden.backends.fake.backend import FakeBackend
from armwarden.backends.fake.config import Config
from armwarden.backends.servo import Setpoint, SpreadMotion, segment_velocity, spread_motion
from armwarden.core.errors import BackendError
from armwarden.core.state import JointState
from armwarden.core.trajectory import JointTrajectory
from armwarden.robot.model import RobotModel
from tests.backends.joint_torque_conformance import Load, check_gravity_at_rest, check_push, gravity, settled_state
from tests.backends.test_fake import FR3_JOINT_NAMES, Q_REACH, Q_READY, straight_line
from tests.helpers import run_opened

#: the fake's model is the test's: only rounding separates them
NUMERICAL_NM = 1e-9


@pytest.fixture(scope="module")
def fr3() -> RobotModel:
    return RobotModel.from_description("builtin:fr3", FR3_JOINT_NAMES, "fr3_link0", "fr3_hand_tcp")


def run(scenario, **options):
    return run_opened(lambda: FakeBackend(**options), scenario)


def test_a_still_fake_arm_measures_the_gravity_of_its_pose(fr3: RobotModel) -> None:
    async def scenario(backend: FakeBackend) -> None:
        state = await check_gravity_at_rest(backend, fr3, NUMERICAL_NM)
        assert state.positions.tolist() == Q_READY.tolist()

    run(scenario)


def test_a_push_on_the_forearm_changes_the_fake_torques_by_minus_j_transpose_f(fr3: RobotModel) -> None:
    async def scenario(backend: FakeBackend) -> None:
        force, point = (0.0, 30.0, -10.0), (0.05, 0.0, 0.1)
        load = Load("fr3_link4", force, point_in_frame=point, release=backend.release_push,
                    apply=lambda: backend.push("fr3_link4", force, point))
        await check_push(backend, fr3, load, NUMERICAL_NM)

    run(scenario)


def test_a_push_at_a_point_off_the_frame_origin_adds_its_lever(fr3: RobotModel) -> None:
    """The same force at a point 17 cm from the frame's origin: the torque differs by the lever's moment."""
    async def scenario(backend: FakeBackend) -> None:
        backend.push("fr3_link5", (20.0, 0.0, 0.0))
        at_origin = await settled_state(backend, after_stamp=_now())
        backend.push("fr3_link5", (20.0, 0.0, 0.0), (0.1, 0.1, 0.1))
        off_origin = await settled_state(backend, after_stamp=_now())
        assert at_origin.efforts is not None and off_origin.efforts is not None
        assert np.abs(off_origin.efforts - at_origin.efforts).max() > 0.5

    run(scenario)


def test_the_fake_measures_the_inverse_dynamics_of_the_commanded_motion(fr3: RobotModel) -> None:
    """Mid-motion, every published sample reads rnea(q, q̇, q̈) of its own setpoint's spread
    motion, and that motion's velocity."""
    trajectory = straight_line(Q_READY, Q_REACH, 1.0, dt_s=0.25)  # q̈ ≠ 0 in the first and last 0.125 s

    async def scenario(backend: FakeBackend) -> None:
        data = fr3.model.createData()
        checked = accelerating = 0  # samples checked, and those of them with q̈ ≠ 0

        async def watch() -> None:
            nonlocal checked, accelerating
            while True:
                setpoint = backend.servo.latest
                state = await backend.read_joint_state()
                spread = setpoint.spread
                if setpoint.following and state.stamp == setpoint.stamp and spread is not None:
                    expected = pin.rnea(fr3.model, data, setpoint.positions, spread.velocities, spread.accelerations)
                    assert state.efforts is not None
                    np.testing.assert_allclose(state.efforts, expected, rtol=0, atol=NUMERICAL_NM)
                    assert state.velocities is spread.velocities
                    checked += 1
                    accelerating += bool(spread.accelerations.any())
                await _sleep()

        async with anyio.create_task_group() as group:
            group.start_soon(watch)
            result = await backend.execute(trajectory)
            group.cancel_scope.cancel()
            assert result.completed
        assert checked > 0 and accelerating > 0
        final = await settled_state(backend)
        assert final.efforts is not None
        np.testing.assert_allclose(final.efforts, gravity(fr3, Q_REACH), rtol=0, atol=NUMERICAL_NM)

    run(scenario)


def test_a_stopped_fake_arm_reads_the_gravity_of_its_pose_from_the_hold_on(fr3: RobotModel) -> None:
    trajectory = straight_line(Q_READY, Q_REACH, 4.0)

    async def scenario(backend: FakeBackend) -> None:
        state: JointState | None = None
        async with anyio.create_task_group() as group:
            group.start_soon(backend.execute, trajectory)
            while not (backend.servo.latest.following and backend.servo.latest.velocities.any()):
                await _sleep()
            await backend.stop()
            state = await backend.read_joint_state()
        assert state is not None and state.efforts is not None and not state.velocities.any()
        np.testing.assert_allclose(state.efforts, gravity(fr3, state.positions), rtol=0, atol=NUMERICAL_NM)

    run(scenario)


def test_spread_motion_ramps_between_segment_midpoints_from_rest_to_rest() -> None:
    trajectory = JointTrajectory(("a",), np.array([0.0, 1.0, 2.0]), np.array([[0.0], [1.0], [3.0]]))
    # from rest to 1 rad/s by the first midpoint (0.5 s), to 2 rad/s by the second (1.5 s), to rest at 2 s
    assert _motion(spread_motion(trajectory, 0.25)) == (0.5, 2.0)
    assert _motion(spread_motion(trajectory, 1.0)) == (1.5, 1.0)
    assert _motion(spread_motion(trajectory, 1.75)) == (1.0, -4.0)
    assert _motion(spread_motion(trajectory, 2.0)) == (0.0, 0.0)
    # the acceleration integrates to the velocity, which meets each segment's at its midpoint
    times = np.linspace(0.0, 1.5, 15001)
    integrated = np.trapezoid([spread_motion(trajectory, t).accelerations[0] for t in times], times)
    assert integrated == pytest.approx(segment_velocity(trajectory, 1.25)[0], abs=1e-3)


def test_a_momentum_observer_fed_the_fakes_motion_and_torques_sees_no_external_torque(fr3: RobotModel) -> None:
    """dp/dt = τ + Cᵀq̇ − g with p = M(q)q̇: the published velocity and torque agree, so an observer
    (gain 50 s⁻¹, every 1 ms sample) reads near zero. With the linear segments' own velocity the
    momentum jumps at each waypoint with no torque behind it (4–5 N·m on joints 1–3 here)."""
    from armwarden.planning.timing import time_parameterize

    trajectory = time_parameterize(FR3_JOINT_NAMES, np.array([Q_READY, 2 * Q_REACH - Q_READY]),
                                   np.full(7, 1.0), np.full(7, 3.0))
    torques = FakeBackend().joint_torques
    assert torques is not None
    model, data = fr3.model, fr3.model.createData()
    gain, dt = 50.0, 0.001
    residual, integral, start, peak = np.zeros(7), np.zeros(7), None, 0.0
    for t in np.arange(0.0, trajectory.duration_s + 0.1, dt):
        q, spread = trajectory.sample(t), spread_motion(trajectory, t)
        tau = torques.compute(Setpoint(q, segment_velocity(trajectory, t), 0.0, following=True, spread=spread)).moving
        mass = pin.crba(model, data, q)
        mass = np.triu(mass) + np.triu(mass, 1).T
        coriolis = pin.computeCoriolisMatrix(model, data, q, spread.velocities)
        momentum = mass @ spread.velocities
        start = momentum if start is None else start
        integral += (tau + coriolis.T @ spread.velocities - pin.computeGeneralizedGravity(model, data, q) + residual) * dt
        residual = gain * (momentum - start - integral)
        peak = max(peak, float(np.abs(residual).max()))
    assert peak < 0.2  # the discretisation at 1 kHz: measured 0.05 N·m


def test_fake_torque_noise_is_seeded_and_has_the_asked_spread(fr3: RobotModel) -> None:
    def samples(seed: int) -> np.ndarray:
        backend = FakeBackend(joint_torque_noise_nm=0.5, joint_torque_noise_seed=seed)
        setpoint = backend.servo.latest
        return np.array([backend.joint_torques.compute(setpoint).still for _ in range(400)])  # type: ignore[union-attr]

    first, again, other = samples(1), samples(1), samples(2)
    assert np.array_equal(first, again) and not np.array_equal(first, other)
    deviation = first - gravity(fr3, Q_READY)
    assert abs(float(deviation.mean())) < 0.1 and 0.4 < float(deviation.std()) < 0.6


def test_a_fake_without_joint_torques_publishes_none_and_refuses_a_push() -> None:
    async def scenario(backend: FakeBackend) -> None:
        assert not backend.capabilities.joint_torques
        assert (await backend.read_joint_state()).efforts is None
        with pytest.raises(BackendError, match="no joint torques"):
            backend.push("fr3_link4", (0.0, 10.0, 0.0))

    run(scenario, joint_torques=False)


def test_nan_joint_torques_are_published_as_nan_with_the_sample_stamp() -> None:
    async def scenario(backend: FakeBackend) -> None:
        before = await backend.read_joint_state()
        backend.nan_joint_torques = True
        state = await _state_after(backend, _now())
        assert state.efforts is not None and np.all(np.isnan(state.efforts))
        # the rest of the sample is as it was: finite positions, a fresh stamp of its own
        assert state.positions.tolist() == before.positions.tolist() and state.stamp > before.stamp

    run(scenario)


def test_frozen_joint_torques_repeat_while_the_arm_moves_on() -> None:
    async def scenario(backend: FakeBackend) -> None:
        stuck = (await settled_state(backend)).efforts
        backend.freeze_joint_torques = True
        result = await backend.execute(straight_line(Q_READY, Q_REACH, 0.3))
        state = await _state_after(backend, _now())
        assert result.completed and state.efforts is not None and stuck is not None
        assert state.positions.tolist() == Q_REACH.tolist()
        assert state.efforts.tolist() == stuck.tolist()

    run(scenario)


def test_a_push_on_an_unknown_frame_or_with_a_non_finite_force_is_refused() -> None:
    backend = FakeBackend()
    with pytest.raises(Exception, match="unknown frame"):
        backend.push("no_such_link", (0.0, 0.0, 1.0))
    with pytest.raises(ValueError, match="finite"):
        backend.push("fr3_link4", (0.0, float("nan"), 1.0))
    assert backend.joint_torques is not None and backend.joint_torques.push is None


def test_the_fake_config_switches_joint_torques_and_their_noise() -> None:
    assert Config().joint_torques and Config().joint_torque_noise_nm == 0.0
    with pytest.raises(ValueError):
        Config(joint_torque_noise_nm=-1.0)


def _motion(motion: SpreadMotion) -> tuple[float, float]:
    return float(motion.velocities[0]), float(motion.accelerations[0])


def _now() -> float:
    return time.monotonic()


async def _sleep() -> None:
    await anyio.sleep(0.001)


async def _state_after(backend: FakeBackend, stamp: float) -> JointState:
    deadline = time.monotonic() + 10.0
    while True:
        state = await backend.read_joint_state()
        if state.stamp > stamp:
            return state
        assert time.monotonic() < deadline, "no new sample"
        await _sleep()


def test_a_sped_up_fake_whose_thread_stalls_mid_motion_leaves_the_observer_nothing_to_skip(fr3: RobotModel) -> None:
    """At speedup 10 a 30 ms stall of the servo thread is 0.3 s of the arm's motion: the observer
    skips an interval that long and fails closed after 0.1 s of them (review finding F1). The fake
    arm moved on meanwhile, and its history holds every control period of it."""
    from armwarden.safety.contact_source import JointTorqueContact
    from tests.safety.test_joint_torque_monitor import mon_observer

    async def scenario(backend: FakeBackend) -> tuple[int, float, bool]:
        kinematics = backend._compute_tcp
        stalls = 0

        def stalling(q: np.ndarray) -> np.ndarray:
            nonlocal stalls
            if backend.servo.busy and stalls == 0 and backend.servo.latest.following:
                stalls += 1
                time.sleep(0.03)
            return kinematics(q)

        backend._compute_tcp = stalling  # type: ignore[method-assign]
        contact = JointTorqueContact(backend.read_joint_states_since, mon_observer(fr3), FR3_JOINT_NAMES,
                                     time_scale=backend.speedup, max_unobserved_s=0.1)
        await contact.read()
        finite = True
        async with anyio.create_task_group() as group:
            done = anyio.Event()

            async def move() -> None:
                await backend.execute(straight_line(Q_READY, Q_REACH, duration_s=2.0))
                done.set()

            group.start_soon(move)
            while not done.is_set():
                estimate = await contact.read()
                finite = finite and estimate is not None and bool(np.all(np.isfinite(estimate.force)))
                await anyio.sleep(0.005)
        return stalls, contact.unobserved_s, finite

    stalls, unobserved_s, finite = run(scenario, speedup=10.0)
    assert stalls == 1 and unobserved_s == 0.0 and finite
