"""The audit writer thread: writes records in call order and decides when they reach the disk.

Every record is written (``os.write``) by one thread, in the order the calls handed them over,
so the chain is the call order. When a record must be on disk depends on its durability class:

- `Durability.NOW` — actuating calls, approval questions and answers, refusals of actuating
  calls, e-stops, resets, start-up and shutdown: the batch it is in is fsync-ed before any
  caller of that batch is answered, so the reply waits for the disk.
- `Durability.WINDOW` — records of read-only calls: nobody waits. The record is written and
  fsync-ed at most ``window_s`` after it was handed over (sooner when a `NOW` record or a tail
  read follows: everything queued before it is written first, and one fsync covers it all). A
  crash can lose the read-only records of the last window, never a `NOW` record nor anything
  handed over before one.
- `Durability.NONE` — a job that writes nothing (reading the tail in call order).

A failed write or fsync is reported to the callers of the batch that wait for it, and logged for
records nobody waits for; either way the log is then broken (``sync`` marks it before raising),
so the next record is refused: the log fails closed instead of writing past a hole.
"""

from __future__ import annotations

import asyncio
import collections
import concurrent.futures
import enum
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from armwarden.handoff import settle_threadsafe

logger = logging.getLogger(__name__)

#: the longest group-commit window accepted [s]: beyond that "on disk soon" means little
MAX_COMMIT_WINDOW_S = 1.0


class Durability(enum.Enum):
    """When a record handed to the writer must be on disk (see the module docstring)."""

    NOW = "now"
    WINDOW = "window"
    NONE = "none"


@dataclass(frozen=True, slots=True)
class Job:
    """One piece of work for the writer: ``call`` runs on the writer thread; its result (or error)
    settles ``future`` on ``loop`` (or ``waiter``, from any thread) once the job's durability class
    allows; none of them: nobody waits."""

    call: Callable[[], Any]
    durability: Durability
    loop: asyncio.AbstractEventLoop | None = None
    future: asyncio.Future[Any] | None = None
    waiter: concurrent.futures.Future[Any] | None = None  # for a caller outside any event loop
    #: monotonic time it was handed over [s] (how long its record took to reach the disk: monitoring)
    queued_mono: float = field(default_factory=time.monotonic)


class Writer:
    """The writer thread of one log. ``sync`` fsyncs what was written (and raises on failure).

    Jobs wait in one deque, in call order. A job that someone waits for (or that must be on disk
    now) wakes the thread at once; a window record only arms the window's timer (the first of a
    window wakes the thread to start it) and is written with the others when the window closes —
    so a burst of state polls costs the event loop an append each, not a thread switch each.
    """

    def __init__(self, sync: Callable[[], None], window_s: float, name: str = "armwarden-audit",
                 on_durable: Callable[[str, float], None] | None = None) -> None:
        """`on_durable(durability, seconds)` is told, on this thread, how long each record took
        from hand-over to fsynced (monitoring: it must be quick, and its failures are only logged)."""
        self._sync = sync
        self._on_durable = on_durable
        self._window_s = window_s
        self._jobs: collections.deque[Job | None] = collections.deque()
        self._wake = threading.Event()
        self._urgent = False  # a job that must not wait for the window is queued
        self._armed = False  # window records are queued and the thread knows it
        self._thread = threading.Thread(target=self._drain, name=name, daemon=True)
        self._thread.start()

    def put(self, job: Job) -> None:
        self._jobs.append(job)
        if job.durability is Durability.WINDOW and self._window_s > 0:
            if not self._armed:
                self._armed = True
                self._wake.set()
            return
        self._urgent = True
        self._wake.set()

    def stop(self) -> None:
        """Write and fsync everything queued so far, then end the thread (joined unless called from it)."""
        self._jobs.append(None)
        self._urgent = True
        self._wake.set()
        if self._thread is not threading.current_thread():
            self._thread.join()

    # -- the thread -----------------------------------------------------------------------
    def _take_all(self) -> tuple[list[Job], bool]:
        """Everything queued, in order, up to a stop marker. Returns (jobs, stopping)."""
        self._armed = False  # before taking: a window record queued from now on arms a new window
        batch: list[Job] = []
        while True:
            try:
                job = self._jobs.popleft()
            except IndexError:
                return batch, False
            if job is None:
                return batch, True
            batch.append(job)

    def _drain(self) -> None:
        deadline: float | None = None  # when the window records queued so far must be on disk
        while True:
            self._wake.wait(None if deadline is None else max(0.0, deadline - time.monotonic()))
            self._wake.clear()  # before looking: a job queued from now on wakes the thread again
            if not self._urgent:
                if deadline is None:
                    if self._armed:
                        deadline = time.monotonic() + self._window_s  # the first record of a window
                    continue
                if time.monotonic() < deadline:
                    continue
            # reset only when everything queued is about to be taken: a flag set meanwhile is kept
            # (its job is taken now or on the next pass), never lost
            self._urgent = False
            batch, stopping = self._take_all()
            deadline = None
            outcomes = []
            for job in batch:
                try:
                    outcomes.append((job, job.call(), False))
                except BaseException as exc:  # handed back to the awaiting caller
                    outcomes.append((job, exc, True))
            if any(not failed and job.durability is not Durability.NONE for job, _, failed in outcomes):
                try:
                    self._sync()  # one fsync covers everything written so far
                except BaseException as exc:  # nothing of this batch is known to be on disk
                    outcomes = [(job, exc, True) for job, *_ in outcomes]
            durable_mono = time.monotonic()
            self._answer(outcomes)
            self._report_durable(outcomes, durable_mono)
            if stopping:
                return

    def _report_durable(self, outcomes: list[tuple[Job, Any, bool]], durable_mono: float) -> None:
        """After the callers are answered: how long each written record took to reach the disk."""
        if self._on_durable is None:
            return
        try:
            for job, written, failed in outcomes:  # a record's job returns it; a flush's barrier returns None
                if not failed and written is not None and job.durability is not Durability.NONE:
                    self._on_durable(job.durability.value, durable_mono - job.queued_mono)
        except Exception:  # monitoring must never stop the writer
            logger.exception("audit writer: reporting write latency failed")

    @staticmethod
    def _answer(outcomes: list[tuple[Job, Any, bool]]) -> None:
        for job, outcome, failed in outcomes:
            if job.waiter is not None:
                if failed:
                    job.waiter.set_exception(outcome)
                else:
                    job.waiter.set_result(outcome)
            elif job.loop is None or job.future is None:  # nobody waits: a failure is only logged
                if failed:
                    logger.error("audit record could not be written: %s", outcome)
            elif failed:
                settle_threadsafe(job.loop, job.future, error=outcome)
            else:
                settle_threadsafe(job.loop, job.future, outcome)


__all__ = ["MAX_COMMIT_WINDOW_S", "Durability", "Job", "Writer"]
