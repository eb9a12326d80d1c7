"""The MuJoCo backend: the backend contract on real physics, measured state, stops that hold the
arm where it is measured, a wrench that reads only what the environment does to the hand, and
fingers that hold an object by contact and friction."""

from __future__ import annotations

import asyncio
import io
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

import armwarden.backends.mujoco  # noqa: F401 - chooses the offscreen GL platform before mujoco loads

pytest.importorskip("mujoco")

from PIL import Image
from pydantic import ValidationError

from armwarden.backends.base import Backend
from armwarden.backends.mujoco.backend import HOLD_ACCURACY_RAD, MujocoBackend, create_backend
from armwarden.backends.mujoco.config import Config, ObjectConfig
from armwarden.backends.mujoco.model import build_model
from armwarden.backends.mujoco.scene import scene_for_policy
from armwarden.core.errors import BackendError
from armwarden.policy import load_policy
from armwarden.policy.loading import bundled_policy
from armwarden.robot import build_robot
from armwarden.robot.ik import IkSolver
from armwarden.robot.model import resolve_description
from tests.backends.contract import BackendContract, straight_line
from tests.helpers import run_opened

POLICY = load_policy(bundled_policy("fr3"))
EXAMPLE_SCENE = Path(__file__).resolve().parents[2] / "examples" / "mujoco_scene.yaml"
ROBOT = build_robot(POLICY)


def build(**config) -> MujocoBackend:
    return create_backend(ROBOT, POLICY, Config(**config))


def run_with_backend(scenario, **config):
    """Open a MuJoCo backend, run `scenario(backend)` on a fresh event loop, always close it."""
    return run_opened(lambda: build(**config), scenario)


class TestMujocoContract(BackendContract):
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
    table = backend.sim.model.geom("table")
    top = backend.sim.model.geom_pos[table.id][2] + backend.sim.model.geom_size[table.id][2]
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


@pytest.mark.parametrize("speedup", [1.0, 4.0])
def test_each_tick_is_kept_stamped_when_its_state_held_whole_steps_apart(speedup: float):
    """The stamps come from the simulated time, not from when the thread measured: the contact
    observer divides momentum changes by their intervals, so scheduling jitter would be torque."""
    async def scenario(backend: MujocoBackend):
        first = (await backend.read_joint_state()).stamp
        await asyncio.sleep(0.2)
        kept = backend.joint_history.since(first)
        return kept, await backend.read_joint_states_since(first), backend.arm.timestep_s

    kept, read, physics_step_s = run_with_backend(scenario, speedup=speedup)
    timestep_s = physics_step_s / speedup
    gaps = np.diff([state.stamp for state in kept]) / timestep_s
    assert len(kept) > 10 and np.all(gaps >= 1 - 1e-6)
    np.testing.assert_allclose(gaps, np.round(gaps), atol=1e-6)  # whole physics steps, however late a tick ran
    assert [s.stamp for s in read][: len(kept)] == [s.stamp for s in kept]


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
def test_a_stop_brakes_the_arm_where_it_was_measured_not_where_it_was_commanded():
    async def scenario(backend: MujocoBackend):
        q_start = (await backend.read_joint_state()).positions.copy()
        task = asyncio.create_task(backend.execute(straight_line(backend.joint_names, q_start, q_start + 0.4, 1.0)))
        await asyncio.sleep(0.5)
        measured = (await backend.read_joint_state()).positions.copy()  # no await between this and the stop
        backend.stop_now()
        braking = backend.arm.target
        result = await task
        await asyncio.sleep(0.3)
        return measured, braking, result, await backend.read_joint_state(), backend.arm.target

    measured, braking, result, later, holding = run_with_backend(scenario)
    assert result.reason == "stopped"
    assert braking.braking and not holding.braking  # braked, then held
    np.testing.assert_allclose(braking.positions, measured, rtol=0, atol=5e-3)  # at most a few physics steps apart
    # the arm stopped within its braking distance of where the stop found it, and rests where it stopped:
    # it does not spring back to the stop's position, let alone to the commanded one
    # (within the declared hold accuracy: on a starved machine the hold is taken from a sample a few
    # physics steps after the one the result reports, 0.5 mrad apart in a CI run)
    np.testing.assert_allclose(result.final_positions, measured, rtol=0, atol=HOLD_ACCURACY_RAD)
    np.testing.assert_allclose(holding.positions, measured, rtol=0, atol=HOLD_ACCURACY_RAD)
    assert np.max(np.abs(later.velocities)) < 1e-3
    np.testing.assert_allclose(later.positions, measured, rtol=0, atol=HOLD_ACCURACY_RAD)


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


