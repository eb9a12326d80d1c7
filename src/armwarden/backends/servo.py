"""The servo core: a control thread that follows a trajectory tick by tick, and its asyncio side.

A backend whose arm is driven by a periodic loop (the fake's kinematic arm, a MuJoCo physics
thread, a CAN servo loop) composes one `ServoLoop` and implements the few `ServoHooks` that
differ: what a tick prepares (kinematics, a physics step), how a setpoint is commanded (publish
it, write actuator targets, send frames) and how the arm is held still.

Each tick, on the servo thread: take the submitted execution, sample its trajectory at
`elapsed × speedup` (the same linear interpolation the envelope checked, so the last setpoint
is exactly the goal), let the backend prepare it outside the lock, then command and publish it
under the lock *only if no stop landed meanwhile*. A stop (`hold`) runs in whichever thread
calls it: under the lock it bumps the stop sequence number, ends the running or submitted
execution as "stopped", and commands a hold at the last commanded positions with zero velocity.
So no tick computed before a stop can be commanded after it, and nothing waits for the servo
thread to be scheduled (under load, it may wait milliseconds for the interpreter lock).

Results cross into asyncio only through `armwarden.handoff.settle_threadsafe`. If the servo
thread dies, every submitted execution fails and later ones are refused with the reason. If it
hangs (alive, no tick), the backend's watchdog finds it by its tick count (`heartbeat`) and the
stop comes from another thread: `hold` needs only the lock, which a tick holds just to take its
execution and to command, never while it prepares.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import anyio
import numpy as np

from armwarden.backends.arm_state import ArmEvent
from armwarden.backends.base import Backend
from armwarden.backends.realtime import make_current_thread_realtime
from armwarden.backends.ticktiming import TickTiming
from armwarden.backends.values import PREEMPTED, ExecutionResult, ProgressCallback
from armwarden.backends.watchdog import Heartbeat, stall_deadline_s
from armwarden.core.errors import BackendError
from armwarden.core.trajectory import JointTrajectory
from armwarden.handoff import settle_threadsafe

logger = logging.getLogger(__name__)

#: minimum interval between two progress callbacks [s] (≤ 50 Hz)
PROGRESS_PERIOD_S = 0.02
#: the most control periods a late tick records for a hook that asks for them
#: (`ServoHooks.records_missed_samples`): a stall longer than that (a second at 1 kHz) leaves its
#: gap in the stamps
MAX_MISSED_SAMPLES = 1000
#: servo period while nothing moves [s]; stops and executions wake the loop at once
IDLE_PERIOD_S = 0.01
#: how long `shutdown` waits for the servo thread to finish [s]
JOIN_TIMEOUT_S = 2.0
#: `start` fails if the servo thread has not completed its first tick by then [s]
FIRST_TICK_TIMEOUT_S = 5.0


@dataclass(frozen=True)
class Setpoint:
    """What the servo loop commands at one tick; arrays are read-only.

    `positions` [rad], `velocities` [rad/s], `stamp` on the monotonic clock [s]; `following`: a
    sample of a running trajectory (not a hold); `extra` is what `ServoHooks.servo_prepare`
    computed for it (e.g. the TCP position), kept with the sample; `spread`: the trajectory's
    motion as a physical arm would follow it (`spread_motion`) while following, None otherwise
    (a simulated arm's measured velocity and torque; the command's velocity is `velocities`, the
    exact slope of the linear segment the position is on).
    """

    positions: np.ndarray
    velocities: np.ndarray
    stamp: float
    following: bool = False
    extra: Any = None
    spread: SpreadMotion | None = None


class ServoHooks:
    """The backend side of a `ServoLoop`. Defaults do nothing; override what the backend needs."""

    #: a kinematic arm is on its trajectory whatever the host does, and its sensors sample it every
    #: control period: a tick that comes late records the samples of the periods it skipped
    #: (`servo_record`), so a stalled thread leaves no hole in what the contact observer integrates.
    #: Not for a physics simulation: it steps the world itself and measures what it stepped.
    records_missed_samples: bool = False

    def servo_measure_missed(self, setpoint: Setpoint) -> Any:
        """Servo thread, outside the lock: what a sample of a skipped period needs (the measured
        torques), kept as its `extra`. Not `servo_prepare`: a late tick may record hundreds of
        these, and each must cost microseconds, not a whole tick's work (a backend whose prepare
        was slow fell further behind with every tick it recorded, until its watchdog fired)."""
        return None

    def servo_record(self, setpoint: Setpoint) -> None:
        """Servo thread, under the lock, before a late tick's `servo_command`: publish the sample
        of a control period the tick skipped (only where `records_missed_samples`), its `extra`
        from `servo_measure_missed`. Must be quick."""

    def servo_prepare(self, setpoint: Setpoint) -> Any:
        """Servo thread, outside the lock: the slow part of a tick (kinematics, a physics step).
        The result is stored as `setpoint.extra`. May be skipped if a stop lands meanwhile."""
        return None

    def servo_command(self, setpoint: Setpoint) -> None:
        """Servo thread, under the lock, only if no stop landed since the tick began: command
        `setpoint` (publish it, write actuator targets, send frames). Must be quick."""

    def servo_hold_positions(self, commanded: np.ndarray) -> np.ndarray:
        """Any thread, under the lock, on every stop: where to hold [rad]. Default: the last
        commanded positions (a kinematic arm is exactly there); a physical arm returns its
        measured positions, so a stop does not pull it back to where it was told to be."""
        return commanded

    def servo_hold(self, setpoint: Setpoint) -> None:
        """Any thread, under the lock, on every stop: command standing still at
        `setpoint.positions` (velocities are zero). Must be quick; raising reports a failed stop."""

    def servo_held(self, stamp: float) -> None:
        """Any thread, under the lock, once a stop's hold is commanded: when [s, monotonic]."""

    def servo_following(self) -> None:
        """Caller's thread, under the lock, as a trajectory is handed over; raising refuses it."""

    def servo_finished(self) -> None:
        """Servo thread, under the lock, once a trajectory's last setpoint is commanded."""

    def servo_failed(self, error: BaseException) -> None:
        """Servo thread: the loop died with `error` (called once, before executions are failed)."""


