"""The stop channel's connections: one thread, one listening socket, bounded one-shot requests.

Why apart from the e-stop requests: what keeps a real stop from being locked out is here, and it
knows nothing of HTTP or tokens. One thread serves every connection from a `selectors` loop over
non-blocking sockets; a request must arrive whole before its deadline; at most `max_connections`
are open, and a new connection evicts the least useful open one (answered first, then
unauthenticated, oldest first); every answer is the last thing sent before the connection closes.
`StopChannel` subclasses `ConnectionLoop` and supplies what a request means (`_advance`), the
answer to one that came too late (`_on_timeout`) and what follows a reply (`_after_reply`).
"""

from __future__ import annotations

import contextlib
import logging
import selectors
import socket
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from armwarden.core.errors import ConfigurationError
from armwarden.stopchannel.listener import open_listener
from armwarden.stopchannel.wire import MAX_BODY_BYTES, MAX_HEAD_BYTES

if TYPE_CHECKING:  # pragma: no cover
    from armwarden.stopchannel.records import ChannelStop
    from armwarden.stopchannel.wire import RequestHead

__all__ = ["Connection", "ConnectionLoop"]

logger = logging.getLogger(__name__)

_LINGER_S = 0.25  # after answering, how long unread request bytes are drained (avoids a reset eating the answer)


@dataclass(eq=False)
class Connection:
    """One open connection and the one request it may carry (parsed by the channel as it arrives)."""

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


class ConnectionLoop:
    """Bounded one-shot connections on their own thread and socket. `start` binds, `close` stops;
    idempotent. Subclasses answer requests through `_send_answer`."""

    def __init__(
        self, *, host: str, port: int, allow_non_loopback: bool, max_connections: int, request_timeout_s: float
    ) -> None:
        if not 0 <= port <= 65535:
            raise ConfigurationError(f"stop channel port {port} is outside 0-65535")
        if max_connections < 1:
            raise ConfigurationError(f"stop channel max_connections must be at least 1, got {max_connections}")
        if not request_timeout_s > 0:
            raise ConfigurationError(f"stop channel request_timeout_s must be positive, got {request_timeout_s}")
        self._host, self._port = host, port
        self._allow_non_loopback = allow_non_loopback
        self._max_connections = max_connections
        self._request_timeout_s = request_timeout_s
        self._connections: dict[Connection, None] = {}  # insertion order = age
        self._selector = selectors.DefaultSelector()
        self._listener: socket.socket | None = None
        self._wake_r, self._wake_w = socket.socketpair()
        self._thread: threading.Thread | None = None
        self._closing = threading.Event()
        self._lifecycle = threading.Lock()

    # ------------------------------------------------------------------------------ what a subclass supplies
    def _advance(self, conn: Connection) -> None:
        """New request bytes arrived in `conn.buffer`: parse, and answer once the request is whole."""
        raise NotImplementedError

    def _on_timeout(self, conn: Connection) -> None:
        """`conn`'s request did not arrive whole in time: tell its peer (best effort), just before it is dropped."""
        raise NotImplementedError

    def _after_reply(self, conn: Connection) -> None:
        """`conn`'s answer is out (or the connection is gone): report what the request did."""

    def _after_close(self) -> None:
        """The loop has stopped (once, from `close`): release what the subclass holds."""

    # ------------------------------------------------------------------------------ lifecycle
    def start(self) -> ConnectionLoop:
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
            self._after_close()
            return
        with contextlib.suppress(OSError):
            self._wake_w.send(b"x")
        if thread is not threading.current_thread():
            thread.join(timeout=5.0)
            if thread.is_alive():
                logger.error("stop channel thread did not finish within 5 s (a callback is blocking it)")
        self._after_close()

    @property
    def port(self) -> int:
        """The bound port (the real one after `start` when 0 was asked for)."""
        return int(self._port)

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
            if isinstance(key.data, Connection):
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
        fresh: set[Connection] = set()  # accepted in this round: none is evicted before it had a read
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
            conn = Connection(sock, f"{address[0]}:{address[1]}", time.monotonic() + self._request_timeout_s)
            self._connections[conn] = None
            self._selector.register(sock, selectors.EVENT_READ, conn)
            # read at once: a stop whose bytes are already here is served before a burst of newer
            # connections could evict it as an idle one
            self._on_ready(conn, selectors.EVENT_READ)
            fresh.add(conn)

    def _evictee(self, spare: frozenset[Connection] | set[Connection] = frozenset()) -> Connection | None:
        """Answered connections first, then unauthenticated ones; the oldest of those; never one in `spare`."""
        candidates = [c for c in self._connections if c not in spare]
        return min(candidates, key=lambda c: (not c.answered, c.principal is not None)) if candidates else None

    def _expire(self, now: float) -> None:
        for conn in [c for c in self._connections if c.deadline <= now]:
            if not conn.answered:
                self._on_timeout(conn)
            self._drop(conn)

    def _on_ready(self, conn: Connection, mask: int) -> None:
        try:
            if conn.outgoing and mask & selectors.EVENT_WRITE:
                self._send(conn)
            elif mask & selectors.EVENT_READ:
                self._receive(conn)
        except Exception:
            logger.exception("stop channel dropped a connection from %s after an internal error", conn.peer)
            self._drop(conn)

    def _receive(self, conn: Connection) -> None:
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

    # ------------------------------------------------------------------------------ answering
    def _send_answer(self, conn: Connection, response: bytes) -> None:
        conn.answered, conn.outgoing = True, response
        conn.deadline = time.monotonic() + _LINGER_S
        self._send(conn)

    def _send(self, conn: Connection) -> None:
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

    def _drop(self, conn: Connection) -> None:
        if conn not in self._connections:
            return
        del self._connections[conn]
        with contextlib.suppress(KeyError, ValueError):
            self._selector.unregister(conn.sock)
        conn.sock.close()
        self._after_reply(conn)  # a stop is reported even when its answer could not be delivered