# ---------------------------------------------------------------------------- gripper
def test_the_fingers_move_to_a_width_and_home_to_fully_open():
    async def scenario(backend: MujocoBackend):
        moved = await backend.gripper_move(0.04, 0.1)
        state = await backend.gripper_state()
        return moved, state, await backend.gripper_home()

    moved, state, homed = run_with_backend(scenario, speedup=4.0)
    assert moved.success and moved.width_m == pytest.approx(0.04, abs=1e-3)
    assert state is not None and not state.moving and state.width_m == pytest.approx(0.04, abs=1e-3)
    assert homed.success and homed.width_m == pytest.approx(0.08, abs=1e-3)


def test_a_stop_freezes_the_fingers_where_they_are():
    async def scenario(backend: MujocoBackend):
        task = asyncio.create_task(backend.gripper_move(0.0, 0.02))  # 4 s to close
        await asyncio.sleep(0.3)
        backend.stop_now()
        result = await task
        await asyncio.sleep(0.2)
        return result, await backend.gripper_state()

    result, later = run_with_backend(scenario)
    assert not result.success and result.detail == "stopped"
    assert 0.0 < result.width_m < 0.08
    assert later is not None and later.width_m == pytest.approx(result.width_m, abs=5e-4)


def test_widths_forces_and_speeds_out_of_range_are_refused():
    async def scenario(backend: MujocoBackend):
        for call in (lambda: backend.gripper_move(0.09, 0.1), lambda: backend.gripper_move(0.04, float("nan")),
                     lambda: backend.gripper_grasp(0.03, 71.0, 0.1, 0.005, 0.005)):
            with pytest.raises(BackendError, match=r"outside|speed"):
                await call()
        return await backend.gripper_state()

    state = run_with_backend(scenario)
    assert state is not None and state.width_m == pytest.approx(0.08, abs=1e-6)


def published_position(backend: MujocoBackend, body: str) -> np.ndarray:
    """Where a free body is [m] in the last published sample (never `_data`, which the physics
    thread is stepping: a read there can catch a value half computed)."""
    model = backend.sim.model
    address = model.jnt_qposadr[model.body(body).jntadr[0]]  # a free joint: x, y, z, then a quaternion
    return np.array(backend.arm.measured.scene_qpos[address:address + 3])


def hand_down_at(position, seed: np.ndarray) -> np.ndarray:
    """The arm with its TCP at `position` [m], the hand pointing down."""
    solution = IkSolver(ROBOT).solve(np.asarray(position, dtype=float), np.diag([1.0, -1.0, -1.0]), [seed])
    assert solution.success, solution.message
    return solution.q


@pytest.mark.parametrize("stop_after_grasp", [False, True], ids=["grasped", "grasped then stopped"])
def test_a_grasped_box_is_held_by_friction_and_comes_along_when_the_arm_lifts(stop_after_grasp):
    home = np.asarray(POLICY.robot.home_joint_positions, dtype=float)
    table_z = float(POLICY.workspace.box.min[2])  # the cell's table; a table at home height would cut the shoulder
    # the arm starts hand down, its TCP 4 cm above the table, the box between the open fingers
    q_grasp = hand_down_at((0.45, 0.0, table_z + 0.04), home)
    box = ObjectConfig(name="box", shape="box", position_m=(0.45, 0.0, table_z + 0.035), size_m=(0.03, 0.03, 0.07),
                       mass_kg=0.2)
    q_up = hand_down_at((0.45, 0.0, table_z + 0.04 + 0.056), q_grasp)  # the TCP rises 5.6 cm
    rise_m = float(ROBOT.tcp_pose(q_up).position[2] - ROBOT.tcp_pose(q_grasp).position[2])

    async def scenario(backend: MujocoBackend):
        await asyncio.sleep(0.1)
        grasp = await backend.gripper_grasp(0.03, 40.0, 0.1, 0.005, 0.005)
        if stop_after_grasp:  # a stop must not open the hand
            await backend.stop()
        z_before = published_position(backend, "box")[2]
        q_now = (await backend.read_joint_state()).positions
        lifted = await backend.execute(straight_line(backend.joint_names, q_now, q_up, 1.0), stop_epoch=backend.stop_epoch)
        await asyncio.sleep(0.2)
        return grasp, lifted, published_position(backend, "box")[2] - z_before, backend.arm.measured.gripper_force_n

    def build_at_grasp() -> MujocoBackend:
        scene = scene_for_policy(POLICY, objects=(box.spec(),))
        cell = build_model(resolve_description(POLICY.robot.description), ROBOT, scene)
        return MujocoBackend(ROBOT, cell, q_grasp, speedup=2.0, start_tolerance_rad=POLICY.motion.start_tolerance_rad)

    grasp, lifted, box_rise_m, squeeze_n = run_opened(build_at_grasp, scenario)
    assert grasp.success and grasp.is_grasped and grasp.width_m == pytest.approx(0.03, abs=5e-3)
    assert lifted.completed
    assert box_rise_m > 0.8 * rise_m  # it came along (no weld: contact and friction only)
    assert squeeze_n == pytest.approx(40.0, rel=0.05)  # still squeezed with the grasp force, stop or not


