"""Streamable HTTP transport: ``/mcp`` behind Host/Origin checks and bearer tokens, plus ``/healthz``.

Request path (outermost first)::

    uvicorn ─▶ HostOriginGuard ─▶ BearerAuth ─▶ AuthContextMiddleware ─▶ AbandonedMotionStop ─▶ routes
               421 bad Host      401 + WWW-     (SDK: publishes the     (413 over 1 MiB; a      /healthz
               403 bad Origin    Authenticate   user to get_access_     motion call whose       /mcp
               (every path)      (all but       token())                request ends unanswered
                                 /healthz)                              is cancelled)

- With a `console` app, ``/console`` is mounted beside ``/mcp``: it authenticates by itself
  (its session cookie, `armwarden.console`), so `BearerAuth` lets its paths through; Host/Origin
  are checked there like everywhere.
- Host/Origin validation (DNS rebinding) uses the SDK's `TransportSecuritySettings` and
  `TransportSecurityMiddleware.validate_request` on *every* path, before credentials are looked
  at; the same settings are handed to the SDK transport, which checks ``/mcp`` again.
  Allowed Host values: the bind ``host:port`` plus ``127.0.0.1``/``localhost``/``[::1]`` on that
  port, plus `allowed_hosts`. A wildcard bind (``0.0.0.0``/``::``) is not a Host a client sends:
  pass the names clients use in `allowed_hosts`. Requests without an Origin (non-browser
  clients) pass; with one, it must be ``http://<allowed host>`` or listed in `allowed_origins`.
- With a `TokenStore`, every path except ``/healthz`` needs ``Authorization: Bearer <token>``
  (`bearer.BearerAuth`).
  The authenticated `Principal` becomes the SDK's `AuthenticatedUser`/`AccessToken`
  (``client_id`` = token name, ``subject`` = a fingerprint of the token, ``scopes`` = [role]); the
  SDK copies it into the task that runs the tool under both protocol revisions, binds sessions and
  sealed ``requestState`` to it (so to that very token, not just its name), and
  `current_principal` reads it back inside a tool. The Authorization header is removed from the
  request before it reaches the SDK, so ``ctx.headers`` never carries the token.
  Without a token store there is no principal (`current_principal` returns None) and
  `check_bind_safety` only allows loopback binds.
- With `metrics` (a function returning the Prometheus exposition), ``GET /metrics`` serves it
  behind the same Host/Origin checks and bearer tokens (any role: an observer's is enough). A
  scrape refused for its token is handed to `on_refused` (the shared refusal limiter and the
  audit log: a flood of them is thinned); a scrape served is not recorded (it would flood the log).
- `serve_http` runs uvicorn without installing signal handlers (the daemon owns SIGINT/SIGTERM and
  sets the `shutdown` event), without access logs, and with a bounded graceful shutdown so that
  open SSE streams cannot hold the process. It believes no proxy header (X-Forwarded-For,
  -Proto): the peer every record names and every per-host limit counts is the socket's, so a
  client cannot forge it (uvicorn would trust them from loopback by default).
"""

from __future__ import annotations

import contextlib
import logging
import socket
from collections.abc import AsyncIterator, Callable, Iterator, Sequence
from typing import Any

import anyio
import uvicorn
from mcp.server.mcpserver import MCPServer
from mcp.server.transport_security import TransportSecurityMiddleware, TransportSecuritySettings
from prometheus_client import CONTENT_TYPE_LATEST
from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.requests import Request
from starlette.responses import JSONResponse, RedirectResponse, Response
from starlette.routing import Mount, Route, request_response
from starlette.types import ASGIApp, Receive, Scope, Send

from armwarden.core.errors import ConfigurationError
from armwarden.stopchannel.listener import is_loopback
from armwarden.transport.abandoned import AbandonedCallback, AbandonedMotionStop
from armwarden.transport.bearer import BearerAuth
from armwarden.transport.jsonrpc import LatchOnRefusal, RefusedCallback, StopOnReceipt
from armwarden.transport.mcp_middleware import LatchEstopsNotRun, mark_dispatched
from armwarden.transport.tokens import TokenStore

__all__ = [
    "CONSOLE_PATH",
    "HEALTH_PATH",
    "MCP_PATH",
    "METRICS_PATH",
    "bind_http_socket",
    "build_console_only_app",
    "build_http_app",
    "check_bind_safety",
    "is_loopback_host",
    "serve_http",
    "transport_security_settings",
]

logger = logging.getLogger(__name__)

