"""Who is calling and what happened: the record of one tool call, kept in a context variable.

The server's middleware opens a `CallRecord` for every `tools/call`; the tool body and the Guard
add to it (outcome, refusal code, stop timings); the middleware then writes exactly one audit
record from it. Neutral ground, so the Guard can annotate a call without importing the MCP layer.
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
    body_ran: bool = False
    outcome: str | None = None  # "ok" | "refused" | "error" | "cancelled" | "input_required"
    code: str | None = None
    detail: str | None = None
    operator: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    #: monotonic time the call reached ArmWarden's middleware (after the SDK parsed it)
    received_mono: float = field(default_factory=time.monotonic)


CURRENT_CALL: contextvars.ContextVar[CallRecord | None] = contextvars.ContextVar("armwarden_call", default=None)


def current_call() -> CallRecord | None:
    return CURRENT_CALL.get()


def mark_body_ran() -> CallRecord | None:
    record = CURRENT_CALL.get()
    if record is not None:
        record.body_ran = True
    return record