# ---------------------------------------------------------------------------- cameras
@pytest.mark.parametrize("camera", ["scene", "wrist"])
def test_a_camera_snapshot_is_a_png_of_the_configured_size_that_is_not_blank(camera):
    async def scenario(backend: MujocoBackend):
        return await backend.camera_snapshot(camera)

    image = run_with_backend(scenario, camera_width_px=320, camera_height_px=240)
    pixels = np.asarray(Image.open(io.BytesIO(image.png)), dtype=float)
    assert image.camera == camera and (image.width, image.height) == (320, 240)
    assert pixels.shape == (240, 320, 3)
    assert pixels.std() > 10.0  # a scene, not a cleared buffer


def test_the_scene_camera_sees_the_simulated_arm_move():
    async def scenario(backend: MujocoBackend):
        before = await backend.camera_snapshot("scene")
        q_start = (await backend.read_joint_state()).positions.copy()
        turned = q_start + np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
        assert (await backend.execute(straight_line(backend.joint_names, q_start, turned, 1.0))).completed
        return before, await backend.camera_snapshot("scene")

    before, after = run_with_backend(scenario, speedup=4.0, camera_width_px=320, camera_height_px=240)
    first, second = (np.asarray(Image.open(io.BytesIO(image.png)), dtype=float) for image in (before, after))
    changed = np.abs(second - first).max(axis=2) > 30.0
    assert changed.mean() > 0.01  # over 1 % of the pixels changed clearly
    assert after.stamp > before.stamp


def test_the_example_scene_config_is_valid_and_puts_a_box_on_the_table():
    config = Config.model_validate(yaml.safe_load(EXAMPLE_SCENE.read_text()))
    backend = create_backend(ROBOT, POLICY, config)
    model = backend.sim.model
    box = model.body("box").id
    assert [o.name for o in config.objects] == ["box"]
    assert model.body_mass[box] == pytest.approx(0.2)


def test_a_home_outside_the_joint_limits_is_refused():
    cell = build().sim
    outside = np.asarray(POLICY.robot.home_joint_positions, dtype=float) + np.array([0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 0.0])
    with pytest.raises(BackendError, match="joint limits"):
        MujocoBackend(ROBOT, cell, outside)


# ---------------------------------------------------------------------------- found by review
def _blow_up(backend: MujocoBackend, force: float) -> None:
    """A force on the hand that makes the next physics step unstable."""
    hand = backend.arm.model.body(backend.sim.flange_body).id
    backend.arm.data.xfrc_applied[hand, 0] = force


def test_an_unstable_step_is_a_divergence_never_a_reset_published_as_fresh_state() -> None:
    """MuJoCo's automatic reset put the arm back at the model's defaults after an unstable step,
    and that was published as a fresh, valid state (an idle, held arm 'moved' 2.3 rad)."""
    async def scenario(backend: MujocoBackend) -> str:
        held = (await backend.read_joint_state()).positions.copy()
        _blow_up(backend, 1e14)
        deadline = time.monotonic() + 10.0  # a bound on a hung test, not a timing threshold
        while True:  # until the physics thread has stepped: the held state until then, never a reset one
            try:
                state = await backend.read_joint_state()
            except BackendError as refused:
                return str(refused)
            assert np.allclose(state.positions, held, atol=0.01), f"a reset published as fresh: {state.positions}"
            assert time.monotonic() < deadline, "the divergence was never reported"
            await asyncio.sleep(0.01)

    assert "diverged" in run_opened(lambda: create_backend(ROBOT, POLICY, Config()), scenario)


@pytest.mark.parametrize("listening", ["before", "after"])
def test_a_dead_physics_thread_is_reported_to_the_fault_listener(listening: str) -> None:
    """Found by review: the physics thread's death was reported to nobody, so an idle arm's e-stop
    never latched; one that dies before the Guard listens is told to it when it does."""
    heard: list[str] = []

    async def scenario(backend: MujocoBackend) -> None:
        if listening == "before":
            backend.set_fault_listener(heard.append)
        _blow_up(backend, float("nan"))
        servo = backend.servo
        assert servo is not None
        for _ in range(200):
            if servo.error is not None:
                break
            await asyncio.sleep(0.01)
        assert servo.error is not None
        if listening == "after":
            backend.set_fault_listener(heard.append)

    run_opened(lambda: create_backend(ROBOT, POLICY, Config()), scenario)
    assert len(heard) == 1 and "physics thread stopped" in heard[0] and "diverged" in heard[0]
