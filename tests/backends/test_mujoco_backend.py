"""The MuJoCo backend: the backend contract on real physics, measured state, stops that hold the
arm where it is measured, and a wrench that reads only what the environment does to the hand."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

import armwarden.backends.mujoco  # noqa: F401 - chooses the offscreen GL platform before mujoco loads

pytest.importorskip("mujoco")

from pydantic import ValidationError

from armwarden.backends.base import Backend
from armwarden.backends.mujoco.backend import Config, MujocoBackend, create_backend
from armwarden.policy import load_policy
from armwarden.policy.loading import bundled_policy
from armwarden.robot import build_robot
from tests.backends.contract import BackendContract, straight_line

POLICY = load_policy(bundled_policy("fr3"))
ROBOT = build_robot(POLICY)


def build(**config) -> MujocoBackend:
    return create_backend(ROBOT, POLICY, Config(**config))


def run_with_backend(scenario, **config):
    """Open a MuJoCo backend, run `scenario(backend)` on a fresh event loop, always close it."""

    async def main():
        backend = build(**config)
        await backend.open()
        try:
            return await scenario(backend)
        finally:
            await backend.close()

    return asyncio.run(main())


class TestMujocoContract(BackendContract):
    #: what the position servos reach when the trajectory's time is up (measured: about 1.2 mrad)
    goal_tolerance_rad = 2e-3

    def build(self) -> Backend:
        return build()


# ---------------------------------------------------------------------------- config
def test_config_refuses_unknown_keys_and_non_finite_numbers():
    with pytest.raises(ValidationError, match="extra"):
        Config.model_validate({"timestep": 0.001})
    with pytest.raises(ValidationError, match="finite"):
        Config.model_validate({"table_top_z_m": float("nan")})


def test_config_table_height_moves_the_table():
    backend = build(table_top_z_m=0.1)
    table = backend.cell.model.geom("table")
    top = backend.cell.model.geom_pos[table.id][2] + backend.cell.model.geom_size[table.id][2]
    assert top == pytest.approx(0.1)


# ---------------------------------------------------------------------------- state
def test_published_state_is_the_measured_one_and_lags_the_command_while_moving():
    async def scenario(backend: MujocoBackend):
        q_start = (await backend.read_joint_state()).positions.copy()
        trajectory = straight_line(backend.joint_names, q_start, q_start + 0.3, 1.0)
        task = asyncio.create_task(backend.execute(trajectory))
        await asyncio.sleep(0.5)
        state = await backend.read_joint_state()
        commanded = backend.servo.latest.positions.copy()
        await task
        return state, commanded

    state, commanded = run_with_backend(scenario)
    assert np.all(np.abs(state.velocities) > 0.1)  # really moving, at about 0.3 rad/s
    assert not np.array_equal(state.positions, commanded)
    assert np.max(np.abs(state.positions - commanded)) < 0.05


def test_execute_returns_completed_once_the_arm_has_settled_at_the_goal():
    async def scenario(backend: MujocoBackend):
        q_start = (await backend.read_joint_state()).positions.copy()
        trajectory = straight_line(backend.joint_names, q_start, q_start + 0.2, 0.3)
        result = await backend.execute(trajectory)
        return trajectory.goal, result, await backend.read_joint_state()

    goal, result, after = run_with_backend(scenario)
    assert result.completed
    np.testing.assert_allclose(result.final_positions, goal, rtol=0, atol=1e-3)
    np.testing.assert_allclose(after.positions, goal, rtol=0, atol=1e-3)
    assert np.max(np.abs(after.velocities)) <= 1e-3


def test_a_stop_while_the_arm_settles_ends_the_execution_stopped():
    async def scenario(backend: MujocoBackend):
        q_start = (await backend.read_joint_state()).positions.copy()
        task = asyncio.create_task(backend.execute(straight_line(backend.joint_names, q_start, q_start + 0.2, 0.2)))
        while backend.servo.latest.positions.tolist() != (q_start + 0.2).tolist():  # noqa: ASYNC110 - polls the servo
            await asyncio.sleep(0.001)  # the trajectory's time is up: the goal is commanded, the arm catches up
        await backend.stop()
        return await task

    assert run_with_backend(scenario).reason == "stopped"


# ---------------------------------------------------------------------------- stop
def test_a_stop_holds_the_arm_where_it_was_measured_not_where_it_was_commanded():
    async def scenario(backend: MujocoBackend):
        q_start = (await backend.read_joint_state()).positions.copy()
        task = asyncio.create_task(backend.execute(straight_line(backend.joint_names, q_start, q_start + 0.4, 1.0)))
        await asyncio.sleep(0.5)
        measured = (await backend.read_joint_state()).positions.copy()  # no await between this and the stop
        backend.stop_now()
        target = backend._target[0].copy()
        result = await task
        await asyncio.sleep(0.3)
        return measured, target, result, await backend.read_joint_state()

    measured, target, result, later = run_with_backend(scenario)
    assert result.reason == "stopped"
    np.testing.assert_allclose(target, measured, rtol=0, atol=5e-3)  # at most a few physics steps apart
    np.testing.assert_array_equal(result.final_positions, target)
    # the arm decelerates and comes to rest near the hold, without springing back to the command
    assert np.max(np.abs(later.velocities)) < 1e-2
    np.testing.assert_allclose(later.positions, target, rtol=0, atol=2e-2)


# ---------------------------------------------------------------------------- wrench
def test_the_hand_weight_is_compensated_in_any_pose():
    async def scenario(backend: MujocoBackend):
        at_home = await backend.read_wrench()
        q_start = (await backend.read_joint_state()).positions.copy()
        tilted = q_start + np.array([0.0, 0.0, 0.0, 0.0, 0.5, -0.6, 0.4])
        assert (await backend.execute(straight_line(backend.joint_names, q_start, tilted, 0.5))).completed
        await asyncio.sleep(0.3)
        return at_home, await backend.read_wrench()

    for wrench in run_with_backend(scenario, speedup=2.0):
        assert wrench is not None
        assert wrench.force_norm_n < 0.05 and wrench.torque_norm_nm < 0.01


def test_pressing_the_hand_into_the_table_reads_an_upward_force():
    # the table top 2 cm under the TCP at home; joint 4 unbent lowers the hand into it
    table_z = float(ROBOT.tcp_pose(np.asarray(POLICY.robot.home_joint_positions)).position[2]) - 0.02

    async def scenario(backend: MujocoBackend):
        q_start = (await backend.read_joint_state()).positions.copy()
        q_down = q_start.copy()
        q_down[3] -= 0.15
        q_down[5] += 0.15
        await backend.execute(straight_line(backend.joint_names, q_start, q_down, 1.0))
        await asyncio.sleep(0.2)
        return await backend.read_wrench()

    wrench = run_with_backend(scenario, table_top_z_m=table_z, speedup=2.0)
    assert wrench is not None
    assert wrench.force[2] > 5.0  # the table pushes the hand up (friction adds a sideways part)
