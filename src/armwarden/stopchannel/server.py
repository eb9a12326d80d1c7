"""The stop channel: an e-stop path that no MCP load can delay.

Why: an ``estop`` tool call waits its turn behind every other request on the event loop; the
operator who needs to stop may be exactly the one stuck behind the load. The channel is a
second path with nothing in common with the first (see docs/architecture.md, section
"Independent stop channel"): its own OS thread, its own listening socket, no asyncio, no
uvicorn, no MCP SDK. It answers one request, ``POST /estop`` with a bearer token of any role,
by calling the thread-safe ``latch_and_stop(reason, principal)`` and replying with the e-stop
event number.

Robustness comes from bounds, not from trust:
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

The operator console's E-STOP (`ConsoleDoor`, optional): ``POST /console-estop``, a form a
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
import selectors
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from armwarden.core.errors import ConfigurationError
from armwarden.safety.estop import flatten_reason
from armwarden.safety.refusals import RefusalReports
from armwarden.stopchannel.listener import is_loopback, open_listener
from armwarden.stopchannel.wire import (
    CONSOLE_ESTOP_PATH,
    ESTOP_PATH,
    MAX_BODY_BYTES,
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

__all__ = [
    "CONSOLE_ONLY_REFUSAL",
    "CONSOLE_UNSIGNED_PRINCIPAL",
    "ChannelRefusal",
    "ChannelStop",
    "ConsoleDoor",
    "StopChannel",
    "authorise_console_estop",
    "token_store_authenticator",
]

logger = logging.getLogger(__name__)

_LINGER_S = 0.25  # after answering, how long unread request bytes are drained (avoids a reset eating the answer)
_UNAUTHORIZED = (("WWW-Authenticate", 'Bearer realm="armwarden-estop"'),)
#: the answer of a console-only channel (no authenticator) to ``POST /estop``, whatever its token
CONSOLE_ONLY_REFUSAL = (f"this stop channel serves only the operator console's E-STOP button (POST {CONSOLE_ESTOP_PATH} "
                        "with a console page's ticket) and takes no bearer token; it is not the MCP endpoint. For "
                        f"POST {ESTOP_PATH} with a token (armwarden estop --url), start the daemon with --estop-port "
                        "and --auth-tokens")


@dataclass(frozen=True)
class ChannelStop:
    """One e-stop request handed to ``latch_and_stop``, for the audit log.

    `event` and `stop_issued_ms` are None, and `error` says why, when ``latch_and_stop`` raised.
    """

    principal: str
    reason: str
    peer: str
    event: int | None
    stop_issued_ms: float | None
    error: str | None = None


def token_store_authenticator(store: Any) -> Callable[[str], str | None]:
    """Adapt a `armwarden.transport.tokens.TokenStore` (any role accepted) to the channel. A token
    file that becomes unusable does not refuse stops: the last usable version's tokens still do."""

    def authenticate(token: str) -> str | None:
        principal = store.authenticate(token, last_good_while_unusable=True)
        return None if principal is None else str(principal.name)

    return authenticate


@dataclass(frozen=True)
class ChannelRefusal:
    """A request the channel refused (4xx/5xx), for the audit log; `suppressed` counts the refusals
    of the same host not reported since the last one (at most one report per host and second;
    counts left out otherwise are reported by the channel's `RefusalReports`)."""

    peer: str
    status: int
    message: str
    suppressed: int = 0


#: the principal audited for a console E-STOP without a ticket (loopback, not signed in)
CONSOLE_UNSIGNED_PRINCIPAL = "console (not signed in, loopback)"
CONSOLE_ESTOP_REASON = "operator console E-STOP"


