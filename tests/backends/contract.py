"""`BackendContract`: the conformance suite every backend passes (python-can back-to-back style).

A backend's test module subclasses it and implements `build()` (a new, unopened backend):

    class TestMyBackendContract(BackendContract):
        def build(self) -> Backend:
            return MyBackend(...)

The suite checks the rules in `armwarden.backends.base`: lifecycle, stop at any time (also from
another thread while the event loop is blocked), exact execution, progress, cancel → stop,
refused trajectories move nothing, stamps, capabilities against the optional calls, and the death
of each of the backend's own threads (killed through `Backend.inject_worker_failure`) behind the
real Guard: the e-stop latched for the backend fault, audited, named by `get_safety_status`,
motion refused by the Guard and by the backend; the same for each thread that hangs (alive, no
progress: `Backend.inject_worker_hang`, released before the backend closes).
Assertions are about order and outcome, never about how fast something happened.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Any, ClassVar

import anyio
import numpy as np
import pytest

from armwarden.assembly import build_guard
from armwarden.audit import AuditLog
from armwarden.backends.base import Backend
from armwarden.backends.parts import Capabilities
from armwarden.backends.values import PREEMPTED
from armwarden.core.errors import BackendError, RefusalCode, SafetyRefusal
from armwarden.core.state import JointState
from armwarden.core.trajectory import JointTrajectory
from armwarden.policy import bundled_policy, load_policy
from armwarden.tools import spec_of
from tests.helpers import records_of


def straight_line(joint_names, q_start, q_goal, duration_s: float, dt_s: float = 0.01) -> JointTrajectory:
    """Linear joint motion from `q_start` to `q_goal` in `duration_s` [s], sampled every `dt_s`."""
    times = np.linspace(0.0, duration_s, max(2, round(duration_s / dt_s) + 1))
    alpha = times / duration_s
    return JointTrajectory(tuple(joint_names), times, np.outer(1 - alpha, q_start) + np.outer(alpha, q_goal))


async def wait_until(predicate: Callable[[], Awaitable[bool]], timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not await predicate():
        assert time.monotonic() < deadline, "condition not reached in time"
        await anyio.sleep(0.002)


def assert_near(actual: np.ndarray, expected: np.ndarray, accuracy_rad: float) -> None:
    """Equal within a backend's declared accuracy [rad] (exactly equal for a kinematic backend)."""
    np.testing.assert_allclose(actual, expected, rtol=0, atol=accuracy_rad)


async def _true_when(condition: bool) -> bool:
    return condition


#: each tool that needs a backend capability (its record's `capability`) → the backend call it
#: makes, with arguments a backend declaring the capability must accept
OPTIONAL_CALLS: dict[str, Callable[[Backend, Any], Awaitable[Any]]] = {
    "gripper_move": lambda b, s: b.gripper_move(s.gripper_width_m, 0.1),
    "gripper_grasp": lambda b, s: b.gripper_grasp(s.gripper_width_m, 10.0, 0.1, 0.01, 0.01),
    "gripper_home": lambda b, s: b.gripper_home(),
    "camera_snapshot": lambda b, s: b.camera_snapshot((b.capabilities.cameras or ("none",))[0]),
    "list_controllers": lambda b, s: b.list_controllers(),
    "switch_controllers": lambda b, s: b.switch_controllers([], []),
    "set_collision_thresholds": lambda b, s: b.set_collision_thresholds(20.0, 20.0),
    "error_recovery": lambda b, s: b.error_recovery(),
    "list_ros_graph": lambda b, s: b.graph(),
}


def declares(capabilities: Capabilities, tool: str) -> bool:
    """Does a backend with `capabilities` serve `tool` (its record's capability)?"""
    spec = spec_of(tool)
    assert spec is not None and spec.capability is not None, f"{tool} needs no capability"
    return bool(getattr(capabilities, spec.capability))


