"""The fake backend: exact, time-scaled execution on its own control thread; stop, contact, faults.

Timing assertions are about order and behaviour, with generous bounds, so that a loaded 2-core CI
machine does not make them flake.
"""

from __future__ import annotations

import asyncio
import io
import itertools
import threading
import time

import anyio
import numpy as np
import pytest
from PIL import Image

from armwarden.backends.base import Backend
from armwarden.backends.fake.backend import FakeBackend
from armwarden.backends.values import ControllerInfo
from armwarden.core.errors import BackendError
from armwarden.core.trajectory import JointTrajectory
from armwarden.robot.model import RobotModel
from armwarden.robots import load_profile
from tests.backends.contract import BackendContract
from tests.helpers import run_opened

_READY = load_profile("fr3").ready_joint_positions or {}
FR3_JOINT_NAMES, FR3_READY = tuple(_READY), tuple(_READY.values())

Q_READY = np.array(FR3_READY)
# joint 2 forward: the TCP goes down (≈ 3 cm per 0.1 rad near "ready")
Q_REACH = Q_READY + np.array([0.3, 0.2, 0.0, 0.2, 0.0, 0.0, 0.3])


def run_with_backend(scenario, **options):
    """Open a fake backend, run `scenario(backend)` on a fresh event loop, always close it."""
    return run_opened(lambda: FakeBackend(**options), scenario)


def straight_line(q_start, q_goal, duration_s: float, dt_s: float = 0.01) -> JointTrajectory:
    times = np.linspace(0.0, duration_s, max(2, round(duration_s / dt_s) + 1))
    alpha = times / duration_s
    positions = np.outer(1 - alpha, q_start) + np.outer(alpha, q_goal)
    return JointTrajectory(FR3_JOINT_NAMES, times, positions)


def distance_to_polyline(q: np.ndarray, vertices: np.ndarray) -> float:
    """Euclidean distance in joint space from `q` to the piecewise linear path through `vertices`."""
    best = np.inf
    for a, b in itertools.pairwise(vertices):
        ab = b - a
        denom = float(ab @ ab)
        s = 0.0 if denom == 0 else float(np.clip((q - a) @ ab / denom, 0.0, 1.0))
        best = min(best, float(np.linalg.norm(q - (a + s * ab))))
    return best


