"""The watchdog of a backend's own threads: a thread that stops making progress is found, not just
one that ends.

A servo loop blocked in a driver call, a physics step that never returns, a ROS callback that
waits forever: the thread is alive, so nothing that looks for a dead thread notices, yet its
duties (state, health watch, motion, the stop it would stream) are no longer done. Found by review:
the servo thread blocked for 5 s (fake, CAN, MuJoCo) and the ROS executor blocked by one callback
left `get_robot_state` answering stale while `get_safety_status` said all was well. A watchdog on
the worker's own thread (the ROS `_watch` timer) hangs with it, so this one runs on a thread of
its own, one per backend.

Each worker exposes a progress counter (`Heartbeat.count`: a servo loop's ticks, the ROS
executor's heartbeat-timer turns) and a deadline (`stall_deadline_s`: 20 of its periods, at least
0.25 s, never above `STALL_LIMIT_S`). The watchdog samples the counters every `check_period_s`;
a counter that has not moved for longer than its deadline is a hang, reported once
(`on_hang`), which the backend treats exactly like the thread's death (`Backend._worker_hung`).

Time the watchdog itself was not scheduled is not held against a worker: each check credits at
most two check periods of stall, so a stall of the whole process (a loaded host, a paused VM)
delays the verdict instead of inventing one. A hang that holds the interpreter lock (a C call that
never releases it) stops this thread too; only a watchdog outside the process could see that.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

logger = logging.getLogger(__name__)

#: the longest a worker may make no progress before it counts as hung [s]: the Guard's
#: `MAX_STATE_AGE_S` (`armwarden.guard.readings`), so a hung thread is reported as the cause before
#: the stale state it leaves behind is what refuses (a test holds the two equal)
STALL_LIMIT_S = 0.5
#: the shortest deadline [s]: scheduling noise on a loaded host is not a hang
MIN_STALL_DEADLINE_S = 0.25
#: how many of its periods a worker may miss before it counts as hung
STALL_PERIODS = 20
#: checks per shortest deadline
CHECKS_PER_DEADLINE = 8
#: how long `stop` waits for the watchdog thread to end [s] (it may be issuing a hang's stop)
JOIN_TIMEOUT_S = 2.0

#: told (on the watchdog thread) that `worker` made no progress for `stalled_s` [s] (past `deadline_s`)
HangListener = Callable[[str, float, float], object]


def stall_deadline_s(period_s: float) -> float:
    """The hang deadline [s] of a worker that makes progress at least every `period_s` [s]:
    `STALL_PERIODS` periods, at least `MIN_STALL_DEADLINE_S`. `ValueError` when that exceeds
    `STALL_LIMIT_S` (such a worker's progress cannot be judged within the state's max age)."""
    if not (isinstance(period_s, (int, float)) and 0 < period_s < float("inf")):
        raise ValueError(f"a worker's period must be a positive number of seconds, got {period_s!r}")
    deadline = max(STALL_PERIODS * float(period_s), MIN_STALL_DEADLINE_S)
    if deadline > STALL_LIMIT_S:
        raise ValueError(f"a worker with a {period_s:g} s period gets a {deadline:g} s hang deadline, above the "
                         f"{STALL_LIMIT_S:g} s limit (the state's max age): give it a shorter period")
    return deadline


@dataclass(frozen=True)
class Heartbeat:
    """How the watchdog sees the backend thread `worker` make progress: `count()` grows with every
    turn it completes (read from the watchdog thread: a plain int read); `deadline_s`: no growth
    for longer than this [s] is a hang."""

    worker: str
    count: Callable[[], int]
    deadline_s: float

    def __post_init__(self) -> None:
        if not 0 < self.deadline_s <= STALL_LIMIT_S:
            raise ValueError(f"{self.worker}: hang deadline {self.deadline_s!r} s outside (0, {STALL_LIMIT_S:g}] s")


@dataclass
class _Watched:
    """What the watchdog last saw of one worker (under the watchdog's lock)."""

    heartbeat: Heartbeat
    count: int
    progress_at: float  # monotonic time [s] the count was last seen to move
    stalled_s: float = 0.0  # stall credited since then [s] (see the module docstring)
    hung: bool = False  # reported (once)


class WorkerWatchdog:
    """Watches `heartbeats` from a thread of its own (see the module docstring); `on_hang` is told
    of each hung worker once. `clock` is the monotonic clock [s] (tests step it by hand)."""

    def __init__(self, heartbeats: Sequence[Heartbeat], on_hang: HangListener, *, name: str = "backend",
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not heartbeats:
            raise ValueError("a watchdog needs at least one heartbeat")
        workers = [h.worker for h in heartbeats]
        if len(set(workers)) != len(workers):
            raise ValueError(f"heartbeats name a worker twice: {workers}")
        self.name = name
        self.on_hang = on_hang
        self._clock = clock
        #: how often the counters are sampled [s]
        self.check_period_s = min(h.deadline_s for h in heartbeats) / CHECKS_PER_DEADLINE
        #: the longest deadline [s]
        self.longest_deadline_s = max(h.deadline_s for h in heartbeats)
        now = clock()
        self._lock = threading.Lock()  # the records: the watchdog thread checks, the event loop asks
        self._watched = {h.worker: _Watched(h, h.count(), now) for h in heartbeats}
        self._last_check = now
        self._stopping = threading.Event()
        self.thread: threading.Thread | None = None

    # ---------------------------------------------------------------- the verdict (pure: tests call it)
    def check(self) -> list[tuple[str, float, float]]:
        """Sample every counter now; the workers newly found hung, as (worker, stalled [s], deadline [s])."""
        now = self._clock()
        hung: list[tuple[str, float, float]] = []
        with self._lock:
            credit = min(now - self._last_check, 2 * self.check_period_s)
            self._last_check = now
            for watched in self._watched.values():
                count = watched.heartbeat.count()
                if count != watched.count:
                    watched.count, watched.progress_at, watched.stalled_s = count, now, 0.0
                    continue
                watched.stalled_s += credit
                if not watched.hung and watched.stalled_s > watched.heartbeat.deadline_s:
                    watched.hung = True
                    hung.append((watched.heartbeat.worker, now - watched.progress_at, watched.heartbeat.deadline_s))
        return hung

    # ---------------------------------------------------------------- questions from other threads
    def counts(self) -> dict[str, int]:
        """Every worker's counter now."""
        return {worker: watched.heartbeat.count() for worker, watched in self._watched.items()}

    def moved_since(self, counts: Mapping[str, int]) -> bool:
        """Every worker's counter has moved since `counts` (from `counts()`)."""
        return all(watched.heartbeat.count() != counts[worker] for worker, watched in self._watched.items())

    def quiet_s(self, worker: str) -> float:
        """How long [s] `worker` has made no progress as far as the watchdog can tell now (0 if its
        counter moved since the last check)."""
        with self._lock:
            watched = self._watched[worker]
            if watched.heartbeat.count() != watched.count:
                return 0.0
            return max(0.0, self._clock() - watched.progress_at)

    # ---------------------------------------------------------------- the thread
    def start(self) -> None:
        self.thread = threading.Thread(target=self._run, name=f"armwarden-{self.name}-watchdog", daemon=True)
        self.thread.start()

    def stop(self) -> None:
        """End the watchdog thread (any thread but its own; safe twice and before `start`)."""
        self._stopping.set()
        thread = self.thread
        if thread is not None and thread is not threading.current_thread() and thread.is_alive():
            thread.join(JOIN_TIMEOUT_S)
            if thread.is_alive():
                logger.error("%s: the watchdog thread did not end within %g s", self.name, JOIN_TIMEOUT_S)

    def _run(self) -> None:
        while not self._stopping.wait(self.check_period_s):
            try:
                for worker, stalled_s, deadline_s in self.check():
                    if self._stopping.is_set():
                        return
                    self.on_hang(worker, stalled_s, deadline_s)
            except Exception:  # the watchdog must outlive a failing check or report: log, watch on
                logger.exception("%s: the watchdog's check failed", self.name)


__all__ = [
    "MIN_STALL_DEADLINE_S",
    "STALL_LIMIT_S",
    "STALL_PERIODS",
    "HangListener",
    "Heartbeat",
    "WorkerWatchdog",
    "stall_deadline_s",
]
