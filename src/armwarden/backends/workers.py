"""Supervision of a backend's own threads: a dead or hung worker stops the arm and is reported once.

The backend's own threads (a servo or physics loop, a ROS executor) are named in
`worker_threads`. One that ends while the backend is open calls `_worker_died` on its way out:
the e-stop's stop is issued (as far as the rest still can), the fault is reported once, and
from then on every call but stop and close is refused naming the dead thread (a thread never
comes back: only a restart recovers). `inject_worker_failure` is the test seam the conformance
suite kills each thread with; a worker calls `_worker_checkpoint` on its own thread every turn.

A thread that hangs (alive, no progress) is handled the same way (`_worker_hung`): every
worker has a `Heartbeat` (`_worker_heartbeats`: a progress counter and a deadline,
`armwarden.backends.watchdog`), watched from a thread of the backend's own that is none of
the workers; a counter still for longer than its deadline gets the e-stop's stop (issued
beside the watchdog, and not waited for past `stop_timeout_s`: a stop that needs the hung
thread must not keep the fault unreported) and the one report. `inject_worker_hang` is the
seam that hangs a thread at its next checkpoint.

`fault_behind_stale_data()` says whether the backend itself is why its data stopped (a dead
thread, a cell gone silent): the Guard asks when the force monitor finds no usable wrench, so
the cause is reported, not the symptom.

`WorkerSupervision` is the part of `Backend` that does this; it keeps the workers' state and
uses what `Backend` provides (its name, stop deadline, open state, e-stop and fault report).
"""

from __future__ import annotations

import abc
import logging
import threading
import time
from collections.abc import Callable, Sequence

import anyio

from armwarden.backends.watchdog import Heartbeat, WorkerWatchdog
from armwarden.core.errors import BackendError

logger = logging.getLogger(__name__)

#: the longest an injected hang (`WorkerSupervision.inject_worker_hang`) holds its thread [s]
INJECTED_HANG_LIMIT_S = 60.0
#: how often `fault_behind_stale_data` looks whether the backend's threads moved on [s]
PROGRESS_POLL_S = 0.005


