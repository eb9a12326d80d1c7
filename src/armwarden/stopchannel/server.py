"""The stop channel: an e-stop path that no MCP load can delay.

Why: an ``estop`` tool call waits its turn behind every other request on the event loop; the
operator who needs to stop may be exactly the one stuck behind the load. The channel is a
second path with nothing in common with the first (see docs/architecture.md, section
"Independent stop channel"): its own OS thread, its own listening socket, no asyncio, no
uvicorn, no MCP SDK. It answers one request, ``POST /estop`` with a bearer token of any role,
by calling the thread-safe ``latch_and_stop(reason, principal)`` and replying with the e-stop
event number.

Robustness comes from bounds, not from trust (`connections.ConnectionLoop`, which this class
extends with what a request means):
- one thread serves every connection from a `selectors` loop over non-blocking sockets;
- a request must arrive whole within `request_timeout_s` and within the sizes of `wire`;
- at most `max_connections` are open; a new connection evicts the least useful open one
  (answered first, then unauthenticated, oldest first), so slow or half-open connections can
  never keep a real stop out;
- every answer closes the connection; nothing from a request is logged unbounded.

Answers (JSON, always ``Connection: close``): 200 ``{"estopped": true, "event": N,
"stop_issued_ms": T}`` where T is the time from the whole request being read to
``latch_and_stop`` returning; otherwise ``{"error": "..."}`` with 400 malformed, 401 missing or
unknown token, 404/405 wrong path/method, 408 too slow, 413 too large, 501 chunked, and 500
when the authenticator or ``latch_and_stop`` raised (the message says whether a stop may have
been issued). Only requests that reached ``latch_and_stop`` are reported to `on_event`.

The operator console's E-STOP (`console_door.ConsoleDoor`, optional): ``POST /console-estop``, a form a
browser posts cross-origin without a CORS preflight, with the ``ticket`` the console page embeds
for its session (checked on this thread by `ConsoleDoor.check_ticket`, never on the event loop),
or with no ticket from a loopback peer when the console allows that. A browser's Origin must be
one of the console's. Its answers are tiny HTML pages (the page without script shows them).

A channel without an authenticator (``authenticate=None``) serves the console's E-STOP only (the
daemon starts one on an ephemeral loopback port when the console is served without
`--estop-port`): it refuses ``POST /estop`` (404) with a message saying what it does take, since
"unknown bearer token" there misled people holding a token that ``/mcp`` accepts.

The audit hook `on_event` runs after the reply was sent, on this thread: it must be quick
(hand the record to the audit writer) and its failure is logged, never raised.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable
from typing import Any

from armwarden.safety.estop import flatten_reason
from armwarden.safety.refusals import RefusalReports
from armwarden.stopchannel.connections import Connection, ConnectionLoop
from armwarden.stopchannel.console_door import CONSOLE_ESTOP_REASON, ConsoleDoor, authorise_console_estop
from armwarden.stopchannel.records import ChannelRefusal, ChannelStop
from armwarden.stopchannel.wire import (
    CONSOLE_ESTOP_PATH,
    ESTOP_PATH,
    MAX_HEAD_BYTES,
    HttpRefusal,
    RequestHead,
    bearer_token,
    find_head_end,
    parse_console_form,
    parse_head,
    parse_reason,
    render_html_response,
    render_response,
)

__all__ = ["CONSOLE_ONLY_REFUSAL", "StopChannel", "token_store_authenticator"]

logger = logging.getLogger(__name__)

_UNAUTHORIZED = (("WWW-Authenticate", 'Bearer realm="armwarden-estop"'),)
#: the answer of a console-only channel (no authenticator) to ``POST /estop``, whatever its token
CONSOLE_ONLY_REFUSAL = (f"this stop channel serves only the operator console's E-STOP button (POST {CONSOLE_ESTOP_PATH} "
                        "with a console page's ticket) and takes no bearer token; it is not the MCP endpoint. For "
                        f"POST {ESTOP_PATH} with a token (armwarden estop --url), start the daemon with --estop-port "
                        "and --auth-tokens")


def token_store_authenticator(store: Any) -> Callable[[str], str | None]:
    """Adapt a `armwarden.transport.tokens.TokenStore` (any role accepted) to the channel. A token
    file that becomes unusable does not refuse stops: the last usable version's tokens still do."""

    def authenticate(token: str) -> str | None:
        principal = store.authenticate(token, last_good_while_unusable=True)
        return None if principal is None else str(principal.name)

    return authenticate


