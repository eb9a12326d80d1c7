"""The servo core on its own: handoff to asyncio, holds from any thread, a dying servo thread."""

from __future__ import annotations

import asyncio
import threading

import numpy as np
import pytest

from armwarden.backends.servo import ServoHooks, ServoLoop, Setpoint, segment_velocity
from armwarden.backends.values import ExecutionResult
from armwarden.core.errors import BackendError
from armwarden.core.trajectory import JointTrajectory
from armwarden.handoff import settle, settle_threadsafe

pytestmark = pytest.mark.anyio
NAMES = ("a", "b")


class Recorder(ServoHooks):
    """Records what the loop commands and holds."""

    def __init__(self) -> None:
        self.commanded: list[Setpoint] = []
        self.held: list[Setpoint] = []
        self.held_stamps: list[float] = []
        self.failed: list[BaseException] = []

    def servo_command(self, setpoint: Setpoint) -> None:
        self.commanded.append(setpoint)

    def servo_hold(self, setpoint: Setpoint) -> None:
        self.held.append(setpoint)

    def servo_held(self, stamp: float) -> None:
        self.held_stamps.append(stamp)

    def servo_failed(self, error: BaseException) -> None:
        self.failed.append(error)


def line(duration_s: float) -> JointTrajectory:
    return JointTrajectory(NAMES, [0.0, duration_s / 2, duration_s], [[0.0, 0.0], [0.5, -0.5], [1.0, 0.0]])


async def started(hooks: ServoHooks) -> ServoLoop:
    servo = ServoLoop(hooks, [0.0, 0.0], period_s=0.001, name="test servo")
    await servo.start()
    return servo


async def test_a_completed_run_ends_exactly_at_the_goal_and_holds_it() -> None:
    hooks = Recorder()
    servo = await started(hooks)
    try:
        result = await servo.run(line(0.05), lambda fraction: None)
        await asyncio.sleep(0.02)
    finally:
        await servo.shutdown()
    assert result.completed and result.final_positions.tolist() == [1.0, 0.0]
    assert servo.latest.positions.tolist() == [1.0, 0.0] and not servo.latest.velocities.any()
    assert hooks.commanded[-1].positions.tolist() == [1.0, 0.0]


async def test_a_hold_from_another_thread_ends_the_run_stopped_where_it_was_commanded() -> None:
    hooks = Recorder()
    servo = await started(hooks)
    try:
        task = asyncio.create_task(servo.run(line(10.0), lambda fraction: None))
        while not servo.latest.positions.any():  # noqa: ASYNC110 - polls what the servo thread publishes
            await asyncio.sleep(0.002)
        thread = threading.Thread(target=servo.hold)
        thread.start()
        thread.join()
        result = await task
    finally:
        await servo.shutdown()
    assert result.reason == "stopped"
    assert np.array_equal(hooks.held[-1].positions, result.final_positions)
    assert hooks.held_stamps[-1] == hooks.held[-1].stamp  # the backend is told when the hold took effect


class MeasuredRecorder(Recorder):
    """A physical arm: it is measured somewhere else than it was commanded."""

    measured = np.array([0.25, -0.125])

    def servo_hold_positions(self, commanded: np.ndarray) -> np.ndarray:
        return self.measured


async def test_a_hold_stands_still_where_the_hooks_measure_the_arm() -> None:
    hooks = MeasuredRecorder()
    servo = await started(hooks)
    try:
        task = asyncio.create_task(servo.run(line(10.0), lambda fraction: None))
        while not servo.latest.positions.any():  # noqa: ASYNC110 - polls what the servo thread publishes
            await asyncio.sleep(0.002)
        servo.hold()
        result = await task
        await asyncio.sleep(0.02)  # idle ticks keep commanding the hold
    finally:
        await servo.shutdown()
    assert result.reason == "stopped" and result.final_positions.tolist() == [0.25, -0.125]
    assert hooks.held[-1].positions.tolist() == [0.25, -0.125] and not hooks.held[-1].velocities.any()
    assert hooks.commanded[-1].positions.tolist() == [0.25, -0.125]


async def test_a_run_submitted_as_the_servo_thread_dies_is_refused_not_left_hanging() -> None:
    servo = await started(Recorder())
    check = servo.require_running

    def check_then_lose_the_thread() -> None:
        check()
        servo._shutdown = True  # the thread ends (and fails what it owns) between check and submit
        servo._wake.set()
        assert servo.thread is not None
        servo.thread.join(2.0)

    servo.require_running = check_then_lose_the_thread  # type: ignore[method-assign]
    try:
        with pytest.raises(BackendError, match="control thread stopped"):
            await asyncio.wait_for(servo.run(line(0.2), lambda fraction: None), 3.0)
    finally:
        await servo.shutdown()


