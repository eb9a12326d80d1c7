"""The gate around the SDK's stdio streams: the answers its stdio transport does not give.

The SDK reads stdin line by line and hands each parsed message (or the parse failure) to the
server. Three gaps, closed here by a thin layer around its streams (`gate_streams`):

- An unparseable line is dropped in silence (logged at debug level): a client waiting for an
  answer waits for ever. Here it gets a JSON-RPC error with id null: -32700 for a line that is not
  JSON, -32600 for JSON that is not a JSON-RPC message. The session goes on.
- A `tools/call` without a usable id (null, true, 1.0, or none) is parsed by the SDK as a
  notification and dropped: the tool does not run and the client is never told (an `estop` sent
  that way did not latch). Here it is answered with -32600 and id null, as over HTTP
  (`unanswerable_call`); a stopping tool's call holds the robot as it is read, as any stop call.
- A request whose id is still open (no answer sent yet) replaces the open call's entry in the SDK,
  so a `notifications/cancelled` could no longer reach that call — an open motion would not be
  cancellable. Here the second request is answered with a -32600 error under its id and never
  reaches the SDK, as the HTTP transport refuses it with 409 (`abandoned.py`).

Three more, shared with the HTTP transport (`jsonrpc.py`): a stopping tool's call whose `arguments`
is not an object is passed on with that value as its argument (`stop_params_repaired`: the SDK would
refuse it before the tool latches); an `estop` request that is read but will not run — refused
here (a reused id, no usable id, a line that is JSON but not one JSON-RPC message, every element
of a batch, which the SDK cannot read), answered by
the SDK with an error, or settled without an answer — latches the e-stop before that answer
(`on_estop_refused`, `refused_stops`); and every request refused before the server's tools see it —
an unreadable line, a reused id, a call without a usable id, a `tools/call` with malformed params
(the SDK answers that one) —
is reported through `on_refused`, so the daemon audits it.

An id is open from its request until the answer is written, or until the SDK settles the request
without one (it was cancelled: the SDK's `on_request_unanswered` hook). When the input ends with
ids still open, the robot is stopped at once (`on_input_end`: the daemon latches the e-stop, so no
motion starts for a client that is gone) and those calls get up to
`INPUT_END_GRACE_S` to finish and be answered before the session ends (the SDK would cancel
them unanswered: a client that writes its requests and closes its end, `printf ... | armwarden
serve`, got no answer). Ids are compared the way
the SDK matches them (`request_id_key`). Everything else passes unchanged, in order; stdout carries
only MCP messages.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from types import TracebackType
from typing import Any

import anyio
from mcp.shared._stream_protocols import ReadStream, WriteStream
from mcp.shared.message import ServerMessageMetadata, SessionMessage
from mcp_types import (
    ErrorData,
    JSONRPCError,
    JSONRPCNotification,
    JSONRPCRequest,
    JSONRPCResponse,
    RequestId,
)
from pydantic import ValidationError

from armwarden.transport.jsonrpc import (
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
)

__all__ = ["INPUT_END_GRACE_S", "GatedReadStream", "GatedWriteStream", "OpenIds", "gate_streams"]

logger = logging.getLogger(__name__)

#: how long calls already read may still run, and be answered, once the input has ended [s]
INPUT_END_GRACE_S = 3.0


def unreadable_line_error(exc: Exception) -> ErrorData:
    """The JSON-RPC error for a line the SDK could not read as a message."""
    if isinstance(exc, ValidationError) and not any(e.get("type") == "json_invalid" for e in exc.errors()):
        return ErrorData(code=INVALID_REQUEST, message="Invalid Request: the line is not a JSON-RPC 2.0 message")
    return ErrorData(code=PARSE_ERROR, message="Parse error: the line is not valid JSON")


def parsed_line(exc: Exception) -> Any:
    """What the SDK parsed of a line it could not read as one JSON-RPC message (a batch, an object
    that is not a valid message), or None (not JSON). Pydantic keeps every error's input: a list
    fails each message model as a whole; an object misses a field of some model (a request has no
    `result`, so it never passes as a response), and that error's input is the whole object."""
    if not isinstance(exc, ValidationError):
        return None
    for error in exc.errors(include_url=False):
        loc, value = error.get("loc", ()), error.get("input")
        if (len(loc) <= 1 and isinstance(value, list)) or (
                error.get("type") == "missing" and len(loc) == 2 and isinstance(value, dict)):
            return value
    return None