class ServoBackend(Backend, ServoHooks):
    """A backend a `ServoLoop` drives (fake, MuJoCo, CAN): its hold is when a stop took effect, and
    hand-over, end and hold move the arm state, under the loop's lock. A backend that damps reports
    its own recovery before the hand-over (CAN's `_recover`): a hand-over while damped or faulted
    is refused by the arm state, never taken as a recovery."""
    reports_motion_events = True

    def servo_held(self, stamp: float) -> None:
        self._record_stop_stamp(stamp)
        self._arm_event(ArmEvent.STOP)

    def servo_following(self) -> None:
        self._arm_event(ArmEvent.EXECUTE)

    def servo_finished(self) -> None:
        self._arm_event(ArmEvent.FINISH)


@dataclass(eq=False)
class _Execution:
    """One trajectory handed to the servo thread, and the future the thread settles."""

    trajectory: JointTrajectory
    loop: asyncio.AbstractEventLoop
    future: asyncio.Future[ExecutionResult]
    start_time: float | None = None  # perf_counter of the tick that started it
    fraction: float = 0.0  # progress in [0, 1], written by the servo thread


def segment_velocity(trajectory: JointTrajectory, t: float) -> np.ndarray:
    """Joint velocity [rad/s] of the linear segment the trajectory is on at time `t` [s]."""
    times = trajectory.times
    if t <= 0.0 or len(times) < 2 or t >= times[-1]:
        return np.zeros(trajectory.positions.shape[1])
    k = int(np.searchsorted(times, t, side="right")) - 1
    span = times[k + 1] - times[k]
    if span <= 0:
        return np.zeros(trajectory.positions.shape[1])
    return (trajectory.positions[k + 1] - trajectory.positions[k]) / span


@dataclass(frozen=True)
class SpreadMotion:
    """The trajectory's velocity [rad/s] and acceleration [rad/s²] with each waypoint's velocity
    step spread between the midpoints of the segments on either side of it (`spread_motion`)."""

    velocities: np.ndarray
    accelerations: np.ndarray