@dataclass(frozen=True)
class ConsoleDoor:
    """How the channel takes the operator console's E-STOP (``POST /console-estop``).

    `check_ticket` maps a console page's ticket to the signed-in token's name (None: unknown,
    expired or signed out); it runs on the channel's thread, so it must be thread-safe and must
    not wait for the event loop. `allowed_origins`: the console's own origins; a request with
    any other Origin header (``null`` included) is refused, so no other web site can stop the
    robot through a visitor's browser. `back_url`: the link on the answer page.
    """

    check_ticket: Callable[[str], str | None]
    latch_and_stop: Callable[[str, str], int]
    allowed_origins: frozenset[str]
    allow_loopback_without_ticket: bool = True
    back_url: str | None = None


def authorise_console_estop(door: ConsoleDoor, ticket: str | None, peer_host: str) -> str:
    """Who pressed the console's E-STOP: the ticket's session, or, without a valid ticket, a
    loopback peer when the console allows that. The ticket of a page whose session has ended
    (signed out, expired, pushed out by its token's newer sign-ins) still names its token while
    the token is valid (`SessionStore.principal_for_ticket`); a ticket that names nobody (unknown,
    or its token revoked) counts as none: the page that carries it must stop the robot wherever
    a page without one would. `HttpRefusal` 401 otherwise (the stop is
    not issued)."""
    principal = None if ticket is None else door.check_ticket(ticket)
    if principal is not None:
        return flatten_reason(principal, 64) or "unknown"
    why = "no ticket" if ticket is None else "its ticket is unknown or its token revoked: sign in again"
    if not door.allow_loopback_without_ticket:
        raise HttpRefusal(401, f"sign in to the console first ({why})")
    if not is_loopback(peer_host):
        raise HttpRefusal(401, f"without sign-in the console E-STOP works only from this machine ({why})")
    return CONSOLE_UNSIGNED_PRINCIPAL


@dataclass(eq=False)
class _Connection:
    sock: socket.socket
    peer: str
    deadline: float
    buffer: bytearray = field(default_factory=bytearray)
    head: RequestHead | None = None
    body_start: int = 0
    principal: str | None = None
    answered: bool = False
    outgoing: bytes = b""
    stop: ChannelStop | None = None  # reported by `_after_reply` once the answer is out


