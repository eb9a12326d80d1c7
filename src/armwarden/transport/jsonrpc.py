"""JSON-RPC facts both transports share: error codes, the request-id collision rule, refusal wording.

Lean on purpose (no Starlette, no uvicorn): the stdio transport imports it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from mcp.shared.dispatcher import coerce_request_id

#: the line is not JSON
PARSE_ERROR = -32700
#: JSON, but not a request this server takes (not a JSON-RPC message, or an id already open)
INVALID_REQUEST = -32600


def request_id_key(request_id: Any) -> str:
    """The key under which the SDK files a request id: it matches answers and cancellations with
    7, "7" and "07" as one id, so two open requests must never share this key."""
    if isinstance(request_id, (int, str)) and not isinstance(request_id, bool):
        return str(coerce_request_id(request_id))
    return str(request_id)


#: tools whose request stops the robot the moment the transport reads it, before it is queued
STOP_TOOLS = frozenset({"estop", "stop_motion"})
#: (tool, principal or None): hold the robot now; the tool itself runs later and does the rest
StopOnReceipt = Callable[[str, "str | None"], None]


def stop_call(method: Any, params: Any) -> str | None:
    """The tool name if this is a `tools/call` request of a stopping tool, else None."""
    if method != "tools/call" or not isinstance(params, dict):
        return None
    name = params.get("name")
    return name if isinstance(name, str) and name in STOP_TOOLS else None


def duplicate_id_message(request_id: Any) -> str:
    """Why a request was refused: its id is still open. Without the refusal the SDK would replace
    the open call's entry, and that call (perhaps a motion) could no longer be cancelled."""
    return f"request id {str(request_id)[:64]} is already in use by an open request of this session"