class BackendContract:
    """Subclass as `Test<Name>Contract` and implement `build`; override the knobs below if needed."""

    pytestmark: ClassVar[list[pytest.MarkDecorator]] = [pytest.mark.anyio]

    #: joint offsets [rad] of the test motion from the arm's initial position
    reach_rad: float = 0.2
    #: trajectory time [s] of motions meant to finish, and of motions meant to be interrupted
    short_motion_s: float = 0.2
    long_motion_s: float = 4.0
    #: a gripper opening [m] the backend accepts, when it has a gripper
    gripper_width_m: float = 0.04

    def build(self) -> Backend:
        raise NotImplementedError("a BackendContract subclass returns a new, unopened backend")

    @pytest.fixture
    async def backend(self) -> AsyncIterator[Backend]:
        backend = self.build()
        await backend.open()
        try:
            yield backend
        finally:
            await backend.close()

    # ------------------------------------------------------------------ helpers
    async def positions(self, backend: Backend) -> np.ndarray:
        return (await backend.read_joint_state()).positions.copy()

    async def motion(self, backend: Backend, duration_s: float) -> JointTrajectory:
        q_start = await self.positions(backend)
        return straight_line(backend.joint_names, q_start, q_start + self.reach_rad, duration_s)

    @contextlib.asynccontextmanager
    async def executing(self, backend: Backend, trajectory: JointTrajectory) -> AsyncIterator[list[Any]]:
        """`execute(trajectory)` in the background; the body runs once the arm has moved; after
        the block the execution's result is the list's one element."""
        q_start = await self.positions(backend)
        results: list[Any] = []
        async with anyio.create_task_group() as group:
            async def run() -> None:
                results.append(await backend.execute(trajectory))

            group.start_soon(run)
            await wait_until(lambda: self.has_moved(backend, q_start))
            yield results

    def assert_nothing_reached_the_arm(self, backend: Backend) -> None:
        """Called after each refused or preempted execution: a backend whose far side can count
        what arrived (the ROS cell counts trajectory goals) asserts that nothing did."""

    async def has_moved(self, backend: Backend, q_from: np.ndarray) -> bool:
        return bool(np.max(np.abs(await self.positions(backend) - q_from)) > 1e-3)

    async def assert_still(self, backend: Backend) -> np.ndarray:
        """Wait for the arm to come to rest (`rest_speed_rad_s`), then check it stays where it
        rests (`hold_accuracy_rad`) while time passes; return where it rests."""
        async def at_rest() -> bool:
            state = await backend.read_joint_state()
            return bool(np.all(np.abs(state.velocities) <= backend.rest_speed_rad_s))

        await wait_until(at_rest)
        first = await backend.read_joint_state()
        await anyio.sleep(0.05)
        second = await backend.read_joint_state()
        assert_near(second.positions, first.positions, backend.hold_accuracy_rad)
        assert np.all(np.abs(second.velocities) <= backend.rest_speed_rad_s)
        return second.positions

    # ------------------------------------------------------------------ lifecycle
    async def test_open_twice_and_close_twice_are_harmless(self) -> None:
        backend = self.build()
        await backend.open()
        await backend.open()
        assert backend.is_open
        await backend.close()
        await backend.close()
        assert not backend.is_open

    async def test_stop_before_open_and_after_close_does_nothing(self) -> None:
        backend = self.build()
        await backend.stop()
        backend.stop_now()
        await backend.open()
        await backend.close()
        await backend.stop()
        backend.stop_now()

    async def test_calls_after_close_are_refused(self, backend: Backend) -> None:
        trajectory = await self.motion(backend, self.short_motion_s)
        await backend.close()
        with pytest.raises(BackendError, match="not open"):
            await backend.read_joint_state()
        with pytest.raises(BackendError, match="not open"):
            await backend.execute(trajectory)

    async def test_close_during_execution_ends_it_stopped(self, backend: Backend) -> None:
        async with self.executing(backend, await self.motion(backend, self.long_motion_s)) as results:
            await backend.close()
        assert results[0].reason == "stopped"

    # ------------------------------------------------------------------ state and stamps
    async def test_state_names_the_backend_joints_with_finite_values(self, backend: Backend) -> None:
        state = await backend.read_joint_state()
        n = len(backend.joint_names)
        assert state.names == backend.joint_names
        assert state.positions.shape == state.velocities.shape == (n,)
        assert np.all(np.isfinite(state.positions)) and np.all(np.isfinite(state.velocities))
        assert state.stamp <= time.monotonic()

    async def test_stamps_never_go_backwards_and_advance_over_time(self, backend: Backend) -> None:
        stamps = [(await backend.read_joint_state()).stamp]

        async def advanced() -> bool:  # however long a loaded machine takes to deliver the next state
            stamps.append((await backend.read_joint_state()).stamp)
            return stamps[-1] > stamps[0]

        await wait_until(advanced)
        assert stamps == sorted(stamps)

    async def test_the_states_since_a_stamp_are_newer_in_order_and_end_at_the_latest(self, backend: Backend) -> None:
        """`read_joint_states_since`: what the contact observer integrates (every sample a servo
        loop published since its last read, or the latest alone): never empty, stamps rising and
        after the one asked about, the newest no older than what `read_joint_state` gave before."""
        first = await backend.read_joint_states_since(None)
        assert len(first) == 1
        since = first[-1].stamp
        again = await backend.read_joint_states_since(since)
        assert again and all(state.stamp >= since for state in again)  # never empty, never older
        reads: list[tuple[JointState, ...]] = []

        async def newer() -> bool:  # however long a loaded machine takes to deliver the next state
            reads.append(await backend.read_joint_states_since(since))
            return reads[-1][-1].stamp > since

        await wait_until(newer)
        stamps = [state.stamp for state in reads[-1]]
        assert stamps == sorted(set(stamps)) and stamps[0] > since
        assert all(state.names == backend.joint_names for state in reads[-1])

    async def test_wrench_is_none_without_the_capability_and_stamped_with_it(self, backend: Backend) -> None:
        wrench = await backend.read_wrench()
        if not backend.capabilities.wrench:
            assert wrench is None
        else:
            assert wrench is not None and np.isfinite(wrench.stamp) and wrench.stamp <= time.monotonic()

    async def test_states_carry_joint_torques_exactly_when_the_cell_declares_them(self, backend: Backend) -> None:
        """Declared: every state, at rest and moving, has one effort per joint (NaN passes as it
        is; sign and units: tests/backends/joint_torque_conformance.py). Not declared: None."""
        declared = backend.capabilities.joint_torques
        states = [await backend.read_joint_state()]
        async with self.executing(backend, await self.motion(backend, self.long_motion_s)):
            states.append(await backend.read_joint_state())
            await backend.stop()
        states.append(await backend.read_joint_state())
        for state in states:
            if declared:
                assert state.efforts is not None and state.efforts.shape == (len(backend.joint_names),)
            else:
                assert state.efforts is None

    # ------------------------------------------------------------------ execution
    async def test_execute_ends_exactly_at_the_goal_and_leaves_the_trajectory_unchanged(self, backend: Backend) -> None:
        trajectory = await self.motion(backend, self.short_motion_s)
        times, positions, digest = trajectory.times.copy(), trajectory.positions.copy(), trajectory.digest
        result = await backend.execute(trajectory)
        assert result.completed and result.reason == "completed"
        np.testing.assert_allclose(result.final_positions, trajectory.goal, rtol=0, atol=backend.goal_accuracy_rad)
        np.testing.assert_allclose(await self.assert_still(backend), trajectory.goal, rtol=0, atol=backend.goal_accuracy_rad)
        assert np.array_equal(trajectory.times, times) and np.array_equal(trajectory.positions, positions)
        assert trajectory.digest == digest

    async def test_progress_stays_in_0_1_never_decreases_and_ends_at_1(self, backend: Backend) -> None:
        fractions: list[float] = []
        await backend.execute(await self.motion(backend, self.short_motion_s), fractions.append)
        assert fractions and fractions[-1] == 1.0
        assert all(0.0 <= f <= 1.0 for f in fractions) and fractions == sorted(fractions)

    async def test_execute_returns_to_where_it_started(self, backend: Backend) -> None:
        q_start = await self.positions(backend)
        there = await self.motion(backend, self.short_motion_s)
        assert (await backend.execute(there)).completed
        back = straight_line(backend.joint_names, there.goal, q_start, self.short_motion_s)
        assert (await backend.execute(back)).completed
        np.testing.assert_allclose(await self.positions(backend), q_start, rtol=0, atol=backend.goal_accuracy_rad)

    # ------------------------------------------------------------------ refused trajectories
    def malformed(self, backend: Backend, q: np.ndarray) -> dict[str, JointTrajectory]:
        names, n = backend.joint_names, len(backend.joint_names)
        bad_q = q.copy()
        bad_q[0] = np.nan
        def trajectory(joint_names, times, positions) -> JointTrajectory:
            return JointTrajectory(tuple(joint_names), np.array(times, dtype=float), np.array(positions, dtype=float))

        return {
            "other joints": trajectory([f"other_{name}" for name in names], [0.0, 0.1], [q, q]),
            "wrong width": trajectory(names, [0.0, 0.1], np.zeros((2, n + 1))),
            "no waypoints": trajectory(names, np.zeros(0), np.zeros((0, n))),
            "not a number": trajectory(names, [0.0, 0.1], [q, bad_q]),
            "late start": trajectory(names, [0.1, 0.2], [q, q]),
            "time runs back": trajectory(names, [0.0, 0.2, 0.1], [q, q, q]),
        }

    @pytest.mark.parametrize(
        "case", ["other joints", "wrong width", "no waypoints", "not a number", "late start", "time runs back"]
    )
    async def test_a_malformed_trajectory_is_refused_and_nothing_moves(self, backend: Backend, case: str) -> None:
        q_start = await self.positions(backend)
        with pytest.raises(BackendError, match="trajectory"):
            await backend.execute(self.malformed(backend, q_start)[case])
        assert_near(await self.assert_still(backend), q_start, backend.hold_accuracy_rad)
        self.assert_nothing_reached_the_arm(backend)

    async def test_a_trajectory_that_does_not_start_at_the_arm_is_refused_and_nothing_moves(self, backend: Backend) -> None:
        q_start = await self.positions(backend)
        elsewhere = q_start + 2 * backend.start_tolerance_rad
        with pytest.raises(BackendError, match="rad away from the arm"):
            await backend.execute(straight_line(backend.joint_names, elsewhere, q_start, self.short_motion_s))
        assert_near(await self.assert_still(backend), q_start, backend.hold_accuracy_rad)
        self.assert_nothing_reached_the_arm(backend)

    # ------------------------------------------------------------------ stops
    async def test_stop_when_idle_keeps_the_arm_still_and_the_next_motion_runs(self, backend: Backend) -> None:
        q_start = await self.positions(backend)
        await backend.stop()
        assert_near(await self.assert_still(backend), q_start, backend.hold_accuracy_rad)
        assert (await backend.execute(await self.motion(backend, self.short_motion_s))).completed

    async def test_stop_during_execute_ends_it_stopped_short_of_the_goal_and_holds(self, backend: Backend) -> None:
        trajectory = await self.motion(backend, self.long_motion_s)
        async with self.executing(backend, trajectory) as results:
            await backend.stop()
        held = await self.assert_still(backend)
        assert not results[0].completed and results[0].reason == "stopped"
        assert_near(results[0].final_positions, held, backend.hold_accuracy_rad)
        assert not np.allclose(held, trajectory.goal)

    async def test_stop_now_from_another_thread_while_the_loop_is_blocked_holds_the_arm(self, backend: Backend) -> None:
        trajectory = await self.motion(backend, self.long_motion_s)
        held_in_thread: list[Any] = []
        stopped = threading.Event()
        async with self.executing(backend, trajectory) as results:
            def stop_from_elsewhere() -> None:
                backend.stop_now()
                held_in_thread.append(backend._latest_joint_state())  # a published sample, if the backend has one
                stopped.set()

            threading.Thread(target=stop_from_elsewhere).start()
            assert stopped.wait(10.0)  # the event loop is blocked the whole time
            time.sleep(0.1)  # noqa: ASYNC251 - the loop stays blocked a little longer, on purpose
        held = await self.assert_still(backend)
        assert results[0].reason == "stopped"
        assert_near(results[0].final_positions, held, backend.hold_accuracy_rad)
        assert not np.allclose(held, trajectory.goal)
        if held_in_thread[0] is not None:  # held in the stopping thread, not when the loop came back
            assert_near(held_in_thread[0].positions, held, backend.hold_accuracy_rad)

    async def test_emergency_stop_now_bumps_the_epoch_ends_the_execution_stopped_and_the_arm_rests(
            self, backend: Backend) -> None:
        trajectory = await self.motion(backend, self.long_motion_s)
        async with self.executing(backend, trajectory) as results:
            before = backend.stop_epoch
            stopped = threading.Event()

            def estop_from_elsewhere() -> None:
                backend.emergency_stop_now()
                stopped.set()

            threading.Thread(target=estop_from_elsewhere).start()
            assert stopped.wait(10.0)
            assert backend.stop_epoch > before
        assert results[0].reason == "stopped"
        held = await self.assert_still(backend)
        assert not np.allclose(held, trajectory.goal)

    async def test_every_stop_bumps_the_stop_epoch(self, backend: Backend) -> None:
        before = backend.stop_epoch
        await backend.stop()
        backend.stop_now()
        threading.Thread(target=backend.stop_now).start()
        await wait_until(lambda: _true_when(backend.stop_epoch == before + 3))

    async def test_a_stop_after_the_decision_to_move_means_nothing_moves(self, backend: Backend) -> None:
        q_start = await self.positions(backend)
        decided = backend.stop_epoch
        thread = threading.Thread(target=backend.stop_now)
        thread.start()
        thread.join()
        result = await backend.execute(await self.motion(backend, self.short_motion_s), stop_epoch=decided)
        assert not result.completed and result.reason == PREEMPTED
        assert_near(await self.assert_still(backend), q_start, backend.hold_accuracy_rad)
        self.assert_nothing_reached_the_arm(backend)

    @pytest.mark.parametrize("delay_ms", [0.0, 0.05, 0.2, 0.5, 1.0, 2.0])
    async def test_a_stop_racing_the_hand_over_is_never_overtaken(self, backend: Backend, delay_ms: float) -> None:
        # The stop is issued from another thread after the decision to move, at some moment around
        # the hand-over: whichever wins, the motion must not run on after the stop.
        q_start = await self.positions(backend)
        trajectory = await self.motion(backend, self.long_motion_s)
        decided = backend.stop_epoch

        def stop_soon() -> None:
            time.sleep(delay_ms / 1000)
            backend.stop_now()

        thread = threading.Thread(target=stop_soon)
        thread.start()
        result = await backend.execute(trajectory, stop_epoch=decided)
        thread.join()
        assert not result.completed and result.reason in ("stopped", PREEMPTED)
        held = await self.assert_still(backend)
        assert not np.allclose(held, trajectory.goal)
        again = straight_line(backend.joint_names, held, q_start, self.short_motion_s)
        assert (await backend.execute(again)).completed

    async def test_cancelling_execute_stops_the_arm_and_frees_the_backend(self, backend: Backend) -> None:
        q_start = await self.positions(backend)
        trajectory = await self.motion(backend, self.long_motion_s)
        async with anyio.create_task_group() as group:
            group.start_soon(backend.execute, trajectory)
            await wait_until(lambda: self.has_moved(backend, q_start))
            group.cancel_scope.cancel()
        held = await self.assert_still(backend)
        assert not np.allclose(held, trajectory.goal)
        again = straight_line(backend.joint_names, held, q_start, self.short_motion_s)
        assert (await backend.execute(again)).completed

    # ------------------------------------------------------------------ capabilities
    @pytest.mark.parametrize("call", sorted(OPTIONAL_CALLS))
    async def test_an_optional_call_works_when_declared_and_is_refused_otherwise(self, backend: Backend, call: str) -> None:
        invoke = OPTIONAL_CALLS[call]
        if declares(backend.capabilities, call):
            await invoke(backend, self)
        else:
            with pytest.raises(BackendError, match="has no"):
                await invoke(backend, self)

    async def test_gripper_state_matches_the_gripper_capability(self, backend: Backend) -> None:
        state = await backend.gripper_state()
        assert (state is not None) == backend.capabilities.gripper

    # ------------------------------------------------------------------ the backend's own threads
    async def test_a_dead_backend_thread_is_a_latched_audited_fault_and_motion_is_refused(self, tmp_path: Path) -> None:
        workers = self.build().worker_threads
        if not workers:  # nothing of its own to die; the seam says so
            async with self.opened_backend() as backend:
                with pytest.raises(BackendError, match="has no thread 'worker'"):
                    backend.inject_worker_failure("worker", RuntimeError("injected"))
            return
        for worker in workers:  # each on a fresh backend: one death at a time
            await self.assert_thread_death_is_a_fault(worker, tmp_path / f"audit-{worker}.jsonl")

    async def test_a_hung_backend_thread_is_a_latched_audited_fault_and_motion_is_refused(self, tmp_path: Path) -> None:
        workers = self.build().worker_threads
        if not workers:  # nothing of its own to hang; the seam says so
            async with self.opened_backend() as backend:
                with pytest.raises(BackendError, match="has no thread 'worker'"):
                    backend.inject_worker_hang("worker", threading.Event())
            return
        for worker in workers:  # each on a fresh backend: one hang at a time
            await self.assert_thread_hang_is_a_fault(worker, tmp_path / f"audit-hang-{worker}.jsonl")

    async def assert_thread_hang_is_a_fault(self, worker: str, audit_path: Path) -> None:
        """Hang `worker` (alive, no progress) behind the real Guard until the fault is checked:
        latched, audited, reported by the safety status, every motion refused; then let it go, so
        the backend closes as usual."""
        release = threading.Event()
        async with self.opened_backend() as backend:
            try:
                with AuditLog(audit_path) as audit:
                    guard = build_guard(load_policy(bundled_policy("fr3")), backend, audit)
                    q_start = await self.positions(backend)
                    backend.inject_worker_hang(worker, release)
                    hung = f"the {worker} thread made no progress for"
                    await self.assert_worker_fault_is_latched_and_refused(backend, guard, audit, q_start, hung, hung)
                    assert await backend.fault_behind_stale_data() == backend.worker_failure
            finally:
                release.set()
        self.assert_nothing_reached_the_arm(backend)

    @contextlib.asynccontextmanager
    async def opened_backend(self) -> AsyncIterator[Backend]:
        backend = self.build()
        await backend.open()
        try:
            yield backend
        finally:
            await backend.close()

    async def assert_thread_death_is_a_fault(self, worker: str, audit_path: Path) -> None:
        """Kill `worker` behind the real Guard; the fault must be latched, audited, reported by
        the safety status, and every motion refused."""
        async with self.opened_backend() as backend:
            with AuditLog(audit_path) as audit:
                guard = build_guard(load_policy(bundled_policy("fr3")), backend, audit)
                q_start = await self.positions(backend)
                backend.inject_worker_failure(worker, RuntimeError(f"injected: the {worker} thread dies"))
                died = f"the {worker} thread stopped (RuntimeError: injected: the {worker} thread dies)"
                await self.assert_worker_fault_is_latched_and_refused(backend, guard, audit, q_start, died,
                                                                      f"the {worker} thread stopped")
        self.assert_nothing_reached_the_arm(backend)

    async def assert_worker_fault_is_latched_and_refused(self, backend: Backend, guard: Any, audit: AuditLog,
                                                         q_start: np.ndarray, cause: str, refusal: str) -> None:
        """Once a worker died or hung: the e-stop latches as a backend fault naming `cause`, the
        safety status and the audit log say so, the Guard refuses to plan, and the backend refuses
        to move or read with a message matching `refusal`."""
        await wait_until(lambda: _true_when(guard.latch.is_latched))
        event = guard.latch.current_event
        assert event is not None and event.source == "backend_fault" and cause in event.reason, event
        status = guard.safety_status()
        assert status.estopped and any(cause in fault for fault in status.faults), status
        audit.flush()
        records = records_of(audit.path)
        assert any(r["event"] == "backend_fault" and cause in r["detail"] for r in records), records
        with pytest.raises(SafetyRefusal) as refused:  # the Guard refuses: the e-stop is latched
            await guard.plan("joints", {"joint_positions": q_start.tolist()})
        assert refused.value.code is RefusalCode.ESTOPPED
        with pytest.raises(BackendError, match=refusal):  # and so does the backend
            await backend.execute(straight_line(backend.joint_names, q_start, q_start + self.reach_rad,
                                                self.short_motion_s))
        with pytest.raises(BackendError, match=refusal):  # reads name the cause, not stale data
            await backend.read_joint_state()