def spread_motion(trajectory: JointTrajectory, t: float) -> SpreadMotion:
    """The motion of a physical arm that follows the trajectory smoothly, at time `t` [s].

    A piecewise-linear path changes velocity only in impulses at its waypoints, which no motor
    delivers and which a sampled torque reading would see as spikes, or miss (a momentum
    observer then sees momentum jump with no torque behind it). Spread instead: the velocity is
    piecewise linear through each segment's velocity at the segment's midpoint (from rest at the
    start, to rest at the end), never outside the velocities of the segments around it, and the
    acceleration is its slope, so each integrates exactly to the other."""
    times, positions = trajectory.times, trajectory.positions
    zero = np.zeros(positions.shape[1])
    if t <= 0.0 or len(times) < 2 or t >= times[-1]:
        return SpreadMotion(zero, zero)
    last = len(times) - 2  # the last segment

    def knot(j: int) -> tuple[float, np.ndarray]:
        """(time, velocity) where the spread velocity equals segment j's (rest beyond the ends)."""
        if j < 0:
            return 0.0, zero
        if j > last:
            return float(times[-1]), zero
        span = times[j + 1] - times[j]
        return float(times[j] + times[j + 1]) / 2, (positions[j + 1] - positions[j]) / span if span > 0 else zero

    k = int(np.searchsorted(times, t, side="right")) - 1
    (t0, v0), (t1, v1) = (knot(k - 1), knot(k)) if t < knot(k)[0] else (knot(k), knot(k + 1))
    if t1 <= t0:
        return SpreadMotion(v0, zero)
    slope = (v1 - v0) / (t1 - t0)
    return SpreadMotion(v0 + slope * (t - t0), slope)


def frozen(array: Any) -> np.ndarray:
    """A read-only float copy: published samples can be shared across threads without a lock."""
    out = np.array(array, dtype=float)
    out.setflags(write=False)
    return out