class OpenIds:
    """The keys (`request_id_key`) of the requests read and not yet settled, each with its params
    when it is an `estop` call (a refusal or an unanswered end then latches the e-stop)."""

    def __init__(self) -> None:
        self._keys: dict[str, Mapping[str, Any] | None] = {}
        self._none_left: anyio.Event | None = None

    def __contains__(self, key: str) -> bool:
        return key in self._keys

    def __bool__(self) -> bool:
        return bool(self._keys)

    def add(self, key: str, estop_params: Mapping[str, Any] | None = None) -> None:
        self._keys[key] = estop_params

    def discard(self, key: str) -> Mapping[str, Any] | None:
        """Settle `key`; returns its params if it was an open `estop` call."""
        estop_params = self._keys.pop(key, None)
        if not self._keys and self._none_left is not None:
            self._none_left.set()
        return estop_params

    async def all_settled(self) -> None:
        """Return once no request is open."""
        if self._keys:
            self._none_left = anyio.Event()
            await self._none_left.wait()


class GatedWriteStream:
    """Write side: passes every message on; an answer closes its request's id first, and an error
    answer to an `estop` call latches the e-stop before it is written (the tool did not run)."""

    def __init__(self, inner: WriteStream[SessionMessage], open_ids: OpenIds,
                 on_estop_refused: LatchOnRefusal | None = None) -> None:
        self._inner = inner
        self._open_ids = open_ids
        self._on_estop_refused = on_estop_refused

    async def send(self, item: SessionMessage, /) -> None:
        message = item.message
        if isinstance(message, (JSONRPCResponse, JSONRPCError)) and message.id is not None:
            # before the write: the SDK has already dropped the call, and the client may reuse the id
            # as soon as it reads the answer
            estop_params = self._open_ids.discard(request_id_key(message.id))
            if estop_params is not None and isinstance(message, JSONRPCError):
                refused_stops([("estop", estop_params)], self._on_estop_refused, None,
                              f"the estop call was answered with JSON-RPC error {message.error.code}: "
                              f"{message.error.message[:200]}")
        await self._inner.send(item)

    async def reply(self, message: JSONRPCError) -> None:
        """An answer of this layer's own; dropped if the session is already closing."""
        try:
            await self._inner.send(SessionMessage(message))
        except (anyio.BrokenResourceError, anyio.ClosedResourceError):
            logger.debug("dropped an error answer: the stdio session is closing")

    async def aclose(self) -> None:
        await self._inner.aclose()

    async def __aenter__(self) -> GatedWriteStream:
        return self

    async def __aexit__(self, exc_type: type[BaseException] | None, exc_val: BaseException | None,
                        exc_tb: TracebackType | None) -> bool | None:
        await self.aclose()
        return None


