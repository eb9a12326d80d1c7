"""The audit writer thread: writes records in call order and decides when they reach the disk.

Every record is written (``os.write``) by one thread, in the order the calls handed them over,
so the chain is the call order. When a record must be on disk depends on its durability class:

- `Durability.NOW` — actuating calls, approval questions and answers, refusals of actuating
  calls, e-stops, resets, start-up and shutdown: the batch it is in is fsync-ed before any
  caller of that batch is answered, so the reply waits for the disk.
- `Durability.WINDOW` — records of read-only calls: nobody waits. The record is written at once
  and fsync-ed at most ``window_s`` after that write (sooner when a `NOW` record follows: one
  fsync covers everything written before it). A power loss or kernel crash can lose the
  read-only records of the last window, never a `NOW` record nor anything before one.
- `Durability.NONE` — a job that writes nothing (reading the tail in call order).

A failed fsync is reported to the callers of the batch that wait for it; a failed fsync of
window records nobody waits for is logged and leaves the log broken (``on_sync`` raises after
marking it), so the next record is refused: the log fails closed instead of writing past a hole.
"""

from __future__ import annotations

import asyncio
import enum
import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
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
    settles ``future`` on ``loop`` once the job's durability class allows (both None: nobody waits)."""

    call: Callable[[], Any]
    durability: Durability
    loop: asyncio.AbstractEventLoop | None = None
    future: asyncio.Future[Any] | None = None


class Writer:
    """The writer thread of one log. ``sync`` fsyncs what was written (and raises on failure)."""

    def __init__(self, sync: Callable[[], None], window_s: float, name: str = "armwarden-audit") -> None:
        self._sync = sync
        self._window_s = window_s
        self._jobs: queue.SimpleQueue[Job | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._drain, name=name, daemon=True)
        self._thread.start()

    def put(self, job: Job) -> None:
        self._jobs.put(job)

    def stop(self) -> None:
        """Write and fsync everything queued so far, then end the thread (joined unless called from it)."""
        self._jobs.put(None)
        if self._thread is not threading.current_thread():
            self._thread.join()

    # -- the thread -----------------------------------------------------------------------
    def _next_batch(self, deadline: float | None) -> tuple[list[Job], bool]:
        """Wait for work (until ``deadline`` when window records await their fsync), then take
        everything queued. Returns (jobs, stopping); no jobs and not stopping = the window closed."""
        try:
            first = self._jobs.get() if deadline is None else self._jobs.get(timeout=max(0.0, deadline - time.monotonic()))
        except queue.Empty:
            return [], False
        if first is None:
            return [], True
        batch = [first]
        while True:
            try:
                more = self._jobs.get_nowait()
            except queue.Empty:
                return batch, False
            if more is None:
                return batch, True
            batch.append(more)

    def _drain(self) -> None:
        deadline: float | None = None  # when the oldest unsynced window record must be on disk
        while True:
            batch, stopping = self._next_batch(deadline)
            outcomes = []
            for job in batch:
                try:
                    outcomes.append((job, job.call(), False))
                except BaseException as exc:  # handed back to the awaiting caller
                    outcomes.append((job, exc, True))
            written = [job.durability for job, _, failed in outcomes if not failed]
            if Durability.WINDOW in written and deadline is None:
                deadline = time.monotonic() + self._window_s
            if Durability.NOW in written or (deadline is not None and (stopping or not batch)):
                deadline = None  # one fsync covers everything written so far
                try:
                    self._sync()
                except BaseException as exc:  # nothing of this batch is known to be on disk
                    outcomes = [(job, exc, True) for job, *_ in outcomes]
                    if not outcomes:  # the window closed: nobody to tell but the log
                        logger.error("audit records of the last commit window could not be fsync-ed: %s", exc)
            self._answer(outcomes)
            if stopping:
                return

    @staticmethod
    def _answer(outcomes: list[tuple[Job, Any, bool]]) -> None:
        for job, outcome, failed in outcomes:
            if job.loop is None or job.future is None:  # nobody waits: a failure is only logged
                if failed:
                    logger.error("audit record could not be written: %s", outcome)
            elif failed:
                settle_threadsafe(job.loop, job.future, error=outcome)
            else:
                settle_threadsafe(job.loop, job.future, outcome)


__all__ = ["MAX_COMMIT_WINDOW_S", "Durability", "Job", "Writer"]