class ServoLoop:
    """A periodic servo thread following at most one trajectory at a time (see the module docstring).

    `q_start` [rad] is the first held position; `period_s` the tick period while moving [s];
    `speedup` scales trajectory time (2 = twice as fast); `idle_period_s` is the tick period while
    nothing moves [s] (a physics simulation ticks at `period_s` always: the world keeps moving);
    `name` prefixes error messages; `realtime_priority` (1–99) runs the thread under SCHED_FIFO
    (`start` fails, saying why, if the system refuses it).
    """

    def __init__(
        self, hooks: ServoHooks, q_start: Any, *, period_s: float, speedup: float = 1.0,
        idle_period_s: float = IDLE_PERIOD_S, name: str = "servo", realtime_priority: int | None = None,
    ) -> None:
        if not (np.isfinite(period_s) and period_s > 0):
            raise ValueError(f"period_s must be a positive number of seconds, got {period_s}")
        if not (np.isfinite(speedup) and speedup > 0):
            raise ValueError(f"speedup must be a positive number, got {speedup}")
        self.hooks = hooks
        self.period_s = float(period_s)
        self.speedup = float(speedup)
        self.idle_period_s = max(self.period_s, float(idle_period_s))
        self.name = name
        self.realtime_priority = realtime_priority
        #: ticks run so far (the thread's heartbeat: the backend's watchdog reads it, see `heartbeat`)
        self.tick_count = 0
        #: when each tick began against when it was scheduled (rate, deadline misses, jitter)
        self.timing = TickTiming(self.period_s)
        #: why the thread died, if it did
        self.error: BaseException | None = None
        self.thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._shutdown = False
        self._pending: _Execution | None = None
        self._active: _Execution | None = None
        self._stop_seq = 0  # bumped by every hold: a tick computed before it is not commanded
        self._refusing: str | None = None  # set once the thread is gone (why)
        q = frozen(q_start)
        self._still = frozen(np.zeros(q.shape))
        setpoint = Setpoint(q, self._still, time.monotonic())
        self._latest = replace(setpoint, extra=hooks.servo_prepare(setpoint))

    # ---------------------------------------------------------------- reading
    @property
    def latest(self) -> Setpoint:
        """The last commanded setpoint (replaced whole by each tick or hold; no lock needed)."""
        return self._latest

    def heartbeat(self, worker: str) -> Heartbeat:
        """The watchdog's view of this loop, the backend's thread `worker`: its tick count, which
        must move within `stall_deadline_s` of its longest period (the idle one)."""
        return Heartbeat(worker, lambda: self.tick_count, stall_deadline_s(self.idle_period_s))

    @property
    def busy(self) -> bool:
        """An execution is submitted or running."""
        return self._pending is not None or self._active is not None

    def require_running(self) -> None:
        """Raise `BackendError` unless the servo thread is alive and healthy."""
        if self.error is not None:
            raise BackendError(f"{self.name} control thread failed: {self.error!r}")
        thread = self.thread
        if thread is None or not thread.is_alive():
            raise BackendError(f"{self.name} control thread is not running")

    # ---------------------------------------------------------------- lifecycle (event loop)
    async def start(self, thread_name: str | None = None) -> None:
        """Start the servo thread; return once it has completed a tick of its own."""
        self.thread = threading.Thread(target=self._run, name=thread_name or f"armwarden-{self.name}-servo", daemon=True)
        self.thread.start()
        deadline = time.monotonic() + FIRST_TICK_TIMEOUT_S
        while self.tick_count == 0:
            self.require_running()
            if time.monotonic() > deadline:
                raise BackendError(f"{self.name}: the control thread did not tick within {FIRST_TICK_TIMEOUT_S} s")
            await asyncio.sleep(0.0005)

    async def shutdown(self) -> None:
        """Stop the servo thread (without holding: stop first) and fail whatever still waits."""
        self._shutdown = True
        self._wake.set()
        thread = self.thread
        if thread is not None and thread.is_alive():
            await anyio.to_thread.run_sync(thread.join, JOIN_TIMEOUT_S)
            if thread.is_alive():
                logger.error("%s: control thread did not stop within %.1f s", self.name, JOIN_TIMEOUT_S)
        self.fail_executions(BackendError(f"{self.name} closed"))

    # ---------------------------------------------------------------- motion
    async def run(
        self, trajectory: JointTrajectory, progress: ProgressCallback, *, hold_on_exit: bool = True,
        preempted: Callable[[], bool] | None = None,
    ) -> ExecutionResult:
        """Follow `trajectory` until it completes or a stop ends it; report progress ≤ 50 Hz.

        `preempted` (the backend's `_stop_landed`) is asked under the lock every hold takes, as the
        trajectory is handed over: if a stop came first, nothing moves and the result is "stopped".
        If the caller is cancelled (or `progress` raises), the arm is held before the exception
        propagates, unless `hold_on_exit` is false (a fault injection that loses stops).
        """
        self.require_running()
        loop = asyncio.get_running_loop()
        execution = _Execution(trajectory, loop, loop.create_future())
        with self._lock:
            if self._refusing is not None:  # the thread died after the check above
                raise BackendError(f"{self.name}: {self._refusing}")
            if self.busy:
                raise BackendError(f"{self.name} is already executing a trajectory; one execution at a time")
            if preempted is not None and preempted():
                return ExecutionResult(False, PREEMPTED, self._latest.positions.copy())
            self.hooks.servo_following()
            self._pending = execution
        self._wake.set()
        reported = -1.0
        try:
            while True:
                done, _ = await asyncio.wait((execution.future,), timeout=PROGRESS_PERIOD_S)
                if done:
                    break
                self.require_running()  # never wait on a thread that is gone
                if execution.fraction != reported:
                    reported = execution.fraction
                    progress(reported)
            result = execution.future.result()
            if result.completed and reported != 1.0:
                progress(1.0)
            return result
        except BaseException:
            if hold_on_exit:
                self.hold()
            execution.future.cancel()
            raise

    def hold(self) -> Setpoint:
        """Stop commanding motion, now, from the calling thread (any thread). Returns the hold."""
        with self._lock:
            self._stop_seq += 1
            stopped = [e for e in (self._active, self._pending) if e is not None]
            self._active = self._pending = None
            setpoint = replace(self._latest, velocities=self._still, stamp=time.monotonic(), following=False,
                               spread=None)
            try:
                setpoint = replace(setpoint, positions=frozen(self.hooks.servo_hold_positions(setpoint.positions)))
                self.hooks.servo_hold(setpoint)
            except BaseException as exc:
                failure = exc
            else:
                failure = None
                self._latest = setpoint
                self.hooks.servo_held(setpoint.stamp)
        if failure is not None:
            for execution in stopped:
                settle_threadsafe(execution.loop, execution.future, error=BackendError(f"{self.name}: stop failed: {failure}"))
            self._wake.set()
            raise failure
        for execution in stopped:
            settle_threadsafe(execution.loop, execution.future, ExecutionResult(False, "stopped", setpoint.positions.copy()))
        self._wake.set()  # the idle period starts now
        return setpoint

    def fail_executions(self, error: BackendError) -> None:
        """Fail every submitted execution and refuse later ones (the servo thread is gone)."""
        with self._lock:
            self._refusing = str(error)
            pending = [e for e in (self._pending, self._active) if e is not None]
            self._pending = self._active = None
        for execution in pending:
            settle_threadsafe(execution.loop, execution.future, error=error)

    # ---------------------------------------------------------------- the servo thread
    def _run(self) -> None:
        period = self.period_s
        try:
            if self.realtime_priority is not None:
                make_current_thread_realtime(self.realtime_priority)
            next_tick = time.perf_counter()
            while not self._shutdown:
                self.timing.record(time.perf_counter(), next_tick)
                self._tick()
                # idle: tick slowly; a stop or a new execution wakes the loop at once, and the idle
                # loop takes the interpreter lock from planning less often
                next_tick += period if self.busy else self.idle_period_s
                delay = next_tick - time.perf_counter()
                if delay < -10 * period:  # fell far behind (machine stalled): resynchronise
                    next_tick = time.perf_counter()
                elif delay > 0 and self._wake.wait(delay):
                    self._wake.clear()  # woken early by a stop or a new execution: tick now
                    next_tick = time.perf_counter()
        except BaseException as exc:  # a dead servo loop must never look like a healthy one
            logger.exception("%s: control thread failed", self.name)
            self.error = exc
            try:
                self.hooks.servo_failed(exc)
            except Exception:  # pragma: no cover - reporting must not hide the failure
                logger.exception("%s: servo_failed hook raised", self.name)
        finally:
            self.fail_executions(BackendError(f"{self.name} control thread stopped"))

    def _tick(self) -> None:
        with self._lock:
            if self._active is None and self._pending is not None:
                self._active, self._pending = self._pending, None
            execution = self._active
            stop_seq = self._stop_seq
            held = self._latest
        now = time.perf_counter()
        stamp = time.monotonic()
        self.tick_count += 1

        missed: list[Setpoint] = []
        if execution is None:
            setpoint, completed, fraction = Setpoint(held.positions, self._still, stamp), False, 0.0
        else:
            if execution.start_time is None:
                execution.start_time = now
            t = (now - execution.start_time) * self.speedup
            setpoint, completed, fraction = self._following(execution.trajectory, t, stamp)
            if self.hooks.records_missed_samples:
                missed = self._missed_samples(execution.trajectory, t, held.stamp if held.following else None, stamp)
        setpoint = self._prepared(setpoint)

        with self._lock:
            if self._stop_seq != stop_seq:
                return  # a stop landed while this tick was computed: it already commanded the hold
            for sample in missed:
                self.hooks.servo_record(sample)
            self.hooks.servo_command(setpoint)
            self._latest = setpoint
            if execution is not None:
                execution.fraction = fraction
                if completed:
                    self._active = None
                    self.hooks.servo_finished()
        if completed and execution is not None:
            settle_threadsafe(execution.loop, execution.future, ExecutionResult(True, "completed", setpoint.positions.copy()))

    def _prepared(self, setpoint: Setpoint) -> Setpoint:
        extra = self.hooks.servo_prepare(setpoint)
        if extra is None:  # (dataclasses.replace costs microseconds a tick; most hooks return None)
            return setpoint
        return replace(setpoint, extra=extra)

    @staticmethod
    def _following(trajectory: JointTrajectory, t: float, stamp: float) -> tuple[Setpoint, bool, float]:
        """The setpoint at trajectory time `t` [s], stamped `stamp`; whether it is the goal; the
        fraction of the trajectory done."""
        duration = trajectory.duration_s
        if t >= duration:
            goal = frozen(trajectory.goal)
            return Setpoint(goal, frozen(np.zeros(goal.shape)), stamp, following=True), True, 1.0
        motion = spread_motion(trajectory, t)
        spread = SpreadMotion(frozen(motion.velocities), frozen(motion.accelerations))
        setpoint = Setpoint(frozen(trajectory.sample(t)), frozen(segment_velocity(trajectory, t)), stamp,
                            following=True, spread=spread)
        return setpoint, False, t / duration

    def _missed_samples(self, trajectory: JointTrajectory, t: float, previous_stamp: float | None,
                        stamp: float) -> list[Setpoint]:
        """The samples, measured (`servo_measure_missed`), of the control periods between the previous following tick
        (`previous_stamp`; None: this tick starts the trajectory) and this one at `stamp`, where it
        came more than a period and a half late; at most `MAX_MISSED_SAMPLES`, the latest ones."""
        if previous_stamp is None:
            return []
        count = min(int((stamp - previous_stamp) / self.period_s - 0.5), MAX_MISSED_SAMPLES)
        samples = []
        for k in range(count, 0, -1):  # oldest first
            at = stamp - k * self.period_s
            t_at = t - k * self.period_s * self.speedup
            if t_at >= 0.0 and at > previous_stamp:
                sample = self._following(trajectory, t_at, at)[0]
                samples.append(replace(sample, extra=self.hooks.servo_measure_missed(sample)))
        return samples


__all__ = ["FIRST_TICK_TIMEOUT_S", "IDLE_PERIOD_S", "JOIN_TIMEOUT_S", "MAX_MISSED_SAMPLES", "PROGRESS_PERIOD_S", "ServoBackend",
           "ServoHooks", "ServoLoop", "Setpoint", "SpreadMotion", "frozen", "segment_velocity", "spread_motion"]
