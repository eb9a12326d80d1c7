"""Stopping: the one path that must always work.

`stop_motion` and `emergency_stop` never wait for anything but the backend's stop: they bump the
stop generation (an execution still being checked sees it and does not start) and latch
synchronously, then await the backend. A stop that fails latches the software e-stop and voids
every plan; the human is told to use the hardware e-stop. Each stop's timing (issued, confirmed,
arm still) goes on the call's audit record.

Stops never wait for the audit log (a full disk must not keep the arm moving); a release does:
it is written and fsynced before the latch lets go, and one that cannot be recorded does not
happen (`release`). Releases run one at a time, so a second release of the same event (two
operators at once) is refused before it writes a record of a release that would not happen.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import anyio

from armwarden import conversions
from armwarden.approval.plans import PlanStore
from armwarden.audit import AuditLog, AuditWriteError
from armwarden.backends.base import Backend
from armwarden.callcontext import current_call, note_stop_timing
from armwarden.core.errors import BackendError, RefusalCode, SafetyRefusal
from armwarden.results import EStopResult, ResetResult, StopResult
from armwarden.safety.estop import EStopEvent, EStopLatch


class Stopper:
    """Stops arm and gripper, latches the e-stop, and keeps the faults a failed stop leaves."""

    def __init__(self, backend: Backend, latch: EStopLatch, plans: PlanStore, audit: AuditLog | None = None) -> None:
        self.backend = backend
        self.latch = latch
        self.plans = plans
        #: where a release is recorded before it takes effect (None: no log, tests only)
        self.audit = audit
        #: bumped by every stop; an execution that saw another value before moving does not move
        self.generation = 0
        self.faults: list[str] = []
        self.force_violation_latched = False
        #: held from a release's check to its effect: check, record and release are one step
        self._releasing = anyio.Lock()

    async def stop_motion(self) -> StopResult:
        """Stop arm and gripper now. Never rate limited, never needs approval."""
        self.generation += 1
        try:
            await self._timed_stop()
        except BackendError as exc:
            event = self._latch_failed_stop("stop_motion", exc)
            raise SafetyRefusal(RefusalCode.STOP_FAILED, f"the stop command failed ({exc}); the software e-stop "
                                f"#{event.number} is latched. Use the hardware e-stop if the robot is still moving.") from exc
        return StopResult(stopped=True, detail="stop commanded for arm and gripper")

    async def emergency_stop(self, reason: object, source: str = "estop", force: dict | None = None) -> EStopResult:
        """Latch, invalidate every plan and stop arm and gripper. Accepts any reason."""
        self.generation += 1
        event = self.latch.latch(reason, source, force_violation=force)
        if source == "force_monitor":
            self.force_violation_latched = True
        self.plans.invalidate_all(f"e-stop #{event.number}")
        try:
            await self._timed_stop(emergency=True)
        except BackendError as exc:
            event = self._latch_estop_stop_failure(event, exc)
        return EStopResult(estopped=True, estop_event=conversions.estop_info(event))

    def latch_and_stop(self, reason: str, source: str, schedule: Callable[[Callable[[], object]], None]) -> EStopEvent:
        """The e-stop from any thread, without the event loop (stop channel, SIGUSR1): latch, then
        stop arm and gripper with the backend's thread-safe `emergency_stop_now`; the plans are voided on the
        loop afterwards through `schedule` (until then they are refused anyway: each carries the
        latch generation it was made under). Raises `BackendError`, with a `stop_failed` e-stop
        latched on top, when the stop could not be issued."""
        event = self.latch.latch(reason, source)
        self.generation += 1
        try:
            self.backend.emergency_stop_now()
        except BackendError as exc:
            event = self._latch_estop_stop_failure(event, exc)
            raise BackendError(f"e-stop #{event.number}: the stop could not be issued: {exc}") from exc
        finally:
            voided = event
            schedule(lambda: self.plans.invalidate_all(f"e-stop #{voided.number}"))
        return event

    def backend_fault(self, reason: str) -> EStopEvent:
        """From any thread (the backend's): the backend found a fault and has already stopped or
        damped the arm. Latch the e-stop (plans made before it are refused: they carry the latch
        generation) and record the fault for `get_safety_status`; nothing moves until a human
        resets the e-stop and the backend finds the fault cleared."""
        self.generation += 1
        self.faults.append(reason)
        return self.latch.latch(reason, "backend_fault")

    def hold_now(self, *, emergency: bool = False) -> BackendError | None:
        """From any thread: stop arm and gripper now with the backend's `stop_now` (an e-stop
        request: `emergency_stop_now`), without latching. For a stop or e-stop request the transport
        has just read: the arm is stopped before the request waits its turn, and the tool, when it
        runs, stops again, latches and records. Returns the failure, if the stop could not be
        issued (the tool's own stop then fails and latches too)."""
        self.generation += 1
        try:
            if emergency:
                self.backend.emergency_stop_now()
            else:
                self.backend.stop_now()
        except BackendError as exc:
            return exc
        return None

    async def stop_for(self, what: str) -> EStopEvent | None:
        """Stop arm and gripper for a call that can no longer do it itself (cancelled, abandoned).
        Returns None when the stop was issued, else the e-stop event latched because it failed."""
        self.generation += 1
        try:
            await self.backend.stop()
        except BackendError as exc:
            return self._latch_failed_stop(what, exc)
        return None

    async def after_abandoned_call(self, tool: str, request_id: Any, cancelled: bool | None,
                                   running: bool) -> tuple[str, str]:
        """A client went away before its motion call answered (see `Guard.abandoned_call`): stop
        what that call still moves (`running`, only when its cancellation failed). Returns the
        audit outcome and detail."""
        outcome = {True: "cancelled", None: "ended_with_request", False: "nothing_running"}[cancelled]
        detail = f"the client of {tool} (request {str(request_id)[:64]}) went away before the answer"
        if running:
            event = await self.stop_for("stop after a client disconnected")
            if event is None:
                outcome, detail = "stopped", detail + "; the cancellation failed, so the robot was stopped"
            else:
                outcome, detail = "stop_failed", detail + f"; the stop FAILED, e-stop #{event.number} latched ({event.reason})"
        return outcome, detail

    async def release(self, shown_event: str | None, operator: str | None, via: str) -> ResetResult:
        """Release the e-stop a human approved resetting: only the event they were shown (none
        shown: the current one), and only if it is still the one latched. Recorded first: the
        `estop_release` record is on disk before the latch lets go; if it cannot be written,
        nothing is released and the refusal says why (AUDIT_UNAVAILABLE). One release at a time:
        a second one waits, then finds the event released and is refused without a record."""
        async with self._releasing:
            current = self.latch.current_event
            try:
                shown = int(shown_event) if shown_event is not None else (current.number if current else -1)
            except ValueError:
                shown = -1
            allowed = self.latch.check_release(shown)
            if not allowed.released:
                raise SafetyRefusal(RefusalCode.RESET_REFUSED, f"reset_estop refused: {allowed.message}")
            await self._record_release(shown, operator, via)
            result = self.latch.release(shown)  # checks again: an e-stop latched while the record was written wins
            if not result.released:
                raise SafetyRefusal(RefusalCode.RESET_REFUSED, f"reset_estop refused: {result.message}")
            self.force_violation_latched = False
            return ResetResult(estopped=self.latch.is_latched, released_event=shown, detail=result.message)

    async def _record_release(self, number: int, operator: str | None, via: str) -> None:
        """`estop_release` on disk, or SafetyRefusal(AUDIT_UNAVAILABLE) and the latch stays."""
        if self.audit is None:
            return
        held = [event.number for event in self.latch.held_events]
        call = current_call()
        try:
            await self.audit.append_async(
                "estop_release", session=None if call is None else call.session,
                principal=None if call is None else call.principal, tool=None if call is None else call.tool,
                outcome="releasing", operator=operator,
                detail=f"e-stop #{number} approved for release via {via} (releasing the held events {held}); it takes "
                       "effect only after this record is on disk, and only if no newer e-stop latched meanwhile",
                extra={"estop_event": number, "held_events": held, "via": via},
            )
        except AuditWriteError as exc:
            raise SafetyRefusal(RefusalCode.AUDIT_UNAVAILABLE, f"reset_estop refused: the release could not be "
                                f"recorded ({exc}), so it was NOT applied: nothing was released, e-stop #{number} "
                                "stays latched. A release needs a working audit log: make room on its disk (the "
                                "daemon reopens the log when it restarts)") from exc

    def _latch_estop_stop_failure(self, event: EStopEvent, exc: BaseException) -> EStopEvent:
        """The stop of e-stop `event` could not be issued: record the fault and latch again on top."""
        self.faults.append(f"stop during e-stop #{event.number} failed: {exc}")
        return self.latch.latch(f"stop failed during e-stop #{event.number}: {exc}", "stop_failed")

    def _latch_failed_stop(self, what: str, exc: BaseException) -> EStopEvent:
        """A stop that could not be issued: latch the e-stop, void every plan, report the fault."""
        event = self.latch.latch(f"{what} failed: {exc}", "stop_failed")
        self.plans.invalidate_all("stop failed")
        self.faults.append(f"{what} failed: {exc}")
        return event

    async def _timed_stop(self, *, emergency: bool = False) -> None:
        """The backend stop (an e-stop's: `emergency_stop`), with when it was issued and confirmed
        noted on the call's audit record."""
        issued = time.monotonic()
        stopped = False
        try:
            await (self.backend.emergency_stop() if emergency else self.backend.stop())
            stopped = True
        finally:
            note_stop_timing(issued, time.monotonic(), self.backend.last_stop_stamp, stopped)