async def wait_until(predicate, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not await predicate():
        assert time.monotonic() < deadline, "condition not reached in time"
        await asyncio.sleep(0.002)


async def has_moved(backend: FakeBackend, q_from=Q_READY, by_rad: float = 0.01):
    async def predicate():
        state = await backend.read_joint_state()
        return np.max(np.abs(state.positions - q_from)) > by_rad

    return predicate


class TestFakeBackendContract(BackendContract):
    def build(self) -> Backend:
        return FakeBackend()


# ---------------------------------------------------------------------------- execution
def test_executes_the_trajectory_exactly_along_its_linear_interpolation():
    # a bent path (three segments with different directions) so that "on the path" means something
    vertices = np.array([Q_READY, Q_READY + [0.2, 0, 0, 0, 0, 0, 0], Q_READY + [0.2, 0.1, 0, 0.2, 0, 0, 0], Q_REACH])
    times = np.array([0.0, 0.15, 0.3, 0.45])
    trajectory = JointTrajectory(FR3_JOINT_NAMES, times, vertices)

    async def scenario(backend: FakeBackend):
        fractions: list[float] = []
        task = asyncio.create_task(backend.execute(trajectory, fractions.append))
        samples = []
        while not task.done():
            samples.append((await backend.read_joint_state()).positions)
            await asyncio.sleep(0.003)
        result = await task
        return result, samples, fractions, await backend.read_joint_state()

    result, samples, fractions, final = run_with_backend(scenario)
    assert result.completed and result.reason == "completed"
    assert np.array_equal(result.final_positions, trajectory.goal)
    assert np.array_equal(final.positions, trajectory.goal)
    assert np.all(final.velocities == 0.0)
    assert len(samples) > 10
    assert max(distance_to_polyline(q, vertices) for q in samples) < 1e-9
    assert fractions and fractions[-1] == 1.0
    assert all(0.0 <= f <= 1.0 for f in fractions) and fractions == sorted(fractions)


def test_speedup_shortens_the_wall_time_of_a_trajectory():
    trajectory = straight_line(Q_READY, Q_REACH, duration_s=1.0)

    async def timed(backend: FakeBackend):
        start = time.perf_counter()
        result = await backend.execute(trajectory)
        return result, time.perf_counter() - start

    real_result, real_s = run_with_backend(timed, speedup=1.0)
    fast_result, fast_s = run_with_backend(timed, speedup=10.0)
    assert real_result.completed and fast_result.completed
    assert np.array_equal(fast_result.final_positions, trajectory.goal)
    assert real_s >= 1.0  # a time-based interpolation cannot finish early
    assert 0.1 <= fast_s < real_s / 2


def test_a_second_execution_while_one_runs_is_refused():
    async def scenario(backend: FakeBackend):
        first = asyncio.create_task(backend.execute(straight_line(Q_READY, Q_REACH, 2.0)))
        await wait_until(await has_moved(backend, by_rad=0.0))
        with pytest.raises(BackendError, match="one execution at a time"):
            await backend.execute(straight_line(Q_READY, Q_READY, 0.1))
        return await first

    # a refused execute() also stops the arm: the base class stops on any failure (fail closed)
    assert run_with_backend(scenario).reason == "stopped"


# ---------------------------------------------------------------------------- stop
def test_stop_holds_the_arm_before_it_returns_and_records_when():
    async def scenario(backend: FakeBackend):
        assert backend.last_stop_stamp is None
        task = asyncio.create_task(backend.execute(straight_line(Q_READY, Q_REACH, 2.0)))
        await wait_until(await has_moved(backend))
        requested = time.monotonic()
        await backend.stop()
        returned = time.monotonic()
        held = await backend.read_joint_state()  # no await in between: the hold is already published
        return requested, returned, held, backend.last_stop_stamp, await task

    requested, returned, held, stamp, result = run_with_backend(scenario)
    assert requested <= stamp <= returned
    # the hold was published before stop() returned (an idle tick may have re-stamped it since)
    assert held.stamp >= stamp and np.all(held.velocities == 0.0)
    assert np.array_equal(result.final_positions, held.positions)


def test_stop_does_not_wait_for_a_starved_control_thread_and_its_late_step_is_dropped():
    # the control thread is stuck in the middle of a step (as when it waits for the interpreter
    # lock under load): the stop still holds the arm at once, and the step computed before the stop
    # is never published afterwards
    async def scenario(backend: FakeBackend):
        task = asyncio.create_task(backend.execute(straight_line(Q_READY, Q_REACH, 2.0)))
        await wait_until(await has_moved(backend))
        entered, release = threading.Event(), threading.Event()
        compute_tcp = backend._compute_tcp

        def stalled_compute_tcp(q):
            entered.set()
            release.wait(5.0)
            return compute_tcp(q)

        backend._compute_tcp = stalled_compute_tcp
        assert await asyncio.to_thread(entered.wait, 5.0)
        await backend.stop()
        held = await backend.read_joint_state()
        release.set()
        await asyncio.sleep(0.05)  # the stalled step finishes and later ticks run
        backend._compute_tcp = compute_tcp
        later = await backend.read_joint_state()
        return held, later, await task

    held, later, result = run_with_backend(scenario)
    assert result.reason == "stopped"
    assert np.array_equal(held.positions, later.positions)
    assert np.all(later.velocities == 0.0) and later.stamp > held.stamp


def test_stop_issued_as_the_execution_is_handed_over_is_never_lost():
    # the stop lands right after execute() handed the trajectory over: sometimes before the control
    # thread picked it up, sometimes just after; either way the execution must end "stopped"
    async def scenario(backend: FakeBackend):
        results = []
        for _ in range(20):
            q_now = (await backend.read_joint_state()).positions
            task = asyncio.create_task(backend.execute(straight_line(q_now, Q_REACH, 1.0)))
            await asyncio.sleep(0)  # the task runs up to its first await: the trajectory is submitted
            await backend.stop()
            results.append(await task)
        return results

    results = run_with_backend(scenario)
    assert [r.reason for r in results] == ["stopped"] * 20
    assert not np.allclose(results[-1].final_positions, Q_REACH)


def test_fail_stop_makes_stop_raise():
    async def scenario(backend: FakeBackend):
        with pytest.raises(BackendError, match="fail_stop"):
            await backend.stop()

    run_with_backend(scenario, fail_stop=True)


# ---------------------------------------------------------------------------- wrench
def test_virtual_table_pushes_back_in_proportion_to_penetration():
    model = RobotModel.from_description("builtin:fr3", FR3_JOINT_NAMES, "fr3_link0", "fr3_hand_tcp")
    table_z = float(model.tcp_pose(Q_READY).position[2]) - 0.01
    q_touch = Q_READY + [0, 0.1, 0, 0, 0, 0, 0]
    q_deep = Q_READY + [0, 0.15, 0, 0, 0, 0, 0]
    stiffness = 20000.0

    async def scenario(backend: FakeBackend):
        wrenches = [await backend.read_wrench()]
        for q_from, q_to in ((Q_READY, q_touch), (q_touch, q_deep)):
            assert (await backend.execute(straight_line(q_from, q_to, 0.2))).completed
            await asyncio.sleep(0.01)
            wrenches.append(await backend.read_wrench())
        return wrenches

    above, touch, deep = run_with_backend(scenario, table_height_m=table_z, table_stiffness_n_per_m=stiffness, speedup=4.0)
    assert above.force_norm_n == 0.0
    for wrench, q in ((touch, q_touch), (deep, q_deep)):
        penetration = table_z - model.tcp_pose(q).position[2]
        assert penetration > 0
        assert wrench.force[:2].tolist() == [0.0, 0.0] and wrench.torque_norm_nm == 0.0
        assert wrench.force[2] == pytest.approx(stiffness * penetration, rel=1e-9)
    assert deep.force[2] > touch.force[2] > 0


def test_wrench_stamp_advances_with_the_control_loop():
    async def scenario(backend: FakeBackend):
        first = await backend.read_wrench()
        await asyncio.sleep(0.02)
        return first, await backend.read_wrench()

    first, second = run_with_backend(scenario)
    assert second.stamp > first.stamp


def test_freeze_wrench_keeps_the_stamp():
    async def scenario(backend: FakeBackend):
        first = await backend.read_wrench()
        await asyncio.sleep(0.05)
        return first, await backend.read_wrench()

    first, second = run_with_backend(scenario, freeze_wrench=True)
    assert second.stamp == first.stamp


def test_stalled_wrench_reads_time_out():
    async def scenario(backend: FakeBackend):
        with pytest.raises(TimeoutError):
            await backend.read_wrench()

    run_with_backend(scenario, stall_wrench_s=2.0)


def test_backend_without_wrench_reports_none():
    async def scenario(backend: FakeBackend):
        return backend.capabilities.wrench, await backend.read_wrench()

    assert run_with_backend(scenario, wrench=False) == (False, None)


# ---------------------------------------------------------------------------- gripper
def test_gripper_moves_grasps_and_homes():
    async def scenario(backend: FakeBackend):
        moved = await backend.gripper_move(0.04, 0.1)
        state_after_move = await backend.gripper_state()
        grasped = await backend.gripper_grasp(0.03, 40.0, 0.1, 0.005, 0.005)
        state_after_grasp = await backend.gripper_state()
        backend.object_width_m = 0.0  # nothing between the fingers: they close fully
        await backend.gripper_home()
        missed = await backend.gripper_grasp(0.03, 20.0, 0.1, 0.005, 0.005)
        homed = await backend.gripper_home()
        return moved, state_after_move, grasped, state_after_grasp, missed, homed, backend.last_grasp_force_n

    moved, state_after_move, grasped, state_after_grasp, missed, homed, force = run_with_backend(scenario, speedup=10.0)
    assert moved.success and moved.width_m == 0.04 and state_after_move.width_m == 0.04
    assert not state_after_move.moving
    assert grasped.success and grasped.is_grasped and grasped.width_m == pytest.approx(0.03)
    assert state_after_grasp.is_grasped
    assert not missed.success and not missed.is_grasped and missed.width_m == 0.0
    assert homed.success and homed.width_m == 0.08
    assert force == 20.0


def test_stop_interrupts_a_gripper_move():
    async def scenario(backend: FakeBackend):
        task = asyncio.create_task(backend.gripper_move(0.0, 0.01))  # 8 s to close
        await wait_until(lambda: _gripper_moving(backend))
        await asyncio.sleep(0.05)
        await backend.stop()
        result = await task
        held = await backend.gripper_state()
        await asyncio.sleep(0.05)
        return result, held, await backend.gripper_state()

    result, held, later = run_with_backend(scenario)
    assert not result.success and result.detail == "stopped"
    assert 0.0 < result.width_m < 0.08
    assert not held.moving and held.width_m == later.width_m == result.width_m


async def _gripper_moving(backend: FakeBackend) -> bool:
    return (await backend.gripper_state()).moving


def test_gripper_refuses_widths_outside_its_range():
    async def scenario(backend: FakeBackend):
        with pytest.raises(BackendError, match="outside"):
            await backend.gripper_move(0.09, 0.1)
        with pytest.raises(BackendError, match="speed"):
            await backend.gripper_move(0.04, float("nan"))
        return (await backend.gripper_state()).width_m

    assert run_with_backend(scenario) == 0.08


# ---------------------------------------------------------------------------- cameras, controllers, graph
@pytest.mark.parametrize("camera", ["scene", "wrist"])
def test_camera_returns_a_decodable_png_of_the_expected_size(camera):
    async def scenario(backend: FakeBackend):
        return await backend.camera_snapshot(camera), await backend.camera_snapshot(camera)

    first, second = run_with_backend(scenario, table_height_m=0.0)
    image = Image.open(io.BytesIO(first.png))
    assert image.format == "PNG" and image.size == (320, 240) == (first.width, first.height)
    assert first.camera == camera
    assert first.png != second.png  # the frame counter is drawn into the picture
    # deterministic: a fresh backend in the same state renders the same first frame
    again, _ = run_with_backend(scenario, table_height_m=0.0)
    assert again.png == first.png


def test_unknown_camera_is_refused():
    async def scenario(backend: FakeBackend):
        with pytest.raises(BackendError, match="camera"):
            await backend.camera_snapshot("thermal")

    run_with_backend(scenario)


def test_switch_controllers_validates_names_and_claims():
    async def scenario(backend: FakeBackend):
        with pytest.raises(BackendError, match="unknown controller"):
            await backend.switch_controllers(["no_such_controller"], [])
        with pytest.raises(BackendError, match="claim"):
            await backend.switch_controllers(["joint_impedance_controller"], [])
        await backend.switch_controllers(["joint_impedance_controller"], ["fr3_arm_controller"])
        states = {c.name: c.state for c in await backend.list_controllers()}
        with pytest.raises(BackendError, match="not active"):
            await backend.execute(straight_line(Q_READY, Q_REACH, 0.1))
        return states

    states = run_with_backend(scenario)
    assert states == {
        "fr3_arm_controller": "inactive",
        "joint_impedance_controller": "active",
        "franka_robot_state_broadcaster": "active",
    }


def test_error_recovery_clears_a_fault_that_blocks_motion():
    async def scenario(backend: FakeBackend):
        backend.fault = True
        with pytest.raises(BackendError, match="error recovery"):
            await backend.execute(straight_line(Q_READY, Q_REACH, 0.1))
        await backend.error_recovery()
        return backend.fault, await backend.execute(straight_line(Q_READY, Q_REACH, 0.1))

    fault, result = run_with_backend(scenario)
    assert fault is False and result.completed


def test_collision_thresholds_are_stored_and_graph_and_capabilities_describe_the_robot():
    async def scenario(backend: FakeBackend):
        await backend.set_collision_thresholds(30.0, 25.0)
        return backend.collision_thresholds, await backend.graph(), backend.capabilities

    thresholds, graph, capabilities = run_with_backend(scenario)
    assert thresholds == (30.0, 25.0)
    assert set(graph) == {"nodes", "topics", "services", "actions"}
    assert "/fr3_arm_controller/follow_joint_trajectory" in graph["actions"]
    assert capabilities.cameras == ("wrist", "scene") and capabilities.gripper and capabilities.wrench
    assert "fr3_hand_tcp" in capabilities.frames and "fr3_link0" in capabilities.frames


def test_custom_controller_list_is_used():
    custom = [ControllerInfo("arm", "joint_trajectory_controller/JointTrajectoryController", "active")]

    async def scenario(backend: FakeBackend):
        return await backend.list_controllers()

    assert run_with_backend(scenario, controllers=custom) == custom


# ---------------------------------------------------------------------------- bookkeeping, lifecycle
def test_actuation_commands_count_every_call_that_could_move_something():
    async def scenario(backend: FakeBackend):
        counts = [backend.actuation_commands]
        # reads and stop are not actuation commands
        await backend.read_joint_state()
        await backend.read_wrench()
        await backend.gripper_state()
        await backend.list_controllers()
        await backend.graph()
        await backend.camera_snapshot("scene")
        await backend.stop()
        counts.append(backend.actuation_commands)
        await backend.execute(straight_line(Q_READY, Q_REACH, 0.05))
        await backend.gripper_move(0.05, 0.1)
        await backend.gripper_grasp(0.04, 10.0, 0.1, 0.01, 0.01)
        await backend.gripper_home()
        await backend.switch_controllers([], [])
        await backend.set_collision_thresholds(20.0, 20.0)
        await backend.error_recovery()
        counts.append(backend.actuation_commands)
        with pytest.raises(BackendError):  # a refused command still reached the backend: counted
            await backend.gripper_move(1.0, 0.1)
        counts.append(backend.actuation_commands)
        return counts

    assert run_with_backend(scenario, speedup=10.0) == [0, 0, 7, 8]


def test_state_read_right_after_open_is_a_sample_of_the_running_control_loop():
    # a daemon builds the backend, then spends a while loading models before opening it: the first
    # read after open() must not be the (stale) sample taken at construction
    async def scenario():
        backend = FakeBackend()
        constructed = time.monotonic()
        time.sleep(0.2)  # noqa: ASYNC251 - the first sample must age while nothing else runs
        opened = time.monotonic()
        await backend.open()
        try:
            return constructed, opened, (await backend.read_joint_state()).stamp
        finally:
            await backend.close()

    constructed, opened, stamp = asyncio.run(scenario())
    assert stamp >= opened > constructed


def test_a_dead_control_thread_fails_the_running_execution_and_refuses_new_ones():
    async def scenario(backend: FakeBackend):
        task = asyncio.create_task(backend.execute(straight_line(Q_READY, Q_REACH, 2.0)))
        await wait_until(await has_moved(backend))

        def broken_compute_tcp(q):
            raise RuntimeError("injected: control thread crash")

        backend._compute_tcp = broken_compute_tcp
        with pytest.raises(BackendError, match="control thread"):
            await asyncio.wait_for(task, 5.0)
        q_now = backend.servo.latest.positions
        with pytest.raises(BackendError, match="control thread"):
            await asyncio.wait_for(backend.execute(straight_line(q_now, Q_READY, 0.2)), 5.0)

    run_with_backend(scenario)


def test_a_stop_after_the_fingers_arrived_does_not_report_the_move_as_interrupted():
    async def scenario(backend: FakeBackend):
        task = asyncio.create_task(backend.gripper_move(0.02, 0.1))  # 0.6 s of travel
        await asyncio.sleep(0.01)  # the move has started
        time.sleep(0.7)  # noqa: ASYNC251 - the loop is blocked past the arrival: the move's task has not resumed yet
        await backend.stop()  # lands between the arrival and the task noticing it
        return await task

    result = run_with_backend(scenario)
    assert result.success and result.width_m == pytest.approx(0.02)


def test_close_is_idempotent_joins_the_thread_and_refuses_further_calls():
    async def scenario():
        backend = FakeBackend()
        await backend.open()
        thread = backend.control_thread
        assert thread is not None and thread.is_alive()
        await backend.close()
        await backend.close()
        assert not thread.is_alive()
        assert thread not in threading.enumerate()
        with pytest.raises(BackendError, match="not open"):
            await backend.read_joint_state()
        with pytest.raises(BackendError, match="not open"):
            await backend.execute(straight_line(Q_READY, Q_REACH, 0.1))
        await backend.stop()  # stop after close is a harmless no-op

    asyncio.run(scenario())


def test_close_during_execution_stops_it():
    async def scenario():
        backend = FakeBackend()
        await backend.open()
        task = asyncio.create_task(backend.execute(straight_line(Q_READY, Q_REACH, 2.0)))
        await wait_until(await has_moved(backend))
        await backend.close()
        return await task, backend.control_thread.is_alive()

    result, alive = asyncio.run(scenario())
    assert result.reason == "stopped" and not alive


def test_close_inside_a_cancelled_scope_still_stops_and_joins_the_thread():
    async def scenario():
        backend = FakeBackend()
        await backend.open()
        task = asyncio.create_task(backend.execute(straight_line(Q_READY, Q_REACH, 2.0)))
        await wait_until(await has_moved(backend))
        with anyio.move_on_after(0.01):  # like a server shutting down on SIGTERM
            try:
                await anyio.sleep(10)
            finally:
                await backend.close()  # every await in here is cancelled unless shielded
        joined = not backend.control_thread.is_alive()  # checked before anything else can run
        return joined, await task

    joined, result = asyncio.run(scenario())
    assert joined
    assert result.reason == "stopped"


def test_close_does_not_hang_when_the_stop_hangs():
    async def scenario():
        backend = FakeBackend()
        await backend.open()

        async def hung_stop():
            await asyncio.sleep(3600)

        backend._stop = hung_stop
        backend.stop_timeout_s = 0.2
        start = time.monotonic()
        await backend.close()
        return time.monotonic() - start, backend.control_thread.is_alive()

    elapsed_s, alive = asyncio.run(scenario())
    assert elapsed_s < 5.0 and not alive


@pytest.mark.parametrize("period_s", [0.002, 0.0, float("nan")])
def test_refuses_a_control_period_above_one_millisecond(period_s):
    with pytest.raises(ValueError, match="control_period_s"):
        FakeBackend(control_period_s=period_s)


def test_refuses_a_home_outside_the_joint_limits():
    with pytest.raises(ValueError, match="outside the joint limits"):
        FakeBackend(home=[0.0] * 7)


def test_stopping_the_fingers_from_another_thread_ends_a_gripper_move_stopped_where_they_froze():
    async def scenario(backend: FakeBackend):
        task = asyncio.create_task(backend.gripper_move(0.0, 0.01))  # 8 s to close
        await wait_until(lambda: _gripper_moving(backend))
        stopper = threading.Thread(target=backend._stop_fingers)
        stopper.start()
        result = await task
        stopper.join()
        return result, await backend.gripper_state()

    result, held = run_with_backend(scenario)
    assert not result.success and result.detail == "stopped"
    assert 0.0 < result.width_m < 0.08
    assert not held.moving and held.width_m == result.width_m
