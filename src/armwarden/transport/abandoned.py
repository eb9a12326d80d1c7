"""Cancel motion calls whose HTTP caller went away.

Under the 2026-07-28 protocol a tool call lives and dies with its HTTP request: when the client
disconnects, the SDK cancels the call, and a cancelled call stops what it moved (Guard). Under
2025-11-25 the call runs inside the session, not the request: a client that drops the connection
of an `execute_plan` POST would leave the call running — waiting for an approval that can still be
posted later, or moving the arm to its goal with nobody watching.

This ASGI layer closes that gap for exactly the call that was abandoned. For each POST to the MCP
endpoint it reads the body first (at most `MAX_BODY_BYTES`; a larger body, declared or sent, is
refused with 413 before the SDK sees it, so no call escapes the watch by being large), refuses
(409) a request whose id is already used by an open request of the same session (the SDK would
overwrite the open call's entry, and that call could no longer be cancelled), and notes whether
the response was sent in full. When a request that carried a `tools/call` of a motion tool ends without its
response, it sends the SDK, through the same app and in the same session and principal, the
`notifications/cancelled` for that request id that the client would have sent. The SDK cancels
that one call wherever it is (prechecks, approval question, motion) and the Guard's cancellation
path stops the robot and audits it. Nothing else is touched: another client's motion keeps going.
`on_abandoned` is told afterwards, for the audit log.

It also repairs a stopping tool's call whose `arguments` is not an object (`stop_params_repaired`:
the SDK would refuse it before the e-stop latches) and reports (`on_refused`, awaited before the
request goes on, so the daemon's record is on disk before the answer) every `tools/call` the SDK
will refuse before any tool sees it and every duplicate id it refuses itself. Apart from that
repair it never blocks, changes or drops a message of a request it passes on.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Awaitable, Callable
from typing import Any

import anyio
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from armwarden.transport.jsonrpc import (
    INVALID_REQUEST,
    RefusedCallback,
    StopOnReceipt,
    duplicate_id_message,
    request_id_key,
    screen_call,
)

logger = logging.getLogger(__name__)

#: tools whose call, abandoned by its client, must be cancelled
MOTION_TOOLS = frozenset({"execute_plan", "gripper_move", "gripper_grasp", "gripper_home"})
#: POST bodies above this are refused (413); no MCP message this server accepts comes near it
MAX_BODY_BYTES = 1024 * 1024
#: how long the injected cancellation may take before it is given up (logged) [s]
CANCEL_TIMEOUT_S = 2.0
SESSION_HEADER = b"mcp-session-id"

#: (tool, arguments, request id, cancelled): True = the cancellation was accepted by the SDK; False =
#: it was not; None = no session, so there was nothing to cancel (the SDK ends such a call itself)
AbandonedCallback = Callable[[str, dict[str, Any], Any, "bool | None"], Awaitable[None]]


def decode_message(body: bytes) -> dict[str, Any] | None:
    """The JSON-RPC message object in a request body, or None (not JSON, or not one object).
    Decoded once per request; the SDK parses the body again on its own."""
    try:
        message = json.loads(body)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return None
    return message if isinstance(message, dict) else None


def motion_call(message: dict[str, Any] | None) -> tuple[str, dict[str, Any], Any] | None:
    """(tool, arguments, request id) if `message` is a JSON-RPC `tools/call` request of a motion tool."""
    if message is None or message.get("method") != "tools/call":
        return None
    request_id = message.get("id")
    if isinstance(request_id, bool) or not isinstance(request_id, (int, str)):
        return None  # without a usable id it is a notification: the SDK runs nothing
    params = message.get("params")
    if not isinstance(params, dict) or params.get("name") not in MOTION_TOOLS:
        return None
    arguments = params.get("arguments")
    return str(params["name"]), arguments if isinstance(arguments, dict) else {}, request_id


class _ClientGone(Exception):
    """The client disconnected before its request body arrived."""


async def _read_body(receive: Receive) -> bytes | None:
    """The whole request body, or None once it exceeds `MAX_BODY_BYTES`."""
    body = bytearray()
    while True:
        message = await receive()
        if message["type"] != "http.request":
            raise _ClientGone
        body.extend(message.get("body", b""))
        if len(body) > MAX_BODY_BYTES:
            return None
        if not message.get("more_body", False):
            return bytes(body)


def _replaying(body: bytes, afterwards: Callable[[], Awaitable[Message]]) -> Receive:
    """A `receive` that hands over `body` in one message, then defers to `afterwards`."""
    pending = True

    async def receive() -> Message:
        nonlocal pending
        if pending:
            pending = False
            return {"type": "http.request", "body": body, "more_body": False}
        return await afterwards()

    return receive


async def _refuse(send: Send, status: int, message: str, request_id: Any = None) -> None:
    """A JSON-RPC error answer that the SDK never saw the request for."""
    payload = json.dumps({"jsonrpc": "2.0", "id": request_id, "error": {"code": INVALID_REQUEST, "message": message}}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(payload)).encode()),
                            (b"connection", b"close")]})
    await send({"type": "http.response.body", "body": payload})


def _header(scope: Scope, name: bytes) -> bytes | None:
    return next((value for key, value in scope.get("headers", []) if key == name), None)


def _declared_length(scope: Scope) -> int | None:
    value = _header(scope, b"content-length")
    try:
        return int(value) if value is not None else None
    except ValueError:
        return None


def _request_key(scope: Scope, message: dict[str, Any] | None) -> tuple[str, bytes, str] | None:
    """(principal, session, id) of a JSON-RPC request sent in a session: the SDK matches
    cancellations (and answers) by id, with 7, "7" and "07" the same (`request_id_key`), so two
    open requests must never share one. The principal is part of the key: the session header is
    the client's claim, checked by the SDK only later, so nobody can block (or probe) the ids of
    another principal's session."""
    session = _header(scope, SESSION_HEADER)
    if session is None:
        return None
    if message is None or "method" not in message or "id" not in message:
        return None  # a notification, or the client's answer to a server request (other id space)
    return _principal(scope), session, request_id_key(message["id"])


