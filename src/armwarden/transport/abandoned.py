"""Cancel motion calls whose HTTP caller went away.

Under the 2026-07-28 protocol a tool call lives and dies with its HTTP request: when the client
disconnects, the SDK cancels the call, and a cancelled call stops what it moved (Guard). Under
2025-11-25 the call runs inside the session, not the request: a client that drops the connection
of an `execute_plan` POST would leave the call running — waiting for an approval that can still be
posted later, or moving the arm to its goal with nobody watching.

This ASGI layer closes that gap for exactly the call that was abandoned. For each POST to the MCP
endpoint it reads the body first (at most `MAX_BODY_BYTES`; a larger body, declared or sent, is
refused with 413 before the SDK sees it, so no call escapes the watch by being large;
`request_body.py`), refuses
(409) a request whose id is already used by an open request of the same session (the SDK would
overwrite the open call's entry, and that call could no longer be cancelled), and notes whether
the response was sent in full. When a request that carried a `tools/call` of a motion tool ends without its
response, it sends the SDK, through the same app and in the same session and principal, the
`notifications/cancelled` for that request id that the client would have sent. The SDK cancels
that one call wherever it is (prechecks, approval question, motion) and the Guard's cancellation
path stops the robot and audits it. Nothing else is touched: another client's motion keeps going.
`on_abandoned` is told afterwards, for the audit log.

It also repairs a stopping tool's call whose `arguments` is not an object (`stop_params_repaired`:
the SDK would refuse it before the e-stop latches), latches the e-stop for an `estop` request that
is refused anyway (`refused_stops`, before the refusal is answered; after the tools saw it,
`LatchEstopsNotRun`), refuses (400, -32600) a JSON-RPC batch itself after screening every element
(`screen_batch`: a stop in it holds, an `estop` latches, as the SDK refuses batches under both
revisions), refuses (400, -32600) a `tools/call` without a
usable id (`unanswerable_call`: the SDK would drop it as a notification, unanswered and unrun, as
stdio refuses it), and reports (`on_refused`, awaited before the
answer leaves, so the daemon's record is on disk first) every request refused before the server's
tools saw it, as stdio does: a body over the limit (by its size, and the digest of what was read:
never the body), a duplicate id, a call without a usable id, a `tools/call` with malformed params,
and every error answer the
SDK gives a `tools/call` (or a body nobody could read) before its dispatch reached the tools —
a routing header that disagrees with the body (2026-07-28, -32020), a body its JSON parser
rejects (-32700), an unknown session. Such an answer is held back until its record is written;
whether the dispatch was reached is told by `mark_dispatched`, an MCP server middleware the
HTTP app installs outermost (`mcp_middleware.py`), so a call the tools saw (and the tool layer recorded) is not
recorded twice. Apart from the repair it never changes or drops a message of a request it passes on.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Awaitable, Callable
from typing import Any

import anyio
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from armwarden.tools import names
from armwarden.transport.jsonrpc import (
    HEADER_MISMATCH,
    INVALID_PARAMS,
    INVALID_REQUEST,
    PARSE_ERROR,
    LatchOnRefusal,
    RefusedCallback,
    RefusedRequest,
    StopOnReceipt,
    StopTaken,
    batch_refusal,
    duplicate_id_message,
    refused_stops,
    request_id_key,
    screen_batch,
    screen_call,
    stop_call,
    unanswerable_call,
    usable_request_id,
)
from armwarden.transport.mcp_middleware import noting_dispatch
from armwarden.transport.request_body import (
    MAX_BODY_BYTES,
    ClientGone,
    body_digest,
    declared_length,
    decode_body,
    header,
    read_body,
    refuse_unseen,
    replaying,
)

logger = logging.getLogger(__name__)

#: tools whose call, abandoned by its client, must be cancelled
MOTION_TOOLS = names(lambda spec: spec.moves)
#: how long the injected cancellation may take before it is given up (logged) [s]
CANCEL_TIMEOUT_S = 2.0
SESSION_HEADER = b"mcp-session-id"

#: a refused request's arguments go into its record only up to this body size [bytes]; a larger
#: body is recorded by its size and digest (and its tool's name)
RECORDED_BODY_BYTES = 16 * 1024
#: how much of an error answer is read to name its JSON-RPC code [bytes]
_ERROR_ANSWER_BYTES = 64 * 1024
#: what an SDK error answer's JSON-RPC code makes of the refusal in the audit log (else "refused")
_REFUSAL_OUTCOMES = {PARSE_ERROR: "unreadable", INVALID_REQUEST: "unreadable", HEADER_MISMATCH: "header_mismatch",
                     INVALID_PARAMS: "invalid_params"}

#: (tool, arguments, request id, cancelled): True = the cancellation was accepted by the SDK; False =
#: it was not; None = no session, so there was nothing to cancel (the SDK ends such a call itself)
AbandonedCallback = Callable[[str, dict[str, Any], Any, "bool | None"], Awaitable[None]]

def motion_call(message: dict[str, Any] | None) -> tuple[str, dict[str, Any], Any] | None:
    """(tool, arguments, request id) if `message` is a JSON-RPC `tools/call` request of a motion tool."""
    if message is None or message.get("method") != "tools/call":
        return None
    request_id = message.get("id")
    if not usable_request_id(request_id):
        return None  # refused before the SDK sees it (`unanswerable_call`): nothing runs
    params = message.get("params")
    if not isinstance(params, dict) or params.get("name") not in MOTION_TOOLS:
        return None
    arguments = params.get("arguments")
    return str(params["name"]), arguments if isinstance(arguments, dict) else {}, request_id


def _request_key(scope: Scope, message: dict[str, Any] | None) -> tuple[str, bytes, str] | None:
    """(principal, session, id) of a JSON-RPC request sent in a session: the SDK matches
    cancellations (and answers) by id, with 7, "7" and "07" the same (`request_id_key`), so two
    open requests must never share one. The principal is part of the key: the session header is
    the client's claim, checked by the SDK only later, so nobody can block (or probe) the ids of
    another principal's session."""
    session = header(scope, SESSION_HEADER)
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
                 on_stop_request: StopOnReceipt | None = None, on_refused: RefusedCallback | None = None,
                 on_estop_refused: LatchOnRefusal | None = None) -> None:
        self.app = app
        self.path = path.rstrip("/")
        self.on_abandoned = on_abandoned
        self.on_stop_request = on_stop_request
        self.on_refused = on_refused
        self.on_estop_refused = on_estop_refused
        self._open_requests: set[tuple[str, bytes, str]] = set()  # (principal, session, id) of POSTs not ended

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope.get("method") != "POST" or scope.get("path", "").rstrip("/") != self.path:
            await self.app(scope, receive, send)
            return
        declared = declared_length(scope)
        too_large = f"request body over {MAX_BODY_BYTES} bytes refused"
        if declared is not None and declared > MAX_BODY_BYTES:  # refused before reading: no "100 Continue" for it
            await self._report(scope, None, "too_large", f"{too_large} (HTTP 413): declared {declared} bytes, not read", 0)
            await refuse_unseen(send, 413, too_large)
            return
        try:
            body, whole = await read_body(receive)
        except ClientGone:
            return  # nothing was asked, nothing runs
        if not whole:
            await self._report(scope, None, "too_large", f"{too_large} (HTTP 413): sent without a declared length, cut off "
                               f"after {body_digest(body)}", len(body))
            await refuse_unseen(send, 413, too_large)
            return
        decoded = decode_body(body)
        principal = _principal(scope) or None
        if isinstance(decoded, list):
            await self._refuse_batch(scope, decoded, send, len(body))
            return
        message = decoded if isinstance(decoded, dict) else None
        reported = False
        stops: list[tuple[str, Any]] = []  # (tool, params) of the stop calls it makes
        if message is not None:
            params, malformed = screen_call(message.get("method"), message.get("params"), self.on_stop_request,
                                            principal)
            if (tool := stop_call(message.get("method"), params)) is not None:
                stops.append((tool, params))
            if params is not message.get("params"):  # a stopping call, repaired: replay the new body
                message = {**message, "params": params}
                body = json.dumps(message).encode()
                scope = {**scope, "headers": [(key, str(len(body)).encode() if key == b"content-length" else value)
                                              for key, value in scope.get("headers", [])]}
            if not usable_request_id(message.get("id")) and (
                    idless := unanswerable_call(message.get("method"), params)) is not None:
                taken = refused_stops(stops, self.on_estop_refused, principal, idless)
                await self._report(scope, message, "invalid_request", idless, len(body), taken)
                await refuse_unseen(send, 400, idless)
                return
            if malformed is not None:
                await self._report(scope, message, "invalid_params", malformed, len(body))  # the SDK answers it
                reported = True
        key = _request_key(scope, message)
        if key is not None and key in self._open_requests:
            # the SDK would replace the open call's entry: that call could then no longer be cancelled
            request_id = message.get("id") if message else None
            why = f"{message.get('method') if message else None} refused: {duplicate_id_message(request_id)}"
            taken = refused_stops(stops, self.on_estop_refused, principal, why)
            await self._report(scope, message, "duplicate_request_id", why, len(body), taken)
            await refuse_unseen(send, 409, duplicate_id_message(request_id), request_id=request_id)
            return
        if key is not None:
            self._open_requests.add(key)
        try:
            await self._pass_on(scope, receive, send, body, message, reported, stops)
        finally:
            if key is not None:
                self._open_requests.discard(key)

    async def _refuse_batch(self, scope: Scope, elements: list[Any], send: Send, body_bytes: int) -> None:
        """Refuse a batch (400, -32600), as the SDK would under either revision, once every
        element is screened: a stop call in it holds the robot, an `estop` latches the e-stop."""
        principal = _principal(scope) or None
        stops, names = screen_batch(elements, self.on_stop_request, principal)
        why = batch_refusal(len(elements))
        taken = refused_stops(stops, self.on_estop_refused, principal, why)
        await self._report(scope, None, "invalid_request", why, body_bytes, taken, names)
        await refuse_unseen(send, 400, why)

    async def _report(self, scope: Scope, message: dict[str, Any] | None, outcome: str, why: str, body_bytes: int,
                      stops: tuple[StopTaken, ...] = (), batch: tuple[str, ...] | None = None) -> None:
        """Hand a refusal to `on_refused`: the message's method, params and id (its params without
        the arguments when the body was over `RECORDED_BODY_BYTES`), or Nones for a body that
        was not read or not understood; who sent it (the principal `BearerAuth` authenticated,
        the session header as the client claimed it)."""
        if self.on_refused is None:
            return
        method = request_id = params = None
        if message is not None:
            method, request_id, params = message.get("method"), message.get("id"), message.get("params")
            if not isinstance(params, dict):
                params = None
            elif body_bytes > RECORDED_BODY_BYTES:
                params = {"name": params["name"]} if isinstance(params.get("name"), str) else None
        try:
            session = header(scope, SESSION_HEADER)
            await self.on_refused(RefusedRequest(
                method, params, request_id, outcome, why, stops, batch, principal=_principal(scope) or None,
                session=None if session is None else session.decode("latin-1"), peer=(scope.get("client") or (None,))[0]))
        except Exception:
            logger.exception("reporting the refused request %r failed", request_id)

    @staticmethod
    def _sdk_refusal(message: dict[str, Any] | None, body: bytes, answer: list[Message]) -> tuple[str, str]:
        """(outcome, why) of an error answer the SDK gave a request before its dispatch reached the tools."""
        status = int(answer[0]["status"])
        text = b"".join(part.get("body", b"") for part in answer[1:])[:_ERROR_ANSWER_BYTES]
        code: Any = None
        said = ""
        try:
            error = json.loads(text)["error"]
            code, said = error.get("code"), str(error.get("message", ""))[:200]
        except (ValueError, TypeError, KeyError, AttributeError, RecursionError):
            said = text[:200].decode("utf-8", "replace")
        params = message.get("params") if message is not None else None
        name = params.get("name") if isinstance(params, dict) else None
        what = f"tools/call of {str(name)[:64]}" if isinstance(name, str) else "a request"
        rpc = f", JSON-RPC {code}" if isinstance(code, int) else ""
        why = f"{what} refused by the MCP SDK before any tool saw it (HTTP {status}{rpc}: {said}); body {body_digest(body)}"
        outcome = _REFUSAL_OUTCOMES.get(code, "refused") if isinstance(code, int) else "refused"
        return outcome, why

    async def _pass_on(self, scope: Scope, receive: Receive, send: Send, body: bytes,
                       message: dict[str, Any] | None, reported: bool, stops: list[tuple[str, Any]]) -> None:
        answered = False
        # an error answer to a `tools/call` (or to a body nobody could read) that the tools never
        # saw is held until its refusal is recorded; a refusal already reported is not watched
        watched = not reported and (message is None or message.get("method") == "tools/call")
        dispatched: list[str] = []
        held: list[Message] = []

        async def send_and_note(out: Message) -> None:
            nonlocal answered
            if out["type"] == "http.response.start" and watched and int(out["status"]) >= 400 and not dispatched:
                held.append(out)
                return
            if held:
                held.append(out)
                if out["type"] != "http.response.body" or out.get("more_body", False):
                    return
                with anyio.CancelScope(shield=True):  # the latch and the record, then the answer
                    outcome, why = self._sdk_refusal(message, body, held)
                    taken = refused_stops(stops, self.on_estop_refused, _principal(scope) or None, why)
                    await self._report(scope, message, outcome, why, len(body), taken)
                for part in held:
                    await send(part)
                held.clear()
                answered = True
                return
            await send(out)
            if out["type"] == "http.response.body" and not out.get("more_body", False):
                answered = True

        try:
            with noting_dispatch(dispatched):
                await self.app(scope, replaying(body, receive), send_and_note)  # then: the client's disconnect, if any
        finally:
            if not answered and (call := motion_call(message)) is not None:
                with anyio.CancelScope(shield=True):  # runs also when this request task was cancelled
                    await self._abandoned(scope, *call)

    async def _abandoned(self, scope: Scope, tool: str, arguments: dict[str, Any], request_id: Any) -> None:
        cancelled: bool | None = None  # no session: the call ended with its request (2026-07-28)
        if header(scope, SESSION_HEADER) is not None:
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
            await self.app({**scope, "headers": headers}, replaying(payload, after_the_response), send)
        if not status or status[0] >= 300:
            logger.error("the SDK did not accept the cancellation of request %r (status %s)", request_id, status)
            return False
        return True