MCP_PATH = "/mcp"
HEALTH_PATH = "/healthz"
CONSOLE_PATH = "/console"
METRICS_PATH = "/metrics"
PUBLIC_PATHS = frozenset({HEALTH_PATH})
"""Paths served without a bearer token (Host/Origin are still checked)."""

_LOOPBACK_NAMES = frozenset({"localhost", "localhost."})


# ------------------------------------------------------------------------ bind safety
def is_loopback_host(host: str) -> bool:
    """True for 127.0.0.0/8, ::1 (also bracketed or IPv4-mapped) and 'localhost'."""
    name = host.strip().lower()
    if name in _LOOPBACK_NAMES:
        return True
    if name.startswith("[") and name.endswith("]"):
        name = name[1:-1]
    return is_loopback(name)  # other host names may resolve anywhere: not loopback


def check_bind_safety(host: str, token_store: TokenStore | None) -> None:
    """Refuse (ConfigurationError) to serve a non-loopback address without bearer tokens."""
    if token_store is None and not is_loopback_host(host):
        raise ConfigurationError(
            f"refusing to serve HTTP on {host!r} without bearer tokens: anyone who can reach it could move "
            "the robot. Bind 127.0.0.1 (or ::1/localhost), or pass a token file "
            "(create one with 'armwarden tokens add FILE --role operator')."
        )


# ------------------------------------------------------------------------ Host / Origin
def _host_header(host: str, port: int) -> Iterator[str]:
    bracketed = f"[{host}]" if ":" in host and not host.startswith("[") else host
    yield f"{bracketed}:{port}"
    if port == 80:  # clients omit the default port
        yield bracketed


def transport_security_settings(
    host: str, port: int, *, allowed_hosts: Sequence[str] = (), allowed_origins: Sequence[str] = ()
) -> TransportSecuritySettings:
    """DNS-rebinding settings: the bind address, loopback names and `allowed_hosts` on `port`.

    `allowed_hosts` entries may be ``name`` (port `port` implied), ``name:port`` or ``name:*``.
    """
    hosts: list[str] = []
    for name in (host, "127.0.0.1", "localhost", "::1"):
        hosts.extend(_host_header(name, port))
    for entry in allowed_hosts:
        bare_ipv6 = entry.count(":") > 1 and not entry.startswith("[")
        has_port = not bare_ipv6 and (entry.rsplit(":", 1)[-1].isdigit() or entry.endswith(":*"))
        hosts.extend([entry] if has_port else _host_header(entry, port))
    hosts = list(dict.fromkeys(hosts))
    origins = list(dict.fromkeys([*(f"http://{value}" for value in hosts), *allowed_origins]))
    return TransportSecuritySettings(enable_dns_rebinding_protection=True, allowed_hosts=hosts, allowed_origins=origins)


class HostOriginGuard:
    """Pure ASGI: reject a foreign Host (421) or Origin (403) on every HTTP path; no WebSockets."""

    def __init__(self, app: ASGIApp, settings: TransportSecuritySettings) -> None:
        self.app = app
        self.checker = TransportSecurityMiddleware(settings)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "websocket":  # nothing here speaks WebSocket: refuse before any check
            await send({"type": "websocket.close", "code": 1008})
            return
        if scope["type"] == "http":
            rejection = await self.checker.validate_request(Request(scope), is_post=False)
            if rejection is not None:
                await rejection(scope, receive, send)
                return
        await self.app(scope, receive, send)


def _metrics_route(metrics: Callable[[], bytes], token_store: TokenStore | None = None,
                   on_refused: RefusedCallback | None = None) -> Route:
    """``GET /metrics``: the exposition, built on a worker thread so a scrape never holds up the
    event loop. With `token_store`, behind its own `BearerAuth` (the console-only app has none)."""

    async def scrape(request: Request) -> Response:
        body = await anyio.to_thread.run_sync(metrics)
        return Response(body, media_type=CONTENT_TYPE_LATEST)

    if token_store is None:
        return Route(METRICS_PATH, scrape, methods=["GET"])
    guarded = BearerAuth(request_response(scrape), token_store, on_refused=on_refused, reported_paths=(METRICS_PATH,))
    return Route(METRICS_PATH, guarded, methods=["GET"])


