"""An actuation journal: a `CountingBackend` that also appends each counted call to a file.

`armwarden eval` starts the real daemon as a subprocess and must count what reached the backend
*below* the Guard, from outside the process: the daemon, asked with `serve --actuation-journal
FILE`, wraps its backend in this class, and every actuating call (an execute handed to the
backend, gripper move/grasp/home, controller switch, collision thresholds, error recovery) and
every stop (marked as such) becomes one JSON line ``{"t": <monotonic s>, "call": ..., "kind":
"actuation"|"stop"|"estop"}``, written and flushed *before* the call is forwarded (so a call the
inner backend refuses still counts). The wrapper only records: it issues no command of its own,
and without the option the daemon does not build it.

A backend that counts its motion at the bus (the CAN backend's `motion_frames`: command frames
sent while following a trajectory) also gets one line after each execute returns, ``{"t": ...,
"call": "execute", "kind": "motion_frames", "frames": <sent during it>, "total": <since start>}``:
what reached the actuators, one level below what reached the backend.
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import Any, TextIO

from armwarden.backends.base import Backend
from armwarden.backends.counting import CountingBackend
from armwarden.backends.values import ExecutionResult, ProgressCallback
from armwarden.core.trajectory import JointTrajectory

__all__ = ["JournalBackend"]


class JournalBackend(CountingBackend):
    """Counts like `CountingBackend` and journals each counted call to `path` (appended, line-flushed)."""

    def __init__(self, inner: Backend, path: str | Path) -> None:
        super().__init__(inner)
        self._journal_lock = threading.Lock()  # stop_now comes from other threads
        self._journal: TextIO = Path(path).open("a", encoding="utf-8")  # noqa: SIM115 - open for the backend's life, closed in close()

    def _write(self, call: str, kind: str, **extra: Any) -> None:
        line = json.dumps({"t": time.monotonic(), "call": call, "kind": kind, **extra}) + "\n"
        with self._journal_lock:
            if self._journal.closed:  # after close nothing reaches the inner backend's arm anyway
                return
            self._journal.write(line)
            self._journal.flush()

    def _actuating(self, method: str) -> None:
        super()._actuating(method)
        self._write(method, "actuation")

    def _stopping(self, *, emergency: bool = False) -> None:
        super()._stopping(emergency=emergency)
        self._write("emergency_stop" if emergency else "stop", "estop" if emergency else "stop")

    def _motion_frames(self) -> int | None:
        """The inner backend's count of motion frames sent at the bus, None if it keeps none."""
        frames = getattr(self.inner, "motion_frames", None)
        return frames if isinstance(frames, int) else None

    async def execute(
        self, trajectory: JointTrajectory, progress: ProgressCallback | None = None, *, stop_epoch: int | None = None
    ) -> ExecutionResult:
        before = self._motion_frames()
        try:
            return await super().execute(trajectory, progress, stop_epoch=stop_epoch)
        finally:
            after = self._motion_frames()
            if before is not None and after is not None:
                self._write("execute", "motion_frames", frames=after - before, total=after)

    async def close(self) -> None:
        try:
            await super().close()
        finally:
            with self._journal_lock:
                self._journal.close()
