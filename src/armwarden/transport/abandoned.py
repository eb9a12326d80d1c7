"""Stop motion whose HTTP caller went away.

Under the 2026-07-28 protocol a tool call lives and dies with its HTTP request: when the client
disconnects, the SDK cancels the call and the Guard stops the arm. Under 2025-11-25 the call runs
inside the session, not the request: a client that drops the connection of an `execute_plan`
POST leaves the motion running to its end, and nobody is there to see it or stop it. This ASGI
layer closes that gap. For each POST to the MCP endpoint it keeps the (bounded) request body and
notes whether the response was sent in full; when the request ends without a complete response
and it was a call to a tool that moves something, it hands the tool name and arguments to
`on_abandoned`, which stops that motion if it is still running (`Guard.stop_abandoned_call`).

It only ever adds a stop; it never blocks, changes or drops a message.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Awaitable, Callable
from typing import Any

import anyio
from starlette.types import ASGIApp, Message, Receive, Scope, Send

logger = logging.getLogger(__name__)

#: tools whose call, abandoned by its client, must not keep moving the robot
MOTION_TOOLS = frozenset({"execute_plan", "gripper_move", "gripper_grasp", "gripper_home"})
#: larger request bodies are not kept (no motion call is anywhere near this size)
MAX_BODY_BYTES = 64 * 1024

AbandonedCallback = Callable[[str, dict[str, Any]], Awaitable[None]]


def motion_call(body: bytes) -> tuple[str, dict[str, Any]] | None:
    """(tool, arguments) if `body` is a JSON-RPC `tools/call` of a motion tool, else None."""
    try:
        message = json.loads(body)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return None
    if not isinstance(message, dict) or message.get("method") != "tools/call":
        return None
    params = message.get("params")
    if not isinstance(params, dict) or params.get("name") not in MOTION_TOOLS:
        return None
    arguments = params.get("arguments")
    return str(params["name"]), arguments if isinstance(arguments, dict) else {}


class AbandonedMotionStop:
    """ASGI middleware: see the module docstring."""

    def __init__(self, app: ASGIApp, path: str, on_abandoned: AbandonedCallback) -> None:
        self.app = app
        self.path = path.rstrip("/")
        self.on_abandoned = on_abandoned

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope.get("method") != "POST" or scope.get("path", "").rstrip("/") != self.path:
            await self.app(scope, receive, send)
            return
        body = bytearray()
        kept = True
        answered = False

        async def receive_and_keep() -> Message:
            nonlocal kept
            message = await receive()
            if message["type"] == "http.request" and kept:
                chunk = message.get("body", b"")
                if len(body) + len(chunk) > MAX_BODY_BYTES:
                    kept = False
                    body.clear()
                else:
                    body.extend(chunk)
            return message

        async def send_and_note(message: Message) -> None:
            nonlocal answered
            await send(message)
            if message["type"] == "http.response.body" and not message.get("more_body", False):
                answered = True

        try:
            await self.app(scope, receive_and_keep, send_and_note)
        finally:
            if not answered and kept and (call := motion_call(bytes(body))) is not None:
                with anyio.CancelScope(shield=True):  # runs also when this request was cancelled
                    try:
                        await self.on_abandoned(*call)
                    except Exception:  # the stop path reports its own failures; never break the server
                        logger.exception("stopping the abandoned %s call failed", call[0])
