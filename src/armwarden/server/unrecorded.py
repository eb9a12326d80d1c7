"""Answers that must reach the caller even when their audit record cannot be written.

Why: the middleware writes one record per call after the tool body ran; when the log cannot take
it (a full disk), the call fails closed with a protocol error. For four tools that error would
be a lie or a danger: a stop or an e-stop that took effect would look failed to the operator who
sent it; `get_safety_status` is how a human learns that the log is unusable; and the answer to a
reset is how the human learns that it was not applied. These answers go out as they are, saying
what happened and that this call is not in the log. Nothing here decides anything: the stop has
happened, and a release never happens unrecorded (`guard.stopping.Stopper.release`).
"""

from __future__ import annotations

from typing import Any

from mcp_types import CallToolResult, InputRequiredResult, TextContent
from pydantic_core import to_json

from armwarden.core.errors import RefusalCode
from armwarden.tools import names

#: the tools answered when their record cannot be written (every other call fails closed)
ANSWERED_UNRECORDED = names(lambda spec: spec.answers_unrecorded)


def answer_unrecorded(tool: str, model: Any, error: BaseException) -> CallToolResult | None:
    """The tool's result `model` (the result as its model, not the wire dict) with what happened
    and that its record could not be written, or None when the call must fail closed instead
    (another tool, or a result of another kind)."""
    if tool not in ANSWERED_UNRECORDED:
        return None
    if isinstance(model, InputRequiredResult):  # the approval question of a reset could not be recorded
        return CallToolResult(content=[TextContent(type="text", text=(
            f"REFUSED [{RefusalCode.AUDIT_UNAVAILABLE.value}]: {tool} refused: the approval question could not be "
            f"recorded ({error}), so nobody was asked and nothing was released: the e-stop stays latched"))],
            is_error=True)
    if not isinstance(model, CallToolResult):
        return None
    if model.is_error:
        warning = f"(this answer's audit record could not be written either: {error})"
        return model.model_copy(update={"content": [*model.content, TextContent(type="text", text=warning)]})
    structured = dict(model.structured_content or {})
    if tool == "get_safety_status":
        structured["audit_ok"] = False
        structured["audit_error"] = structured.get("audit_error") or str(error)
    else:
        structured["audit_error"] = str(error)
    warning = "WARNING: " + _what_happened(tool, structured) + f", but its audit record could not be written: {error}"
    content = [TextContent(type="text", text=to_json(structured).decode()), *model.content[1:],
               TextContent(type="text", text=warning)]
    return model.model_copy(update={"content": content, "structured_content": structured})


def _what_happened(tool: str, structured: dict[str, Any]) -> str:
    number = (structured.get("estop_event") or {}).get("number", "?")
    if tool == "estop":
        return f"e-stop #{number} is latched and in force (arm and gripper stopped)"
    if tool == "stop_motion":
        return "the stop was commanded for arm and gripper"
    if tool == "reset_estop":
        return (f"e-stop #{structured.get('released_event', '?')} was released (its release record was written "
                "before it took effect)")
    return ("the audit log is unusable: nothing actuates and no e-stop can be released until it is repaired; "
            "this status is answered")


__all__ = ["ANSWERED_UNRECORDED", "answer_unrecorded"]
