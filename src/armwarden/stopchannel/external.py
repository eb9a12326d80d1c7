"""The stops that do not wait for the MCP event loop — the stop channel, SIGUSR1, and the hold
the transports issue the moment they read an `estop`/`stop_motion` request — wired to the Guard.

Both run on threads of their own while the event loop may be busy. `ExternalStops` gives them
one thread-safe `latch_and_stop` per source (the Guard's, which latches and calls the
backend's `stop_now` directly) and one `record` that hands the audit record to the audit
writer without waiting (`AuditLog.submit`): the stop never waits for the disk or the loop.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from typing import Any, Protocol

from armwarden.audit import AuditLog, AuditWriteError
from armwarden.safety.estop import EStopEvent
from armwarden.stopchannel.records import ChannelRefusal, ChannelStop

logger = logging.getLogger(__name__)


class ThreadSafeStopper(Protocol):
    def latch_and_stop(self, reason: str, source: str, schedule: Callable[[Callable[[], object]], None]) -> EStopEvent: ...

    def hold_now(self, *, emergency: bool = False) -> Exception | None: ...


class ExternalStops:
    """`latch_and_stop(reason, principal)` callables for the stop channel and signals, and their audit."""

    def __init__(self, stopper: ThreadSafeStopper, audit: AuditLog, loop: asyncio.AbstractEventLoop) -> None:
        self._stopper = stopper
        self._audit = audit
        self._loop = loop

    def latch_and_stop_for(self, source: str) -> Callable[[str, str], int]:
        """The channel's `latch_and_stop` for `source` ("stop_channel", "signal")."""

        def latch_and_stop(reason: str, principal: str) -> int:
            return self._stopper.latch_and_stop(reason, source, self._on_loop).number  # the latch names an empty reason

        return latch_and_stop

    def record(self, stop: ChannelStop) -> None:
        """Audit one external e-stop, after the fact and without waiting (any thread)."""
        failed = stop.error is not None
        self._submit(
            "estop",
            principal=stop.principal,
            outcome="stop_failed" if failed else "latched",
            detail=(f"external e-stop from {stop.peer}: the stop may NOT have been issued: {stop.error}" if failed
                    else f"external e-stop #{stop.event} from {stop.peer}"),
            arguments={"reason": stop.reason},
            extra={"peer": stop.peer, "estop_event": stop.event, "stop_issued_ms": stop.stop_issued_ms},
        )

    def record_refusal(self, refusal: ChannelRefusal) -> None:
        """Audit a request the stop channel refused (bad token, malformed, too slow, too large);
        the channel reports at most one per host and second and counts the rest."""
        self._submit("stop_channel_refused", outcome="refused",
                     detail=f"stop channel answered {refusal.status} to {refusal.peer}: {refusal.message}",
                     extra={"peer": refusal.peer, "status": refusal.status,
                            "not_reported_since_last": refusal.suppressed})

    def stop_on_receipt(self, tool: str, principal: str | None) -> None:
        """A transport has just read an `estop`/`stop_motion` request: hold the robot before the
        request waits its turn behind other work; the tool itself latches and records when it runs.
        Audited (without waiting) as `stop_on_receipt`."""
        failure = self._stopper.hold_now(emergency=tool == "estop")
        self._submit("stop_on_receipt", tool=tool, principal=principal,
                           outcome="stop_failed" if failure is not None else "stopped",
                           detail=f"robot held as the {tool} request was read" if failure is None
                           else f"holding the robot as the {tool} request was read FAILED: {failure}")

    def latch_as_the_client_leaves(self) -> None:
        """The client closed its input with calls still open: latch the e-stop and stop the arm at
        once — the session is over, and nothing may start moving for a client that can no longer
        stop it (a motion call read just before the end is refused, one already moving is
        stopped) — while those calls are answered for whoever still reads. Audited (without
        waiting) as `client_gone`."""
        reason = "the stdio client closed its input with calls still open"
        try:
            event = self._stopper.latch_and_stop(reason, "client_gone", self._on_loop)
        except Exception as exc:  # latched all the same (stop_failed on top); say so loudly
            logger.critical("client gone: the stop could not be issued: %s", exc)
            self._submit("client_gone", outcome="stop_failed", detail=f"{reason}: e-stop latched, but the stop "
                         f"could NOT be issued: {exc}")
            return
        self._submit("client_gone", outcome="latched", detail=f"{reason}: e-stop #{event.number} latched and the "
                     "arm stopped while they are answered", extra={"estop_event": event.number})

    def _submit(self, event: str, **fields: Any) -> None:
        """Hand a record to the audit writer; a log that is closing or closed is said loudly (the
        stop itself has happened either way)."""
        try:
            self._audit.submit(event, **fields)
        except AuditWriteError as exc:
            logger.critical("%s not audited (%s): %s", event, exc, fields.get("detail"))

    def _on_loop(self, work: Callable[[], object]) -> None:
        with contextlib.suppress(RuntimeError):  # the loop is closed (shutting down): the plans die with it
            self._loop.call_soon_threadsafe(work)


__all__ = ["ExternalStops"]