# ------------------------------------------------------------------------ the app
def build_http_app(
    server: MCPServer,
    *,
    host: str,
    port: int,
    token_store: TokenStore | None,
    allowed_origins: Sequence[str] = (),
    allowed_hosts: Sequence[str] = (),
    health: Callable[[], dict[str, Any]] | None = None,
    on_abandoned: AbandonedCallback | None = None,
    on_stop_request: StopOnReceipt | None = None,
    console: ASGIApp | None = None,
    on_refused: RefusedCallback | None = None,
    on_estop_refused: LatchOnRefusal | None = None,
    metrics: Callable[[], bytes] | None = None,
) -> Starlette:
    """The ASGI app: ``/mcp`` (stateful streamable HTTP), ``/healthz`` and, when given, the
    operator `console` at ``/console`` (its own sign-in instead of bearer tokens; Host/Origin
    checked like every path) and the Prometheus exposition `metrics()` at ``/metrics`` (bearer
    tokens like ``/mcp``; a refused scrape goes to `on_refused`).

    Build one app per serve: the SDK's session manager it creates can run only once.
    ``/healthz`` needs no token: `health` must be quick, non-blocking and return JSON-able data that
    tells anyone on the network nothing but that the server is up (the daemon passes none).
    `on_abandoned(tool, arguments, request_id, cancelled)` is awaited after an authenticated motion
    call's request ended without its response and the call was cancelled (see `abandoned.py`).
    `on_stop_request(tool, principal)` is called the moment an `estop`/`stop_motion` request is read,
    before the SDK queues it: it must be quick and thread-safe (it holds the robot).
    `on_refused(refused)` is awaited for a request refused before the tools saw it (a body over
    1 MiB, a duplicate id, malformed `tools/call` params, any error answer the SDK gives a
    `tools/call` before its dispatch), before it is answered.
    `on_estop_refused(reason, principal, why)` latches the e-stop for an `estop` request that was
    read but will not run (refused before or by the SDK, or cancelled), before its answer: quick,
    thread-safe, never waits for the disk.
    """
    security = transport_security_settings(host, port, allowed_hosts=allowed_hosts, allowed_origins=allowed_origins)
    mcp_app = server.streamable_http_app(
        streamable_http_path=MCP_PATH,
        stateless_http=False,  # 2025-11-25 clients need the session's back-channel to elicit
        json_response=False,
        transport_security=security,
        host=host,
    )
    session_manager = server.session_manager  # created by streamable_http_app(); run() works once
    if mark_dispatched not in server.middleware:  # outermost: tells AbandonedMotionStop what the tools saw
        server.middleware.insert(0, mark_dispatched)
    server.middleware[:] = [layer for layer in server.middleware if not isinstance(layer, LatchEstopsNotRun)]
    if on_estop_refused is not None:  # right inside it: an estop the SDK refuses after dispatch still latches
        server.middleware.insert(server.middleware.index(mark_dispatched) + 1, LatchEstopsNotRun(on_estop_refused))

    @contextlib.asynccontextmanager
    async def lifespan(app: Starlette) -> AsyncIterator[None]:
        # A mounted app's own lifespan never runs: without this, every /mcp request is a 500.
        async with session_manager.run():
            yield

    async def healthz(request: Request) -> Response:
        if health is None:
            return JSONResponse({"status": "ok"})
        try:
            return JSONResponse(health())
        except Exception:
            logger.exception("health callback failed")
            return JSONResponse({"status": "error"}, status_code=503)

    middleware = [Middleware(HostOriginGuard, settings=security)]
    if token_store is not None:
        middleware.append(Middleware(BearerAuth, token_store=token_store,
                                     own_auth_prefixes=(CONSOLE_PATH,) if console is not None else (),
                                     on_refused=on_refused, reported_paths=(METRICS_PATH,),
                                     public_paths=PUBLIC_PATHS))
    # innermost: only requests that passed the checks above; always on (it also bounds POST bodies)
    middleware.append(Middleware(AbandonedMotionStop, path=MCP_PATH, on_abandoned=on_abandoned,
                                 on_stop_request=on_stop_request, on_refused=on_refused,
                                 on_estop_refused=on_estop_refused))
    routes: list[Route | Mount] = [Route(HEALTH_PATH, healthz, methods=["GET"])]
    if console is not None:
        routes.append(Mount(CONSOLE_PATH, app=console))
    if metrics is not None:
        routes.append(_metrics_route(metrics))
    return Starlette(
        routes=[*routes, Mount("/", app=mcp_app)],
        middleware=middleware,
        lifespan=lifespan,
    )