async def test_a_failing_tick_fails_the_run_and_reports_the_error_once() -> None:
    class Broken(Recorder):
        def servo_prepare(self, setpoint: Setpoint) -> None:
            if setpoint.positions.any():
                raise RuntimeError("injected")

    hooks = Broken()
    servo = await started(hooks)
    try:
        with pytest.raises(BackendError, match="control thread"):
            await asyncio.wait_for(servo.run(line(1.0), lambda fraction: None), 5.0)
        with pytest.raises(BackendError, match="control thread failed"):
            servo.require_running()
    finally:
        await servo.shutdown()
    assert [str(e) for e in hooks.failed] == ["injected"]


async def test_a_hold_whose_command_fails_raises_and_fails_the_run() -> None:
    class Unheard(Recorder):
        def servo_hold(self, setpoint: Setpoint) -> None:
            raise OSError("bus off")

    servo = await started(Unheard())
    try:
        task = asyncio.create_task(servo.run(line(10.0), lambda fraction: None, hold_on_exit=False))
        while not servo.busy or not servo.latest.positions.any():  # noqa: ASYNC110 - polls the servo thread
            await asyncio.sleep(0.002)
        with pytest.raises(OSError, match="bus off"):
            servo.hold()
        with pytest.raises(BackendError, match="stop failed"):
            await task
    finally:
        await servo.shutdown()


async def test_settle_threadsafe_completes_the_future_once_and_ignores_a_closed_loop() -> None:
    loop = asyncio.get_running_loop()
    future: asyncio.Future[int] = loop.create_future()
    threading.Thread(target=settle_threadsafe, args=(loop, future, 1)).start()
    assert await future == 1
    settle(future, 2)  # already done: ignored
    assert future.result() == 1
    closed = asyncio.new_event_loop()
    closed.close()
    assert settle_threadsafe(closed, future, 3) is False


def test_segment_velocity_is_the_slope_of_the_current_segment_and_zero_outside() -> None:
    trajectory = line(1.0)
    assert segment_velocity(trajectory, 0.25).tolist() == [1.0, -1.0]
    assert segment_velocity(trajectory, 0.75).tolist() == [1.0, 1.0]
    assert segment_velocity(trajectory, 1.0).tolist() == [0.0, 0.0]
    assert segment_velocity(trajectory, -1.0).tolist() == [0.0, 0.0]


class StallingRecorder(Recorder):
    """A kinematic arm's hooks whose servo thread stalls once, 30 ms, a few ticks into a run."""

    records_missed_samples = True

    def __init__(self) -> None:
        super().__init__()
        self.recorded: list[Setpoint] = []
        self.prepared = 0
        self._following_ticks = 0

    def servo_prepare(self, setpoint: Setpoint) -> None:
        if threading.current_thread().name == "servo-under-test":
            self.prepared += 1
        if setpoint.following and threading.current_thread().name == "servo-under-test":
            self._following_ticks += 1
            if self._following_ticks == 5:
                threading.Event().wait(0.03)

    def servo_record(self, setpoint: Setpoint) -> None:
        self.recorded.append(setpoint)
        self.commanded.append(setpoint)


async def run_stalling(hooks: StallingRecorder, duration_s: float) -> tuple[ServoLoop, ExecutionResult]:
    """Run `line(duration_s)` on a 1 kHz loop whose thread `hooks` stall once; the loop and its result."""
    servo = ServoLoop(hooks, [0.0, 0.0], period_s=0.001, name="test servo")
    await servo.start("servo-under-test")
    try:
        return servo, await servo.run(line(duration_s), lambda fraction: None)
    finally:
        await servo.shutdown()


async def test_a_late_tick_records_the_samples_of_the_periods_it_skipped_on_the_trajectory() -> None:
    hooks = StallingRecorder()
    servo, result = await run_stalling(hooks, 0.1)
    assert result.completed and len(hooks.recorded) >= 25  # the 30 ms stall, a period each
    # a tick's whole work (servo_prepare) runs once per tick, never per recorded period: a slow one
    # repeated for each would make the next tick later still, until the watchdog fired
    assert hooks.prepared == len(hooks.commanded) - len(hooks.recorded)
    following = [s for s in hooks.commanded if s.following]
    stamps = np.array([s.stamp for s in following])
    assert np.all(np.diff(stamps) > 0)  # in order, each once
    assert np.max(np.diff(stamps)) < 1.5 * servo.period_s  # no hole a period and a half wide
    # each recorded sample lies on the line: joint a rises 0 -> 1 and b is -a mirrored about the middle
    first_joint = np.array([s.positions[0] for s in following])
    assert np.all(np.diff(first_joint) >= 0)
    for sample in hooks.recorded:
        assert sample.positions[1] == pytest.approx(-min(sample.positions[0], 1.0 - sample.positions[0]))


async def test_a_physics_simulation_gets_no_recorded_samples_from_a_late_tick() -> None:
    hooks = StallingRecorder()
    hooks.records_missed_samples = False  # the default: it steps the world and measures that itself
    _, result = await run_stalling(hooks, 0.05)
    assert result.completed and hooks.recorded == []