class StopChannel:
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
        if not 0 <= port <= 65535:
            raise ConfigurationError(f"stop channel port {port} is outside 0-65535")
        if max_connections < 1:
            raise ConfigurationError(f"stop channel max_connections must be at least 1, got {max_connections}")
        if not request_timeout_s > 0:
            raise ConfigurationError(f"stop channel request_timeout_s must be positive, got {request_timeout_s}")
        self._authenticate = authenticate
        self._latch_and_stop = latch_and_stop
        self._on_event = on_event
        self._on_refused = on_refused
        self._console = console
        # at most one report per host and second, and a budget overall
        self._refusals = refusals if refusals is not None else RefusalReports()
        self._host, self._port = host, port
        self._allow_non_loopback = allow_non_loopback
        self._max_connections = max_connections
        self._request_timeout_s = request_timeout_s
        self._connections: dict[_Connection, None] = {}  # insertion order = age
        self._selector = selectors.DefaultSelector()
        self._listener: socket.socket | None = None
        self._wake_r, self._wake_w = socket.socketpair()
        self._thread: threading.Thread | None = None
        self._closing = threading.Event()
        self._lifecycle = threading.Lock()

    # ------------------------------------------------------------------------------ lifecycle
    def start(self) -> StopChannel:
        """Bind and listen (a `ConfigurationError` says why not), then serve on a new thread."""
        with self._lifecycle:
            if self._closing.is_set() or self._thread is not None:
                raise RuntimeError("a StopChannel can be started once, and not after close()")
            self._listener = open_listener(self._host, self._port, allow_non_loopback=self._allow_non_loopback)
            self._host, self._port = self._listener.getsockname()[:2]
            self._wake_r.setblocking(False)
            self._selector.register(self._listener, selectors.EVENT_READ, "listener")
            self._selector.register(self._wake_r, selectors.EVENT_READ, "wake")
            self._thread = threading.Thread(target=self._serve, name="armwarden-stopchannel", daemon=True)
            self._thread.start()
        logger.debug("stop channel listening on %s:%s", self._host, self._port)  # the daemon says what it takes
        return self

    def close(self) -> None:
        """Stop serving and close every socket. Safe to call twice, or before `start`."""
        with self._lifecycle:
            if self._closing.is_set():
                return
            self._closing.set()
            thread = self._thread
        if thread is None:
            self._release()
            self._refusals.close()
            return
        with contextlib.suppress(OSError):
            self._wake_w.send(b"x")
        if thread is not threading.current_thread():
            thread.join(timeout=5.0)
            if thread.is_alive():
                logger.error("stop channel thread did not finish within 5 s (a callback is blocking it)")
        self._refusals.close()  # the counts of refusals left out are reported, none is dropped

    def __enter__(self) -> StopChannel:
        if self._thread is None:
            self.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    @property
    def port(self) -> int:
        """The bound port (the real one after `start` when 0 was asked for)."""
        return int(self._port)

    @property
    def url(self) -> str:
        host = f"[{self._host}]" if ":" in self._host else self._host
        return f"http://{host}:{self._port}{ESTOP_PATH}"

    @property
    def console_url(self) -> str:
        """Where the console's E-STOP button posts."""
        return self.url.removesuffix(ESTOP_PATH) + CONSOLE_ESTOP_PATH

    @property
    def is_serving(self) -> bool:
        return self._thread is not None and self._thread.is_alive() and not self._closing.is_set()

    def _release(self) -> None:
        for conn in list(self._connections):
            self._drop(conn)
        for sock in (self._listener, self._wake_r, self._wake_w):
            if sock is not None:
                sock.close()
        self._selector.close()

    # ------------------------------------------------------------------------------ the loop
    def _serve(self) -> None:
        try:
            while not self._closing.is_set():
                try:
                    self._round()
                except Exception:  # one bad round must not end the stop path for good
                    logger.critical("stop channel: a serving round failed; serving on", exc_info=True)
                    time.sleep(0.01)
        finally:
            self._release()

    def _round(self) -> None:
        ready = self._selector.select(self._next_timeout())
        for key, mask in ready:
            if isinstance(key.data, _Connection):
                self._on_ready(key.data, mask)
            elif key.data == "wake":
                with contextlib.suppress(OSError):
                    self._wake_r.recv(64)
        # accept last: a connection accepted in the previous round is read before newer ones can evict it
        if any(key.data == "listener" for key, _ in ready):
            self._accept()
        self._expire(time.monotonic())

    def _next_timeout(self) -> float | None:
        if not self._connections:
            return None
        return min(1.0, max(0.0, min(c.deadline for c in self._connections) - time.monotonic()))

    def _accept(self) -> None:
        fresh: set[_Connection] = set()  # accepted in this round: none is evicted before it had a read
        for _ in range(self._max_connections):  # bounded, so open connections get their turn too
            try:
                sock, address = self._listener.accept()  # type: ignore[union-attr]
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:  # e.g. out of file descriptors: free one of ours
                logger.warning("stop channel cannot accept: %s", exc.strerror or exc)
                if (evictee := self._evictee()) is not None:
                    self._drop(evictee)
                else:
                    time.sleep(0.01)
                return
            sock.setblocking(False)
            if len(self._connections) >= self._max_connections:
                evictee = self._evictee(spare=fresh)
                if evictee is None:  # full of this round's connections: refuse the newest instead
                    sock.close()
                    continue
                self._drop(evictee)
            conn = _Connection(sock, f"{address[0]}:{address[1]}", time.monotonic() + self._request_timeout_s)
            self._connections[conn] = None
            self._selector.register(sock, selectors.EVENT_READ, conn)
            # read at once: a stop whose bytes are already here is served before a burst of newer
            # connections could evict it as an idle one
            self._on_ready(conn, selectors.EVENT_READ)
            fresh.add(conn)

    def _evictee(self, spare: frozenset[_Connection] | set[_Connection] = frozenset()) -> _Connection | None:
        """Answered connections first, then unauthenticated ones; the oldest of those; never one in `spare`."""
        candidates = [c for c in self._connections if c not in spare]
        return min(candidates, key=lambda c: (not c.answered, c.principal is not None)) if candidates else None

    def _expire(self, now: float) -> None:
        for conn in [c for c in self._connections if c.deadline <= now]:
            if not conn.answered:
                with contextlib.suppress(OSError):
                    conn.sock.send(render_response(408, {"error": "request not received in time"}))
                self._report_refusal(conn.peer, 408, "request not received in time")
            self._drop(conn)

    def _on_ready(self, conn: _Connection, mask: int) -> None:
        try:
            if conn.outgoing and mask & selectors.EVENT_WRITE:
                self._send(conn)
            elif mask & selectors.EVENT_READ:
                self._receive(conn)
        except Exception:
            logger.exception("stop channel dropped a connection from %s after an internal error", conn.peer)
            self._drop(conn)

    def _receive(self, conn: _Connection) -> None:
        room = MAX_HEAD_BYTES + MAX_BODY_BYTES - len(conn.buffer)
        try:
            data = conn.sock.recv(4096 if conn.answered else room)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            data = b""
        if not data:
            self._drop(conn)
        elif not conn.answered:  # once answered, incoming bytes are only drained
            conn.buffer += data
            self._advance(conn)

    # ------------------------------------------------------------------------------ one request
    def _advance(self, conn: _Connection) -> None:
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

    def _console_principal(self, conn: _Connection, body: bytes) -> str:
        assert conn.head is not None and self._console is not None
        ticket = parse_console_form(body, conn.head.content_type)
        try:
            return authorise_console_estop(self._console, ticket, conn.peer.rsplit(":", 1)[0])
        except HttpRefusal:
            raise
        except Exception:
            logger.exception("stop channel: the console ticket check failed; request from %s refused", conn.peer)
            raise HttpRefusal(500, "the ticket could not be checked; no stop was issued") from None

    def _console_stop(self, conn: _Connection, body: bytes) -> None:
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

    def _answer_console(self, conn: _Connection, status: int, message: str) -> None:
        back = None if self._console is None else self._console.back_url
        self._send_answer(conn, render_html_response(status, message, back))
        if status != 200:
            self._report_refusal(conn.peer, status, message)

    def _check_token(self, conn: _Connection) -> str:
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

    def _stop(self, conn: _Connection, body: bytes) -> None:
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

    # ------------------------------------------------------------------------------ answering
    def _answer(
        self, conn: _Connection, status: int, payload: dict[str, object], headers: tuple[tuple[str, str], ...] = ()
    ) -> None:
        self._send_answer(conn, render_response(status, payload, headers))
        if status != 200:
            self._report_refusal(conn.peer, status, str(payload.get("error", "")))

    def _send_answer(self, conn: _Connection, response: bytes) -> None:
        conn.answered, conn.outgoing = True, response
        conn.deadline = time.monotonic() + _LINGER_S
        self._send(conn)

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

    def _send(self, conn: _Connection) -> None:
        try:
            sent = conn.sock.send(conn.outgoing)
        except (BlockingIOError, InterruptedError):
            sent = 0
        except OSError:
            self._drop(conn)
            return
        conn.outgoing = conn.outgoing[sent:]
        if conn.outgoing:
            self._selector.modify(conn.sock, selectors.EVENT_WRITE, conn)
            return
        with contextlib.suppress(OSError):
            conn.sock.shutdown(socket.SHUT_WR)
        self._selector.modify(conn.sock, selectors.EVENT_READ, conn)
        self._after_reply(conn)

    def _drop(self, conn: _Connection) -> None:
        if conn not in self._connections:
            return
        del self._connections[conn]
        with contextlib.suppress(KeyError, ValueError):
            self._selector.unregister(conn.sock)
        conn.sock.close()
        self._after_reply(conn)  # a stop is reported even when its answer could not be delivered

    def _after_reply(self, conn: _Connection) -> None:
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