def build_console_only_app(console: ASGIApp, *, host: str, port: int, allowed_hosts: Sequence[str] = (),
                           allowed_origins: Sequence[str] = (), metrics: Callable[[], bytes] | None = None,
                           token_store: TokenStore | None = None, on_refused: RefusedCallback | None = None) -> Starlette:
    """The operator console alone (``--console-port`` on stdio): ``/console`` behind the same
    Host/Origin checks as the HTTP transport; ``/`` redirects there. With `metrics`, ``GET
    /metrics`` beside it, behind `token_store`'s bearer tokens as on the HTTP transport (without
    a token store, open like the console's port: loopback only, `check_bind_safety`)."""
    security = transport_security_settings(host, port, allowed_hosts=allowed_hosts, allowed_origins=allowed_origins)

    async def to_console(request: Request) -> Response:
        return RedirectResponse(CONSOLE_PATH + "/", status_code=303)

    routes: list[Route | Mount] = [Route("/", to_console, methods=["GET"]), Mount(CONSOLE_PATH, app=console)]
    if metrics is not None:
        routes.append(_metrics_route(metrics, token_store, on_refused))
    return Starlette(routes=routes, middleware=[Middleware(HostOriginGuard, settings=security)])


# ------------------------------------------------------------------------ serving
class _Server(uvicorn.Server):
    """uvicorn without its signal handlers; `started_event` is set once the socket listens."""

    def __init__(self, config: uvicorn.Config, started_event: anyio.Event | None) -> None:
        super().__init__(config)
        self._started_event = started_event

    @contextlib.contextmanager
    def capture_signals(self) -> Iterator[None]:
        yield  # the daemon handles SIGINT/SIGTERM and sets the shutdown event

    async def startup(self, sockets: list[socket.socket] | None = None) -> None:
        await super().startup(sockets)
        if self.started and self._started_event is not None:
            self._started_event.set()


def bind_http_socket(host: str, port: int) -> socket.socket:
    """A socket bound to host:port (not yet listening) for `serve_http`: bound first, so that port 0
    becomes the real port before anything built from it (Host checks, links) is made, and a busy
    port is a ConfigurationError instead of uvicorn's sys.exit."""
    try:
        family, kind, proto, _, address = socket.getaddrinfo(
            host.strip("[]"), port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
        )[0]
        sock = socket.socket(family, kind, proto)
    except OSError as exc:
        raise ConfigurationError(f"cannot bind HTTP to {host}:{port}: {exc}") from exc
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(address)
        sock.set_inheritable(True)
    except OSError as exc:
        sock.close()
        raise ConfigurationError(f"cannot bind HTTP to {host}:{port}: {exc.strerror or exc}") from exc
    return sock


async def serve_http(
    app: ASGIApp,
    host: str,
    port: int,
    *,
    ready: anyio.Event | None = None,
    shutdown: anyio.Event | None = None,
    graceful_shutdown_s: int = 3,  # whole seconds, as uvicorn takes them
    log_level: str = "warning",
    sock: socket.socket | None = None,
) -> None:
    """Serve `app` on host:port until `shutdown` is set (or the task is cancelled).

    The socket is bound before anything else (or given: `sock`, from `bind_http_socket`; it is
    closed here either way), so a busy port raises ConfigurationError here instead of uvicorn
    calling sys.exit. `ready` is set once requests are accepted. Open connections (SSE streams)
    get `graceful_shutdown_s` seconds [s] to finish.
    Logs go through the `uvicorn` loggers to whatever handlers the daemon configured (stderr).
    """
    if sock is None:
        sock = bind_http_socket(host, port)
    config = uvicorn.Config(
        app,
        host=host,  # for uvicorn's messages only: it serves the socket bound above
        port=port,
        log_config=None,  # keep the daemon's logging (stderr); uvicorn's default sends access logs to stdout
        log_level=log_level,
        access_log=False,
        lifespan="on",
        timeout_graceful_shutdown=graceful_shutdown_s,
        server_header=False,
        proxy_headers=False,  # the socket's peer, never a header's claim (no proxy is in front of us)
        forwarded_allow_ips=[],  # and no address trusted to make that claim, whatever FORWARDED_ALLOW_IPS says
    )
    server = _Server(config, ready)

    async def stop_on_shutdown() -> None:
        assert shutdown is not None
        await shutdown.wait()
        server.should_exit = True

    try:
        async with anyio.create_task_group() as tg:
            if shutdown is not None:
                tg.start_soon(stop_on_shutdown)
            await server.serve(sockets=[sock])
            tg.cancel_scope.cancel()
    finally:
        sock.close()
    if not server.started:
        raise ConfigurationError(f"HTTP server on {host}:{port} did not start (see the log above)")
