"""Who is calling and what happened: the record of one tool call, kept in a context variable.

The server's middleware opens a `CallRecord` for every `tools/call`; the tool body and the Guard
add to it (outcome, refusal code, stop timings); the middleware then writes exactly one audit
record from it. Neutral ground, so the Guard can annotate a call without importing the MCP layer.

`caller` is who made the call, as far as the transport can tell (see `ArmWardenServer`): the
bearer token (name and fingerprint) over authenticated HTTP, else the client connection when the
protocol has one. The Guard binds each plan to it, so only the caller who planned may execute.
"""

from __future__ import annotations

import contextvars
import time
from dataclasses import dataclass, field
from typing import Any


@dataclass
class CallRecord:
    tool: str
    arguments: Any
    session: str | None = None
    principal: str | None = None
    role: str | None = None
    #: opaque identity of the caller that plans are bound to; None outside a tool call
    caller: str | None = None
    body_ran: bool = False
    outcome: str | None = None  # "ok" | "refused" | "error" | "cancelled" | "input_required"
    code: str | None = None
    detail: str | None = None
    operator: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    #: monotonic time the call reached ArmWarden's middleware (after the SDK parsed it)
    received_mono: float = field(default_factory=time.monotonic)
    #: protocol 2026-07-28: questions go out in rounds, and the retry carrying an answer asks again
    rounds: bool = False


CURRENT_CALL: contextvars.ContextVar[CallRecord | None] = contextvars.ContextVar("armwarden_call", default=None)


def current_call() -> CallRecord | None:
    return CURRENT_CALL.get()


def mark_body_ran() -> CallRecord | None:
    record = CURRENT_CALL.get()
    if record is not None:
        record.body_ran = True
    return record




def current_caller() -> str | None:
    """The identity plans made in this call are bound to (None outside a tool call)."""
    record = CURRENT_CALL.get()
    return None if record is None else record.caller


def note_approval(granted: bool, via: str, operator: str | None, answer: str) -> None:
    """Record the human's answer (and the name they gave) on the call's audit record."""
    record = CURRENT_CALL.get()
    if record is not None:
        record.operator = operator or record.operator
        record.extra["approval"] = {"granted": granted, "via": via, "operator": operator, "answer": answer}


def note_stop_timing(issued: float, confirmed: float, still: object, stopped: bool) -> None:
    """When a stop was issued and confirmed (and when the arm was still, if that stop worked),
    in milliseconds after the call reached the server, on the call's audit record."""
    record = CURRENT_CALL.get()
    if record is None:
        return
    timing = {
        "issued_after_receipt": round((issued - record.received_mono) * 1e3, 4),
        "confirmed_after_receipt": round((confirmed - record.received_mono) * 1e3, 4),
    }
    if stopped and isinstance(still, float) and still >= issued:  # this stop's, and it worked
        timing["still_after_receipt"] = round((still - record.received_mono) * 1e3, 4)
    record.extra["stop_timing_ms"] = timing