class GatedReadStream:
    """Read side: answers unreadable lines and duplicate open ids itself, passes the rest on."""

    def __init__(self, inner: ReadStream[SessionMessage | Exception], writer: GatedWriteStream, open_ids: OpenIds,
                 spawn: Callable[..., None], on_refused: RefusedCallback | None = None,
                 on_stop_request: StopOnReceipt | None = None, on_input_end: Callable[[], None] | None = None,
                 on_estop_refused: LatchOnRefusal | None = None) -> None:
        self._inner = inner
        self._writer = writer
        self._open_ids = open_ids
        self._spawn = spawn
        self._on_refused = on_refused
        self._on_stop_request = on_stop_request
        self._on_input_end = on_input_end
        self._on_estop_refused = on_estop_refused

    @property
    def last_context(self) -> Any:
        """The sender context of the last message (the SDK runs its handler in it)."""
        return getattr(self._inner, "last_context", None)

    async def receive(self) -> SessionMessage | Exception:
        while True:
            try:
                item = await self._inner.receive()
            except anyio.EndOfStream:
                await self._answer_open_calls()
                raise
            if isinstance(item, Exception):
                decoded = parsed_line(item)
                if isinstance(decoded, list):
                    await self._refuse_batch(decoded)
                    continue
                error = unreadable_line_error(item)
                taken = self._refuse_stops(self._screen(decoded), error.message)
                logger.warning("stdio: answered an unreadable line with error %d", error.code)
                await self._writer.reply(JSONRPCError(jsonrpc="2.0", id=None, error=error))
                self._report(None, None, None, "unreadable", error.message, taken)
                continue
            if isinstance(item.message, JSONRPCNotification) and (
                    idless := unanswerable_call(item.message.method, item.message.params)) is not None:
                # a call whose id was missing or unusable, parsed by the SDK as a notification
                await self._refuse_idless_call(item.message, idless)
                continue
            if not isinstance(item.message, JSONRPCRequest):
                return item
            request = item.message
            params, malformed = screen_call(request.method, request.params, self._on_stop_request, None)
            tool = stop_call(request.method, params)
            if params is not request.params:
                request = request.model_copy(update={"params": params})
            elif malformed is not None:
                self._report(request.method, request.params, request.id, "invalid_params", malformed)  # the SDK answers it
            key = request_id_key(request.id)
            if key in self._open_ids:
                why = f"{request.method} refused: {duplicate_id_message(request.id)}"
                taken = self._refuse_stops([] if tool is None else [(tool, params)], why)
                logger.warning("stdio: refused %s: request id %r is still open", request.method, request.id)
                await self._writer.reply(JSONRPCError(jsonrpc="2.0", id=request.id, error=ErrorData(
                    code=INVALID_REQUEST, message=duplicate_id_message(request.id))))
                self._report(request.method, request.params, request.id, "duplicate_request_id", why, taken)
                continue
            self._open_ids.add(key, params if tool == "estop" else None)
            return SessionMessage(request, self._closing_on_settle(item.metadata, key))

    def _screen(self, decoded: Any) -> list[tuple[str, Any]]:
        """Hold the robot for a stop call in what the SDK parsed of a line it could not read
        (`parsed_line`), as for any stop request read; returns its (tool, params)."""
        if not isinstance(decoded, dict):
            return []
        params, _ = screen_call(decoded.get("method"), decoded.get("params"), self._on_stop_request, None)
        tool = stop_call(decoded.get("method"), params)
        return [] if tool is None else [(tool, params)]

    async def _refuse_batch(self, elements: list[Any]) -> None:
        """Refuse a batch (-32600, id null), as over HTTP, once every element is screened: a stop
        call in it holds the robot, an `estop` latches the e-stop before the answer."""
        stops, names = screen_batch(elements, self._on_stop_request, None)
        why = batch_refusal(len(elements))
        taken = self._refuse_stops(stops, why)
        logger.warning("stdio: refused a batch of %d", len(elements))
        await self._writer.reply(JSONRPCError(jsonrpc="2.0", id=None, error=ErrorData(code=INVALID_REQUEST, message=why)))
        self._report(None, None, None, "invalid_request", why, taken, names)

    def _refuse_stops(self, stops: list[tuple[str, Any]], why: str) -> tuple[StopTaken, ...]:
        """A refused request's stop calls: an `estop` latches now, before the refusal is answered."""
        return refused_stops(stops, self._on_estop_refused, None, why) if stops else ()

    async def _refuse_idless_call(self, call: JSONRPCNotification, why: str) -> None:
        """Refuse a `tools/call` without a usable id visibly (-32600, id null) and report it, as the
        HTTP transport does; a stopping tool's call holds the robot first, as any stop call read,
        and an `estop` latches before the refusal is answered."""
        taken = self._refuse_stops(self._screen({"method": call.method, "params": call.params}), why)
        logger.warning("stdio: refused a tools/call without a usable id")
        await self._writer.reply(JSONRPCError(jsonrpc="2.0", id=None, error=ErrorData(code=INVALID_REQUEST,
                                                                                      message=why)))
        self._report(call.method, call.params, None, "invalid_request", why, taken)

    async def _answer_open_calls(self) -> None:
        """The input has ended: let the calls already read finish and be answered (for a client
        that wrote its requests and closed its end, `printf ... | armwarden serve`), within
        `INPUT_END_GRACE_S`; the robot is stopped first (`on_input_end`), so no motion runs on or starts."""
        if not self._open_ids:
            return
        if self._on_input_end is not None:
            self._on_input_end()
        with anyio.move_on_after(INPUT_END_GRACE_S):
            await self._open_ids.all_settled()

    def _closing_on_settle(self, metadata: Any, key: str) -> ServerMessageMetadata:
        """Metadata whose `on_request_unanswered` closes `key`: a cancelled request is never answered."""
        if metadata is not None and not isinstance(metadata, ServerMessageMetadata):
            logger.debug("stdio: replacing unexpected metadata %r", metadata)
            metadata = None
        earlier = metadata.on_request_unanswered if metadata is not None else None

        async def settled_unanswered() -> None:
            estop_params = self._open_ids.discard(key)
            if estop_params is not None:  # cancelled before its tool answered: it still latches
                refused_stops([("estop", estop_params)], self._on_estop_refused, None,
                              "the estop call ended without an answer (cancelled)")
            if earlier is not None:
                await earlier()

        if metadata is None:
            return ServerMessageMetadata(on_request_unanswered=settled_unanswered)
        metadata.on_request_unanswered = settled_unanswered
        return metadata

    def _report(self, method: str | None, params: Mapping[str, Any] | None, request_id: RequestId | None,
                outcome: str, why: str, stops: tuple[StopTaken, ...] = (), batch: tuple[str, ...] | None = None) -> None:
        if self._on_refused is not None:
            self._spawn(self._report_refusal, RefusedRequest(method, params, request_id, outcome, why, stops, batch))

    async def _report_refusal(self, refused: RefusedRequest) -> None:
        assert self._on_refused is not None
        try:
            await self._on_refused(refused)
        except Exception:
            logger.exception("reporting the refused request %r failed", refused.request_id)

    async def aclose(self) -> None:
        await self._inner.aclose()

    def __aiter__(self) -> GatedReadStream:
        return self

    async def __anext__(self) -> SessionMessage | Exception:
        try:
            return await self.receive()
        except anyio.EndOfStream:
            raise StopAsyncIteration from None

    async def __aenter__(self) -> GatedReadStream:
        return self

    async def __aexit__(self, exc_type: type[BaseException] | None, exc_val: BaseException | None,
                        exc_tb: TracebackType | None) -> bool | None:
        await self.aclose()
        return None


def gate_streams(read_stream: ReadStream[SessionMessage | Exception], write_stream: WriteStream[SessionMessage],
                 spawn: Callable[..., None], on_refused: RefusedCallback | None = None,
                 on_stop_request: StopOnReceipt | None = None,
                 on_input_end: Callable[[], None] | None = None,
                 on_estop_refused: LatchOnRefusal | None = None) -> tuple[GatedReadStream, GatedWriteStream]:
    """Wrap a server's stream pair (see the module docstring). `spawn(fn, *args)` runs a task."""
    open_ids = OpenIds()
    writer = GatedWriteStream(write_stream, open_ids, on_estop_refused)
    return GatedReadStream(read_stream, writer, open_ids, spawn, on_refused, on_stop_request, on_input_end,
                           on_estop_refused), writer