def _principal(scope: Scope) -> str:
    """The authenticated principal's name ("" without tokens)."""
    user = scope.get("user")
    return str(getattr(getattr(user, "access_token", None), "client_id", "") or "")


class AbandonedMotionStop:
    """ASGI middleware: see the module docstring."""

    def __init__(self, app: ASGIApp, path: str, on_abandoned: AbandonedCallback | None = None,
                 on_stop_request: StopOnReceipt | None = None, on_refused: RefusedCallback | None = None) -> None:
        self.app = app
        self.path = path.rstrip("/")
        self.on_abandoned = on_abandoned
        self.on_stop_request = on_stop_request
        self.on_refused = on_refused
        self._open_requests: set[tuple[str, bytes, str]] = set()  # (principal, session, id) of POSTs not ended

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope.get("method") != "POST" or scope.get("path", "").rstrip("/") != self.path:
            await self.app(scope, receive, send)
            return
        declared = _declared_length(scope)
        try:  # a declared oversize is refused before reading: no "100 Continue" for it
            body = None if declared is not None and declared > MAX_BODY_BYTES else await _read_body(receive)
        except _ClientGone:
            return  # nothing was asked, nothing runs
        if body is None:
            await _refuse(send, 413, f"request body over {MAX_BODY_BYTES} bytes refused")
            return
        message = decode_message(body)
        if message is not None:
            params, malformed = screen_call(message.get("method"), message.get("params"), self.on_stop_request,
                                            _principal(scope) or None)
            if params is not message.get("params"):  # a stopping call, repaired: replay the new body
                message = {**message, "params": params}
                body = json.dumps(message).encode()
                scope = {**scope, "headers": [(key, str(len(body)).encode() if key == b"content-length" else value)
                                              for key, value in scope.get("headers", [])]}
            elif malformed is not None:
                await self._report(message, "invalid_params", malformed)  # the SDK answers it
        key = _request_key(scope, message)
        if key is not None and key in self._open_requests:
            # the SDK would replace the open call's entry: that call could then no longer be cancelled
            request_id = message.get("id") if message else None
            await self._report(message, "duplicate_request_id",
                               f"{message.get('method') if message else None} refused: {duplicate_id_message(request_id)}")
            await _refuse(send, 409, duplicate_id_message(request_id), request_id=request_id)
            return
        if key is not None:
            self._open_requests.add(key)
        try:
            await self._pass_on(scope, receive, send, body, message)
        finally:
            if key is not None:
                self._open_requests.discard(key)

    async def _report(self, message: dict[str, Any] | None, outcome: str, why: str) -> None:
        if self.on_refused is None or message is None:
            return
        params = message.get("params")
        try:
            await self.on_refused(message.get("method"), params if isinstance(params, dict) else None,
                                  message.get("id"), outcome, why)
        except Exception:
            logger.exception("reporting the refused request %r failed", message.get("id"))

    async def _pass_on(self, scope: Scope, receive: Receive, send: Send, body: bytes,
                       message: dict[str, Any] | None) -> None:
        answered = False

        async def send_and_note(message: Message) -> None:
            nonlocal answered
            await send(message)
            if message["type"] == "http.response.body" and not message.get("more_body", False):
                answered = True

        try:
            await self.app(scope, _replaying(body, receive), send_and_note)  # then: the client's disconnect, if any
        finally:
            if not answered and (call := motion_call(message)) is not None:
                with anyio.CancelScope(shield=True):  # runs also when this request task was cancelled
                    await self._abandoned(scope, *call)

    async def _abandoned(self, scope: Scope, tool: str, arguments: dict[str, Any], request_id: Any) -> None:
        cancelled: bool | None = None  # no session: the call ended with its request (2026-07-28)
        if _header(scope, SESSION_HEADER) is not None:
            cancelled = False
            try:
                cancelled = await self._cancel(scope, request_id)
            except Exception:
                logger.exception("cancelling the abandoned %s call %r failed", tool, request_id)
        if self.on_abandoned is not None:
            try:
                await self.on_abandoned(tool, arguments, request_id, cancelled)
            except Exception:
                logger.exception("reporting the abandoned %s call %r failed", tool, request_id)

    async def _cancel(self, scope: Scope, request_id: Any) -> bool:
        """Send `notifications/cancelled` for `request_id` through the app, as the client would have."""
        payload = json.dumps({"jsonrpc": "2.0", "method": "notifications/cancelled", "params": {
            "requestId": request_id, "reason": "the client disconnected before the call finished"}}).encode()
        replaced = {b"content-type", b"content-length", b"accept"}
        headers = [(name, value) for name, value in scope.get("headers", []) if name not in replaced]
        headers += [(b"content-type", b"application/json"), (b"accept", b"application/json, text/event-stream"),
                    (b"content-length", str(len(payload)).encode())]
        done = anyio.Event()
        status: list[int] = []

        async def after_the_response() -> Message:
            await done.wait()
            return {"type": "http.disconnect"}

        async def send(message: Message) -> None:
            if message["type"] == "http.response.start":
                status.append(int(message["status"]))
            elif message["type"] == "http.response.body" and not message.get("more_body", False):
                done.set()

        with anyio.move_on_after(CANCEL_TIMEOUT_S):
            await self.app({**scope, "headers": headers}, _replaying(payload, after_the_response), send)
        if not status or status[0] >= 300:
            logger.error("the SDK did not accept the cancellation of request %r (status %s)", request_id, status)
            return False
        return True