class StopChannel(ConnectionLoop):
    """``POST /estop`` on its own thread and socket. `start` binds, `close` stops; idempotent."""

    def __init__(
        self,
        *,
        authenticate: Callable[[str], str | None] | None,
        latch_and_stop: Callable[[str, str], int],
        host: str = "127.0.0.1",
        port: int = 0,
        on_event: Callable[[ChannelStop], None] | None = None,
        on_refused: Callable[[ChannelRefusal], None] | None = None,
        console: ConsoleDoor | None = None,
        allow_non_loopback: bool = False,
        max_connections: int = 64,
        request_timeout_s: float = 1.0,
        refusals: RefusalReports | None = None,
    ) -> None:
        """`authenticate`: a bearer token's principal (None: not accepted); None for a channel that
        serves only the `console`'s E-STOP. `refusals`: which refusals `on_refused` hears of
        (`safety.refusals`; the daemon's reports the counts it leaves out to the audit log);
        closed with the channel."""
        super().__init__(host=host, port=port, allow_non_loopback=allow_non_loopback, max_connections=max_connections,
                         request_timeout_s=request_timeout_s)
        self._authenticate = authenticate
        self._latch_and_stop = latch_and_stop
        self._on_event = on_event
        self._on_refused = on_refused
        self._console = console
        # at most one report per host and second, and a budget overall
        self._refusals = refusals if refusals is not None else RefusalReports()

    # ------------------------------------------------------------------------------ lifecycle
    def start(self) -> StopChannel:
        """Bind and listen (a `ConfigurationError` says why not), then serve on a new thread."""
        super().start()
        return self

    def _after_close(self) -> None:
        self._refusals.close()  # the counts of refusals left out are reported, none is dropped

    def __enter__(self) -> StopChannel:
        if self._thread is None:
            self.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    @property
    def url(self) -> str:
        host = f"[{self._host}]" if ":" in self._host else self._host
        return f"http://{host}:{self._port}{ESTOP_PATH}"

    @property
    def console_url(self) -> str:
        """Where the console's E-STOP button posts."""
        return self.url.removesuffix(ESTOP_PATH) + CONSOLE_ESTOP_PATH


    # ------------------------------------------------------------------------------ one request
    def _advance(self, conn: Connection) -> None:
        try:
            if conn.head is None:
                end = find_head_end(conn.buffer)
                if end is None:
                    if len(conn.buffer) >= MAX_HEAD_BYTES:
                        raise HttpRefusal(413, f"request line and headers larger than {MAX_HEAD_BYTES} bytes")
                    return
                conn.head, conn.body_start = parse_head(bytes(conn.buffer[:end])), end
                if conn.head.path == CONSOLE_ESTOP_PATH:
                    self._check_console_head(conn.head)
                else:
                    conn.principal = self._check_token(conn)
            body = bytes(conn.buffer[conn.body_start : conn.body_start + conn.head.content_length])
            if len(body) == conn.head.content_length:
                if conn.head.path == CONSOLE_ESTOP_PATH:
                    self._console_stop(conn, body)
                else:
                    self._stop(conn, body)
        except HttpRefusal as refusal:
            if conn.head is not None and conn.head.path == CONSOLE_ESTOP_PATH:
                self._answer_console(conn, refusal.status, f"E-STOP refused: {refusal.message}")
            else:
                self._answer(conn, refusal.status, {"error": refusal.message}, refusal.headers)

    def _check_console_head(self, head: RequestHead) -> None:
        """Refuse a console E-STOP early when this channel has no console, or the Origin is foreign."""
        if self._console is None:
            raise HttpRefusal(404, f"not found; this channel serves no console ({CONSOLE_ESTOP_PATH})")
        if head.origin is not None and head.origin not in self._console.allowed_origins:
            raise HttpRefusal(403, "the request comes from a page that is not this daemon's console")

    def _console_principal(self, conn: Connection, body: bytes) -> str:
        assert conn.head is not None and self._console is not None
        ticket = parse_console_form(body, conn.head.content_type)
        try:
            return authorise_console_estop(self._console, ticket, conn.peer.rsplit(":", 1)[0])
        except HttpRefusal:
            raise
        except Exception:
            logger.exception("stop channel: the console ticket check failed; request from %s refused", conn.peer)
            raise HttpRefusal(500, "the ticket could not be checked; no stop was issued") from None

    def _console_stop(self, conn: Connection, body: bytes) -> None:
        assert self._console is not None
        conn.principal = self._console_principal(conn, body)
        received = time.monotonic()
        try:
            event = self._console.latch_and_stop(CONSOLE_ESTOP_REASON, conn.principal)
        except Exception as exc:
            error = flatten_reason(f"{type(exc).__name__}: {exc}", 300)
            conn.stop = ChannelStop(conn.principal, CONSOLE_ESTOP_REASON, f"console via stop channel {conn.peer}", None, None, error)
            logger.critical("stop channel: console E-STOP by %s failed: %s", conn.principal, error, exc_info=True)
            self._answer_console(conn, 500, "E-STOP FAILED: the stop may NOT have been issued. Use the hardware e-stop.")
            return
        issued_ms = round((time.monotonic() - received) * 1000.0, 3)
        conn.stop = ChannelStop(conn.principal, CONSOLE_ESTOP_REASON, f"console via stop channel {conn.peer}", event, issued_ms)
        self._answer_console(conn, 200, f"E-STOP latched: event #{event}")

    def _answer_console(self, conn: Connection, status: int, message: str) -> None:
        back = None if self._console is None else self._console.back_url
        self._send_answer(conn, render_html_response(status, message, back))
        if status != 200:
            self._report_refusal(conn.peer, status, message)

    def _check_token(self, conn: Connection) -> str:
        assert conn.head is not None
        if self._authenticate is None:
            raise HttpRefusal(404, CONSOLE_ONLY_REFUSAL)
        token = bearer_token(conn.head.authorization)
        try:
            principal = self._authenticate(token)
        except Exception:
            logger.exception("stop channel: the authenticator failed; request from %s refused", conn.peer)
            raise HttpRefusal(500, "the token could not be checked (authenticator failed); no stop was issued") from None
        if principal is None:
            logger.warning("stop channel refused an unknown bearer token from %s", conn.peer)
            raise HttpRefusal(401, "unknown bearer token", _UNAUTHORIZED)
        return flatten_reason(principal, 64) or "unknown"

    def _stop(self, conn: Connection, body: bytes) -> None:
        received = time.monotonic()
        assert conn.head is not None and conn.principal is not None
        reason = parse_reason(body, conn.head.content_type)
        try:
            event = self._latch_and_stop(reason, conn.principal)
        except Exception as exc:
            error = flatten_reason(f"{type(exc).__name__}: {exc}", 300)
            message = f"latch_and_stop failed ({error}); the stop may NOT have been issued - use another stop"
            conn.stop = ChannelStop(conn.principal, reason, conn.peer, None, None, message)
            logger.critical("stop channel: e-stop requested by %s failed: %s", conn.principal, error, exc_info=True)
            self._answer(conn, 500, {"error": message})
            return
        issued_ms = round((time.monotonic() - received) * 1000.0, 3)
        conn.stop = ChannelStop(conn.principal, reason, conn.peer, event, issued_ms)
        self._answer(conn, 200, {"estopped": True, "event": event, "stop_issued_ms": issued_ms})

    def _on_timeout(self, conn: Connection) -> None:
        with contextlib.suppress(OSError):
            conn.sock.send(render_response(408, {"error": "request not received in time"}))
        self._report_refusal(conn.peer, 408, "request not received in time")

    # ------------------------------------------------------------------------------ answering
    def _answer(
        self, conn: Connection, status: int, payload: dict[str, object], headers: tuple[tuple[str, str], ...] = ()
    ) -> None:
        self._send_answer(conn, render_response(status, payload, headers))
        if status != 200:
            self._report_refusal(conn.peer, status, str(payload.get("error", "")))

    def _report_refusal(self, peer: str, status: int, message: str) -> None:
        """Hand a refusal to `on_refused`, at most once per host and second and within an overall
        budget (`safety.refusals`, which reports the counts of those left out)."""
        if self._on_refused is None:
            return
        left_out = self._refusals.admit(peer.rsplit(":", 1)[0])
        if left_out is None:
            return
        try:
            self._on_refused(ChannelRefusal(peer, status, flatten_reason(message, 200), left_out))
        except Exception:
            logger.exception("stop channel: on_refused failed")

    def _after_reply(self, conn: Connection) -> None:
        stop, conn.stop = conn.stop, None
        if stop is None:
            return
        if stop.error is None:
            logger.warning(
                "stop channel: e-stop event %s latched for %s from %s (%.3f ms): %s",
                stop.event, stop.principal, stop.peer, stop.stop_issued_ms, stop.reason or "(no reason given)",
            )
        if self._on_event is None:
            return
        try:
            self._on_event(stop)
        except Exception:
            logger.exception("stop channel: on_event failed for a channel e-stop (event %s)", stop.event)
