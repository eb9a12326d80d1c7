"""The MuJoCo backend's measured joint torques (issue 28): the arm actuators' forces, gravity
compensation included, checked for sign and units against gravity and a known push; a fixed
scene object the arm can run into.

Tolerances. At rest MuJoCo's gravity compensation equals Pinocchio's g(q) to rounding (both use
the URDF's inertias; measured 4e-15 N·m). Under a push the arm yields to the servo's stiffness
and rings down; a reading counts once the arm is settled (< 2e-3 rad/s), when what is left of
the ringing (inertia and servo damping) measured 6e-3 N·m against −Jᵀ F: 0.05 N·m leaves room
for a loaded machine's coarser sampling and stays far below the 1.7–5 N·m the push exerts.
"""

from __future__ import annotations

import time

import anyio
import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import pytest

import armwarden.backends.mujoco  # noqa: F401 - chooses the offscreen GL platform before mujoco loads

pytest.importorskip("mujoco")

from armwarden.backends.mujoco.backend import MujocoBackend, create_backend
from armwarden.backends.mujoco.config import Config, ObjectConfig
from armwarden.backends.servo import Setpoint, segment_velocity
from armwarden.planning.timing import time_parameterize
from armwarden.policy import load_policy
from armwarden.policy.loading import bundled_policy
from armwarden.robot import build_robot
from tests.backends.contract import straight_line
from tests.backends.joint_torque_conformance import (
    Load,
    check_gravity_at_rest,
    check_push,
    gravity,
    push_torque,
    settled_state,
)
from tests.helpers import run_opened

POLICY = load_policy(bundled_policy("fr3"))
ROBOT = build_robot(POLICY)
#: see the module docstring
TOLERANCE_NM = 0.05


def run(scenario, **config):
    return run_opened(lambda: create_backend(ROBOT, POLICY, Config(**config)), scenario)


def test_a_still_simulated_arm_measures_the_gravity_of_its_pose() -> None:
    async def scenario(backend: MujocoBackend) -> None:
        assert backend.capabilities.joint_torques
        await check_gravity_at_rest(backend, ROBOT, TOLERANCE_NM)

    run(scenario)


def test_a_push_on_the_simulated_forearm_changes_its_torques_by_minus_j_transpose_f() -> None:
    async def scenario(backend: MujocoBackend) -> None:
        force, point = (0.0, 30.0, -10.0), (0.05, 0.0, 0.1)
        load = Load("fr3_link4", force, point_in_frame=point, release=backend.release_push,
                    apply=lambda: backend.push("fr3_link4", force, point))
        await check_push(backend, ROBOT, load, TOLERANCE_NM)

    run(scenario)


def test_the_simulation_reports_the_true_external_torque_of_a_push() -> None:
    """The ground truth an observer is judged against: J^T F of the push, and at rest the
    measured torques plus it are the gravity of the pose."""
    async def scenario(backend: MujocoBackend) -> None:
        force, point = (10.0, -20.0, 5.0), (0.0, 0.05, 0.05)
        load = Load("fr3_link6", force, apply=lambda: None, release=lambda: None, point_in_frame=point)
        assert not backend.arm.measured.external_efforts.any()
        backend.push("fr3_link6", force, point)
        state = await settled_state(backend, after_stamp=time.monotonic())
        sample = backend.arm.measured
        assert state.efforts is not None
        np.testing.assert_allclose(sample.external_efforts, -push_torque(ROBOT, sample.positions, load),
                                   rtol=0, atol=TOLERANCE_NM)
        np.testing.assert_allclose(sample.efforts + sample.external_efforts, gravity(ROBOT, sample.positions),
                                   rtol=0, atol=TOLERANCE_NM)

    run(scenario)


