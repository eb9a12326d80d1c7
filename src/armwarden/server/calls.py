"""How tool bodies answer: a structured success, or a refusal as an `isError` result.

Both also note the outcome on the call's `CallRecord` (see `armwarden.callcontext`), from which
the middleware writes the audit record.
"""

from __future__ import annotations

from typing import Any

from mcp_types import CallToolResult, ImageContent, TextContent
from pydantic import BaseModel
from pydantic_core import to_json

from armwarden.callcontext import CURRENT_CALL, CallRecord, current_call, mark_body_ran
from armwarden.core.errors import SafetyRefusal

__all__ = ["CURRENT_CALL", "CallRecord", "current_call", "mark_body_ran", "ok", "ok_data", "refused"]


def ok(result: BaseModel, *extra: ImageContent | TextContent, summary: str | None = None) -> CallToolResult:
    """A successful tool result: structured content, its JSON as text, and any extra content."""
    return _success(result.model_dump_json(), result.model_dump(mode="json"), extra, summary)


def ok_data(data: dict[str, Any]) -> CallToolResult:
    """`ok` for a result given as its output model's JSON data, unvalidated: the SDK validates a
    tool's structured result against the tool's output model before it is sent (a state poll
    need not build the model only to dump it again)."""
    return _success(to_json(data).decode(), data, (), None)


def _success(text: str, structured: dict[str, Any], extra: tuple[ImageContent | TextContent, ...],
             summary: str | None) -> CallToolResult:
    record = current_call()
    if record is not None:
        record.outcome = record.outcome or "ok"
        record.detail = record.detail or summary
    return CallToolResult(content=[TextContent(type="text", text=text), *extra], structured_content=structured)


def refused(exc: SafetyRefusal) -> CallToolResult:
    """A refusal as an `isError` result whose text says what happened and what a human must do."""
    record = current_call()
    if record is not None:
        record.outcome = "refused"
        record.code = exc.code.value  # the plain string, as on the wire
        record.detail = str(exc)
    return CallToolResult(content=[TextContent(type="text", text=f"REFUSED [{exc.code.value}]: {exc}")], is_error=True)
