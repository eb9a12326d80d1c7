"""HTTP serving: `/mcp` with the console and `/metrics` (`--transport http`), or the console alone
on `--console-port` (stdio). The socket is bound before anything is built from its port, and every
start-up line is logged once it accepts requests."""

from __future__ import annotations

import logging
import socket
from typing import Any

import anyio

from armwarden.core.errors import ConfigurationError
from armwarden.daemon.options import ServeOptions
from armwarden.daemon.refusals import refusal_recorder, refused_estop_latch
from armwarden.daemon.startup import Assembly
from armwarden.daemon.stops import ConsoleStop
from armwarden.endpoints import Endpoints, link_host, startup_lines
from armwarden.stopchannel import StopChannel
from armwarden.stopchannel.external import ExternalStops

logger = logging.getLogger("armwarden")

def bind_listener(options: ServeOptions) -> tuple[ServeOptions, socket.socket | None]:
    """Bind the HTTP socket (`--port`, or `--console-port` on stdio) before anything is built from
    its port: with port 0, the Host checks, the console's links and origins and every start-up
    line then name the port really bound. Returns `options` with that port, and the socket.
    (Plain stdio imports nothing of the HTTP transport: tests/server/test_daemon_stdio.py.)"""
    address = options.console_address() if options.transport == "stdio" else (options.host, options.port)
    if address is None:
        return options, None
    from armwarden.transport.http import bind_http_socket

    sock = bind_http_socket(*address)
    return options.with_bound_port(int(sock.getsockname()[1])), sock


def served_endpoints(options: ServeOptions, channel: StopChannel | None, console_stop: ConsoleStop) -> Endpoints:
    """What this daemon serves, for its start-up lines (ports already bound)."""
    return Endpoints(
        tokens=options.auth_tokens,
        mcp=(options.host, options.port) if options.transport == "http" else None,
        console=options.console_address(),
        channel=None if channel is None else (options.stop_channel_host, channel.port),
        channel_takes_tokens=options.stop_channel_takes_tokens,
        console_posts_to_channel=console_stop.estop_url is not None)


def log_startup_lines(served: Endpoints) -> None:
    for line in startup_lines(served):
        logger.info("%s", line)


async def _serve_then_announce(app: Any, host: str, port: int, shutdown: anyio.Event | None,
                               listener: socket.socket | None, served: Endpoints | None) -> None:
    """`serve_http`, logging `served`'s start-up lines once requests are accepted (not before: a
    URL in the log answers)."""
    from armwarden.transport.http import serve_http

    ready = anyio.Event()
    async with anyio.create_task_group() as group:
        async def announce() -> None:
            await ready.wait()
            if served is not None:
                log_startup_lines(served)

        group.start_soon(announce)
        await serve_http(app, host, port, shutdown=shutdown, ready=ready, sock=listener)
        group.cancel_scope.cancel()


def _console_app(options: ServeOptions, assembly: Assembly, external: ExternalStops, tokens: Any,
                 console_stop: ConsoleStop | None = None) -> Any:
    """The operator console for this daemon (docs/console.md): sign-in with `tokens` (None: nobody
    can sign in), the E-STOP button posting to the stop channel (`console_stop`; its own route,
    on the stop channel's thread-safe path, as the fallback), approval answers when the policy's
    `approval.channel` is url or both."""
    from armwarden.console import ConsoleSettings, SessionStore, build_console_app, timed_estop

    settings = ConsoleSettings(
        estop_from_loopback_without_sign_in=not options.console_estop_needs_sign_in,
        answer_approvals=assembly.policy.approval.channel in ("url", "both"),
        estop_url=None if console_stop is None else console_stop.estop_url)
    hook = timed_estop(external.latch_and_stop_for("console"), external.record)
    sessions = SessionStore(tokens) if console_stop is None else console_stop.sessions
    return build_console_app(assembly.guard, sessions, hook, settings, assembly.refusal_reports_for("console"))


async def serve_console_alone(options: ServeOptions, assembly: Assembly, external: ExternalStops,
                         console_stop: ConsoleStop | None = None, shutdown: anyio.Event | None = None,
                         listener: socket.socket | None = None, served: Endpoints | None = None) -> None:
    """``--console-port`` (stdio): the console alone on its own port (`listener`, bound already),
    until `shutdown` is set (it then closes its connections and returns) or it is cancelled.
    `served`: the start-up lines logged once it listens."""
    from armwarden.transport.http import build_console_only_app
    from armwarden.transport.tokens import TokenStore

    address = options.console_address()
    if address is None:  # only run with --console-port on stdio
        raise ConfigurationError("no console address: the console alone is served only with --console-port")
    host, port = address
    tokens = TokenStore.load(options.auth_tokens) if options.auth_tokens else None
    app = build_console_only_app(_console_app(options, assembly, external, tokens, console_stop), host=host,
                                 port=port, allowed_hosts=options.allowed_hosts,
                                 allowed_origins=options.allowed_origins,
                                 metrics=None if assembly.metrics is None else assembly.metrics.exposition,
                                 token_store=tokens, on_refused=refusal_recorder(assembly))
    assembly.guard.approvals.console_url = f"http://{link_host(host)}:{port}/console"
    await _serve_then_announce(app, host, port, shutdown, listener, served)


async def serve_http_clients(options: ServeOptions, assembly: Assembly, external: ExternalStops, shutdown: anyio.Event,
                      console_stop: ConsoleStop | None = None, listener: socket.socket | None = None,
                      served: Endpoints | None = None) -> None:
    """``/mcp`` (and the console, ``/metrics``) on `listener`, bound already to ``--port``; logs
    `served`'s start-up lines once it listens."""
    from armwarden.transport.access import current_principal
    from armwarden.transport.http import build_http_app
    from armwarden.transport.tokens import TokenStore

    tokens = TokenStore.load(options.auth_tokens) if options.auth_tokens else None

    async def on_abandoned(tool: str, arguments: dict[str, Any], request_id: Any, cancelled: bool | None) -> None:
        principal = current_principal()
        await assembly.guard.abandoned_call(tool, arguments, request_id, cancelled,
                                            principal=None if principal is None else principal.name)

    console = None if options.no_console else _console_app(options, assembly, external, tokens,
                                                                            console_stop)
    if console is not None:  # the link URL-mode approvals send
        assembly.guard.approvals.console_url = f"http://{link_host(options.host)}:{options.port}/console"
    # /healthz answers without a token: it says only that the daemon is up, never the arm's state
    app = build_http_app(assembly.server.mcp, host=options.host, port=options.port, token_store=tokens,
                         on_abandoned=on_abandoned, on_stop_request=external.stop_on_receipt, console=console,
                         on_refused=refusal_recorder(assembly),
                         on_estop_refused=refused_estop_latch(assembly, external),
                         allowed_hosts=options.allowed_hosts,
                         allowed_origins=options.allowed_origins,
                         metrics=None if assembly.metrics is None else assembly.metrics.exposition)
    await _serve_then_announce(app, options.host, options.port, shutdown, listener, served)
