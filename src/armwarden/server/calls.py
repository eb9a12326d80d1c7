"""Per-call bookkeeping shared by the tool functions and the audit middleware.

The middleware opens a `CallRecord` for every `tools/call` and puts it in a context variable;
the tool body (if it runs) fills in the outcome. After the call the middleware writes exactly one
audit record from it, so calls refused before a body runs (bad arguments, unknown tool, wrong
role) are recorded as faithfully as those that run.
"""

from __future__ import annotations

import contextvars
from dataclasses import dataclass, field
from typing import Any

from mcp_types import CallToolResult, ImageContent, TextContent
from pydantic import BaseModel

from armwarden.errors import SafetyRefusal


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


CURRENT_CALL: contextvars.ContextVar[CallRecord | None] = contextvars.ContextVar("armwarden_call", default=None)


def current_call() -> CallRecord | None:
    return CURRENT_CALL.get()


def mark_body_ran() -> CallRecord | None:
    record = CURRENT_CALL.get()
    if record is not None:
        record.body_ran = True
    return record


def ok(result: BaseModel, *extra: ImageContent | TextContent, summary: str | None = None) -> CallToolResult:
    """A successful tool result: structured content, its JSON as text, and any extra content."""
    record = current_call()
    if record is not None:
        record.outcome = record.outcome or "ok"
        record.detail = record.detail or summary
    return CallToolResult(
        content=[TextContent(type="text", text=result.model_dump_json()), *extra],
        structured_content=result.model_dump(mode="json"),
    )


def refused(exc: SafetyRefusal) -> CallToolResult:
    """A refusal as an `isError` result whose text says what happened and what a human must do."""
    record = current_call()
    if record is not None:
        record.outcome = "refused"
        record.code = exc.code
        record.detail = str(exc)
    return CallToolResult(content=[TextContent(type="text", text=f"REFUSED [{exc.code}]: {exc}")], is_error=True)