class WorkerSupervision(abc.ABC):
    """The backend's own threads (`worker_threads`): their deaths, hangs and test seams."""

    # provided by `Backend`
    name: str
    stop_timeout_s: float
    _closed: bool
    _fault_report_lock: threading.Lock

    def __init__(self) -> None:
        self._dead_workers: dict[str, str] = {}  # worker thread -> why it is gone (see `_worker_died`)
        self._injected_failures: dict[str, BaseException] = {}  # worker -> what its next turn raises
        self._injected_hangs: dict[str, threading.Event] = {}  # worker -> what its next turn waits for
        self._watchdog: WorkerWatchdog | None = None  # watches the workers while open (see `_worker_hung`)

    @property
    @abc.abstractmethod
    def is_open(self) -> bool: ...

    @abc.abstractmethod
    def _require_open(self) -> None: ...

    @abc.abstractmethod
    def emergency_stop_now(self) -> None: ...

    @abc.abstractmethod
    def _report_fault(self, reason: str) -> None: ...

    #: the backend's own threads, by the names `inject_worker_failure` and `_worker_died` use
    worker_threads: tuple[str, ...] = ()

    @property
    def worker_failure(self) -> str | None:
        """Why a thread of the backend's own is gone (the first that died), or None."""
        dead = self._dead_workers
        return next(iter(dead.values())) if dead else None

    def _worker_died(self, worker: str, error: BaseException | None) -> None:
        """Any thread (the dying one, on its way out): the backend's thread `worker` ended before
        `close` (`error`: why; None: it returned when it must not). Issue the e-stop's
        stop as far as the rest of the backend still can, refuse every later call but stop and close
        (`_require_open`), and report the fault once: a dead thread's duties (state, health watch,
        motion) are silently not done any more, so the Guard must latch and record it."""
        why = "" if error is None else f" ({type(error).__name__}: {error})"
        reason = (f"backend {self.name}: the {worker} thread stopped{why}; nothing it did is done any more "
                  "(restart the daemon)")
        self._lose_worker(worker, reason, lambda: self._stop_after_loss(worker))

    def _worker_hung(self, worker: str, stalled_s: float, deadline_s: float) -> None:
        """Watchdog thread: `worker` made no progress for `stalled_s` [s], past its `deadline_s`.
        A hung thread's duties are not done any more either, so it is lost exactly like a dead one
        (`_worker_died`); the stop is issued beside the watchdog (`_stop_beside`), because it may
        need what the hung thread holds."""
        reason = (f"backend {self.name}: the {worker} thread made no progress for {stalled_s:.3f} s (its "
                  f"deadline: {deadline_s:g} s); it hangs, and nothing it did is done any more (restart the daemon)")
        self._lose_worker(worker, reason, lambda: self._stop_beside(worker))

    def _lose_worker(self, worker: str, reason: str, stop: Callable[[], str | None]) -> None:
        """`worker` is gone for good (`reason`): from now on every call but stop and close is
        refused naming it, `stop()` is issued (it returns why the arm's stop is not confirmed, or
        None), then the fault is reported once. Nothing while closing: that ends the threads on purpose."""
        if self._closed:
            return
        with self._fault_report_lock:
            if worker in self._dead_workers:
                return
            self._dead_workers[worker] = reason
        logger.error("%s", reason)
        unconfirmed = stop()
        self._report_fault(reason if unconfirmed is None else f"{reason}; {unconfirmed}")

    def _stop_after_loss(self, worker: str) -> None:
        """The e-stop's stop on the calling thread (the dying one); a failure is logged, not raised."""
        try:
            self.emergency_stop_now()
        except Exception as exc:  # the dead thread may have been the one that stops: report it all the same
            logger.error("backend %s: the stop after the %s thread died failed: %s", self.name, worker, exc)

    def _stop_beside(self, worker: str) -> str | None:
        """The e-stop's stop, issued on a helper thread and waited for at most `stop_timeout_s`:
        a stop that waits for something the hung `worker` holds (a lock, a driver call) must not
        keep the fault unreported. Returns why the stop is not confirmed, or None."""
        failure: list[BaseException] = []

        def stop() -> None:
            try:
                self.emergency_stop_now()
            except BaseException as exc:  # reported below, with the fault
                failure.append(exc)

        helper = threading.Thread(target=stop, name=f"armwarden-{self.name}-stop-after-hang", daemon=True)
        helper.start()
        helper.join(self.stop_timeout_s)
        if helper.is_alive():
            why = f"the stop did not return within {self.stop_timeout_s:g} s (it waits for the hung {worker} thread)"
        elif failure:
            why = f"the stop failed: {failure[0]}"
        else:
            return None
        logger.error("backend %s: %s", self.name, why)
        return why

    def _worker_heartbeats(self) -> Sequence[Heartbeat]:
        """Hook, called after `_open`: one `Heartbeat` for each of `worker_threads` (its progress
        counter and hang deadline; `ServoLoop.heartbeat` makes a servo loop's)."""
        return ()

    def _start_watchdog(self) -> None:
        """Watch every worker (see `_worker_hung`); `BackendError` if one has no heartbeat."""
        heartbeats = tuple(self._worker_heartbeats())
        watched = sorted(h.worker for h in heartbeats)
        if watched != sorted(self.worker_threads):
            raise BackendError(f"backend {self.name}: its threads {sorted(self.worker_threads)} are not the ones "
                               f"with a heartbeat {watched}: every thread of its own must be watched")
        if heartbeats:
            self._watchdog = WorkerWatchdog(heartbeats, self._worker_hung, name=self.name)
            self._watchdog.start()

    def _worker_quiet_s(self, worker: str) -> float:
        """How long [s] `worker` has made no progress, as far as the watchdog can tell now (0 when
        nothing watches it): a backend does not blame the outside world for data its own quiet
        thread did not take in."""
        watchdog = self._watchdog
        return 0.0 if watchdog is None else watchdog.quiet_s(worker)

    def inject_worker_failure(self, worker: str, error: BaseException) -> None:
        """Test seam (the conformance suite kills each thread): `worker` raises `error` on its own
        thread at its next turn (`_worker_checkpoint`) and dies through its real failure path."""
        self._require_worker(worker)
        self._injected_failures[worker] = error

    def inject_worker_hang(self, worker: str, release: threading.Event) -> None:
        """Test seam (the conformance suite hangs each thread): `worker` blocks at its next turn
        (`_worker_checkpoint`) until `release` is set (at most `INJECTED_HANG_LIMIT_S`), alive and
        making no progress, as in a deadlock or a driver call that never returns."""
        self._require_worker(worker)
        self._injected_hangs[worker] = release

    def _require_worker(self, worker: str) -> None:
        self._require_open()
        if worker not in self.worker_threads:
            names = ", ".join(self.worker_threads) or "none"
            raise BackendError(f"backend {self.name} has no thread {worker!r} (its threads: {names})")

    def _worker_checkpoint(self, worker: str) -> None:
        """Called by `worker` on its own thread every turn: blocks on a hang, raises a failure
        injected for it."""
        if self._injected_hangs:
            release = self._injected_hangs.pop(worker, None)
            if release is not None:
                release.wait(INJECTED_HANG_LIMIT_S)
        if self._injected_failures:
            error = self._injected_failures.pop(worker, None)
            if error is not None:
                raise error

    async def fault_behind_stale_data(self) -> str | None:
        """Whether the backend itself is why its data (the wrench, the joint states) stopped: the
        fault (a dead or hung thread, a cell gone silent), or None when it is not, as far as the
        backend can tell within its own fault-detection time. The Guard asks once the force monitor
        found no usable wrench and the arm is stopped: the cause is reported, not the symptom."""
        return self.worker_failure or await self._hang_behind_stale_data() or await self._fault_behind_stale_data()

    async def _hang_behind_stale_data(self) -> str | None:
        """Wait until every watched thread has moved on since this call (None: they live), or the
        watchdog found one hung (its fault). A thread still quiet after four times the longest
        deadline is named as the cause even without the watchdog's word (fail closed)."""
        watchdog = self._watchdog
        if watchdog is None or not self.is_open:
            return None
        counts = watchdog.counts()
        limit_s = 4 * watchdog.longest_deadline_s
        give_up = time.monotonic() + limit_s
        while not watchdog.moved_since(counts):
            if (failure := self.worker_failure) is not None:
                return failure
            if time.monotonic() > give_up:
                return (f"backend {self.name}: its threads ({', '.join(self.worker_threads)}) made no progress for "
                        f"{limit_s:g} s")
            await anyio.sleep(PROGRESS_POLL_S)
        return self.worker_failure

    async def _fault_behind_stale_data(self) -> str | None:
        """Hook of `fault_behind_stale_data` (default: no fault of its own besides a dead thread)."""
        return None


__all__ = ["INJECTED_HANG_LIMIT_S", "PROGRESS_POLL_S", "WorkerSupervision"]
