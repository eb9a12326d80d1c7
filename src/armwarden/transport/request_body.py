"""The raw ASGI side of a POST to ``/mcp``: its body read once and bounded, handed on again, decoded.

`AbandonedMotionStop` must see a request's body before the SDK does (to refuse what is too large,
to screen stop calls, to know which call to cancel): `read_body` reads it at most `MAX_BODY_BYTES`
far, `replaying` gives the SDK the same bytes, and `refuse_unseen` answers a request the SDK never
saw. A record never carries a body it did not decode: `body_digest` names it instead.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Awaitable, Callable
from typing import Any

from starlette.types import Message, Receive, Scope, Send

from armwarden.transport.jsonrpc import INVALID_REQUEST

__all__ = [
    "MAX_BODY_BYTES",
    "ClientGone",
    "body_digest",
    "declared_length",
    "decode_body",
    "decode_message",
    "header",
    "read_body",
    "refuse_unseen",
    "replaying",
]

#: POST bodies above this are refused (413); no MCP message this server accepts comes near it
MAX_BODY_BYTES = 1024 * 1024


def body_digest(body: bytes) -> str:
    """What a record says of a body it does not carry: its size and SHA-256."""
    return f"{len(body)} bytes, sha256 {hashlib.sha256(body).hexdigest()}"


def decode_body(body: bytes) -> Any:
    """A request body's JSON (an object, a batch's list, ...), or None when it is not JSON.
    Decoded once per request; the SDK parses the body again on its own."""
    try:
        return json.loads(body)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return None


def decode_message(body: bytes) -> dict[str, Any] | None:
    """The JSON-RPC message object in a request body, or None (not JSON, or not one object)."""
    message = decode_body(body)
    return message if isinstance(message, dict) else None


class ClientGone(Exception):
    """The client disconnected before its request body arrived."""


async def read_body(receive: Receive) -> tuple[bytes, bool]:
    """(the request body, True), or (what was read, False) once it exceeds `MAX_BODY_BYTES`."""
    body = bytearray()
    while True:
        message = await receive()
        if message["type"] != "http.request":
            raise ClientGone
        body.extend(message.get("body", b""))
        if len(body) > MAX_BODY_BYTES:
            return bytes(body), False
        if not message.get("more_body", False):
            return bytes(body), True


def replaying(body: bytes, afterwards: Callable[[], Awaitable[Message]]) -> Receive:
    """A `receive` that hands over `body` in one message, then defers to `afterwards`."""
    pending = True

    async def receive() -> Message:
        nonlocal pending
        if pending:
            pending = False
            return {"type": "http.request", "body": body, "more_body": False}
        return await afterwards()

    return receive


async def refuse_unseen(send: Send, status: int, message: str, request_id: Any = None) -> None:
    """A JSON-RPC error answer that the SDK never saw the request for."""
    payload = json.dumps({"jsonrpc": "2.0", "id": request_id, "error": {"code": INVALID_REQUEST, "message": message}}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(payload)).encode()),
                            (b"connection", b"close")]})
    await send({"type": "http.response.body", "body": payload})


def header(scope: Scope, name: bytes) -> bytes | None:
    return next((value for key, value in scope.get("headers", []) if key == name), None)


def declared_length(scope: Scope) -> int | None:
    value = header(scope, b"content-length")
    try:
        return int(value) if value is not None else None
    except ValueError:
        return None
