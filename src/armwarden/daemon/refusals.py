"""Requests a transport refused before the tools saw them: audited (thinned per principal), and an
`estop` among them latched all the same. Shared by the stdio and the HTTP transport."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from armwarden.audit import AuditWriteError
from armwarden.core.errors import BackendError
from armwarden.daemon.startup import Assembly
from armwarden.safety.estop import flatten_reason
from armwarden.stopchannel.external import ExternalStops

if TYPE_CHECKING:
    from armwarden.transport.jsonrpc import LatchOnRefusal, RefusedCallback, RefusedRequest

logger = logging.getLogger("armwarden")

#: records of requests a transport refused, per principal (or host): this many in a row, then one
#: per second (`RefusalReports`); a client's occasional mistakes are each recorded, a flood is not
REFUSAL_RECORDS_BURST = 20


def refusal_recorder(assembly: Assembly) -> RefusedCallback:
    """Audits a request a transport refused before the tools saw it (`request_refused`, on disk
    before its answer where the transport waits for it), with what its stop calls did. Pure
    refusals are thinned per principal (or host; stdio has one client) to `REFUSAL_RECORDS_BURST`,
    then one a second, each record counting those left out before it; a refusal whose stop calls
    acted (held the robot, latched the e-stop) is always recorded. Counts left out are recorded on
    their own (`refusals_left_out`) when the principal goes quiet, and at shutdown."""
    thinning = assembly.refusal_reports_for("transport", burst=REFUSAL_RECORDS_BURST)

    async def record(refused: RefusedRequest) -> None:
        left_out = 0
        if not refused.stops:
            admitted = thinning.admit(refused.principal or refused.peer or "the stdio client")
            if admitted is None:
                return
            left_out = admitted
        params = refused.params if refused.method == "tools/call" and isinstance(refused.params, Mapping) else {}
        tool, arguments = params.get("name"), params.get("arguments")
        extra: dict[str, Any] = {}
        if refused.request_id is not None:
            extra["request_id"] = str(refused.request_id)[:64]
        if refused.session is not None:  # the client's claim, never a session the SDK bound
            extra["session_header"] = flatten_reason(refused.session, 128)
        if refused.peer is not None:
            extra["peer"] = refused.peer
        if left_out:
            extra["not_reported_since_last"] = left_out
        detail = refused.why
        if refused.batch is not None:  # named by what acted (an estop first), its elements in extra
            acted = sorted(refused.stops, key=lambda stop: stop.tool != "estop")
            tool = acted[0].tool if acted else None
            extra["batch"] = list(refused.batch)
        if refused.stops:
            extra["stops"] = [stop.tool for stop in refused.stops]
            events = [stop.estop_event for stop in refused.stops if stop.estop_event is not None]
            if events:
                extra["estop_event"] = events[0]
            detail += "; " + "; ".join(stop.describe() for stop in refused.stops)
        await assembly.audit.append_async("request_refused", tool=None if tool is None else str(tool)[:128],
                                          arguments=None if tool is None else arguments, outcome=refused.outcome,
                                          detail=detail, principal=refused.principal, extra=extra or None)

    return record


def refused_estop_latch(assembly: Assembly, external: ExternalStops) -> LatchOnRefusal:
    """Latches the e-stop for an `estop` request a transport read but that will not run
    (docs/threat-model.md: a clumsy stop still latches) and audits it without waiting, as the
    stop channel does. The source is "estop": its reason is the client's, shown as unverified."""
    latch_and_stop = external.latch_and_stop_for("estop")

    def latch(reason: Any, principal: str | None, why: str) -> int:
        text = flatten_reason(reason)
        failure: BackendError | None = None
        try:
            number = latch_and_stop(text, principal or "")
        except BackendError as exc:  # latched all the same, with a stop_failed e-stop on top
            failure = exc
            event = assembly.guard.latch.current_event
            number = event.number if event is not None else 0
        detail = (f"e-stop #{number} latched: the estop request was read but not run ({flatten_reason(why, 300)})"
                  + ("" if failure is None else f"; the stop could NOT be issued: {failure}"))
        try:
            assembly.audit.submit("estop", tool="estop", principal=principal, arguments={"reason": text},
                                  outcome="latched" if failure is None else "stop_failed", detail=detail,
                                  extra={"estop_event": number})
        except AuditWriteError as exc:  # the latch holds either way
            logger.critical("estop not audited (%s): %s", exc, detail)
        return number

    return latch