@pytest.mark.parametrize("stop", [False, True], ids=["completed", "braked"])
def test_a_momentum_observer_fed_the_simulated_motion_sees_little_external_torque(stop: bool) -> None:
    """The torques belong to the motion: dp/dt = τ + Cᵀq̇ − g, p = M(q)q̇, with the model's rotor
    inertia (MuJoCo's armature) in M, through a whole motion or one braked halfway (the brake
    saturates joints 1–4 at their torque limits). The physics is stepped here, in the test's
    thread. Measured at gain 50 s⁻¹: 0.22 N·m peak, braked or not (the fingers' own dynamics,
    discretisation); before the implicit integrator's damping share was counted, 1.4 N·m moving
    and 4.6 N·m braked."""
    backend = create_backend(ROBOT, POLICY, Config())
    arm = backend.arm
    home = np.asarray(POLICY.robot.home_joint_positions, dtype=float)
    goal = home + np.array([0.6, 0.4, 0.0, 0.4, 0.0, 0.0, 0.6])
    trajectory = time_parameterize(ROBOT.joint_names, np.array([home, goal]), np.full(7, 1.0), np.full(7, 3.0))
    stop_s = trajectory.duration_s / 2 if stop else np.inf
    model = pin.Model(ROBOT.model)
    model.armature = arm.model.dof_armature[backend.sim.arm_dofs].copy()
    data = model.createData()
    gain, dt = 50.0, arm.timestep_s
    residual, integral, peak = np.zeros(7), np.zeros(7), 0.0
    start, last_s = None, arm.measured.sim_s
    arm.start(0.0)
    for k in range(1, round((trajectory.duration_s + 0.2) / dt)):
        t = k * dt
        if t < stop_s:
            setpoint = Setpoint(trajectory.sample(t), segment_velocity(trajectory, t), t, following=t < trajectory.duration_s)
            arm.command(setpoint)
        else:
            setpoint = Setpoint(arm.measured.positions, np.zeros(7), t)
            if not arm.target.braking and k * dt - stop_s < dt:
                arm.brake(setpoint)
        arm.step(setpoint, t, 1.0)
        sample = arm.measured
        if sample.sim_s == last_s:
            continue  # rounding left this tick without a physics step: no new sample
        h, last_s = sample.sim_s - last_s, sample.sim_s
        q, v = sample.positions, sample.velocities
        mass = pin.crba(model, data, q)
        momentum = (np.triu(mass) + np.triu(mass, 1).T) @ v
        if start is None:  # the torques of the step before this sample are not the observer's
            start = momentum
            continue
        coriolis = pin.computeCoriolisMatrix(model, data, q, v)
        integral += (sample.efforts + coriolis.T @ v - pin.computeGeneralizedGravity(model, data, q) + residual) * h
        residual = gain * (momentum - start - integral)
        peak = max(peak, float(np.abs(residual).max()))
    assert arm.tracking_peak_rad < 0.05 and peak < 0.6


def test_a_released_push_leaves_no_force_on_the_arm() -> None:
    async def scenario(backend: MujocoBackend) -> None:
        link = backend.sim.model.body("fr3_link5").id
        backend.push("fr3_link5", (15.0, 0.0, 0.0))
        await _until(lambda: bool(backend.arm.data.xfrc_applied[link].any()))
        backend.release_push()
        await _until(lambda: not backend.arm.data.xfrc_applied[link].any())

    run(scenario)


def test_a_push_on_an_unknown_body_or_with_a_non_finite_force_is_refused() -> None:
    backend = create_backend(ROBOT, POLICY, Config())
    with pytest.raises(ValueError, match="no body"):
        backend.push("no_such_link", (0.0, 0.0, 1.0))
    with pytest.raises(ValueError, match="finite"):
        backend.push("fr3_link4", (0.0, float("inf"), 1.0))
    assert backend.arm.push is None


def test_every_published_state_carries_finite_efforts_of_its_own_sample_while_moving() -> None:
    """Mid-motion the efforts change with the motion and come with each sample's own stamp."""
    home = np.asarray(POLICY.robot.home_joint_positions, dtype=float)
    goal = home + np.array([0.3, 0.2, 0.0, 0.2, 0.0, 0.0, 0.0])

    async def scenario(backend: MujocoBackend) -> None:
        seen: dict[float, np.ndarray] = {}

        async def watch() -> None:
            while True:
                state = await backend.read_joint_state()
                sample = backend.arm.measured
                if sample.stamp == state.stamp:  # the same sample: its efforts, not another's
                    assert state.efforts is sample.efforts
                assert state.efforts is not None and np.all(np.isfinite(state.efforts))
                seen[state.stamp] = state.efforts
                await anyio.sleep(0.002)

        async with anyio.create_task_group() as group:
            group.start_soon(watch)
            result = await backend.execute(straight_line(ROBOT.joint_names, home, goal, 1.0))
            group.cancel_scope.cancel()
            assert result.completed
        assert len({tuple(e.tolist()) for e in seen.values()}) > 10

    run(scenario, speedup=2.0)


def test_a_fixed_object_stays_where_it_is_put_while_a_loose_one_falls() -> None:
    """A box the policy does not know can be put in the arm's path: welded, not free."""
    objects = [ObjectConfig(name=name, shape="box", position_m=(0.3, y, 0.6), size_m=(0.1, 0.1, 0.1), mass_kg=1.0,
                            fixed=name == "wall") for name, y in (("wall", -0.6), ("loose", 0.6))]

    async def scenario(backend: MujocoBackend) -> None:
        model = backend.sim.model
        wall, loose = model.body("wall").id, model.body("loose").id
        assert model.body_jntnum[wall] == 0 and model.body_jntnum[loose] == 1
        start = backend.arm.measured.sim_s
        await _until(lambda: backend.arm.measured.sim_s > start + 0.2)
        data = backend.arm.data
        np.testing.assert_allclose(data.xpos[wall], model.body_pos[wall], atol=1e-12)
        assert data.xpos[loose][2] < model.body_pos[loose][2] - 0.1

    run(scenario, objects=objects)


def test_the_object_config_is_loose_unless_fixed() -> None:
    box = ObjectConfig(name="box", shape="box", position_m=(0.5, 0.0, 0.05), size_m=(0.1, 0.1, 0.1), mass_kg=1.0)
    assert not box.fixed and not box.spec().fixed
    assert ObjectConfig.model_validate(box.model_dump() | {"fixed": True}).spec().fixed


async def _until(condition, timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "condition not reached in time"
        await anyio.sleep(0.002)
