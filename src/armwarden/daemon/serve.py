"""`armwarden serve`: assemble policy, robot model, backend, audit log and Guard, then serve MCP.

Start-up refuses (exit 2, before serving) on an invalid policy, an unavailable backend, an audit
log that cannot be opened, or an unsafe bind. On SIGTERM, SIGINT or end of stdin the daemon
stops the arm and the gripper, closes the backend, writes a final audit record and closes the
log; if that record cannot be written (a full audit disk) it says so and exits with
`EXIT_AUDIT_INCOMPLETE` (3).

Two stops bypass MCP and the event loop (docs/architecture.md, "Independent stop channel"):
SIGUSR1 always, and with `--estop-port` the stop channel (`POST /estop`, any token's role).
Whenever the operator console is served, a stop channel listens too (`--estop-port`, or an
ephemeral loopback port only for the console): the console's E-STOP button posts there.

Once it listens, `serve` logs (INFO) every URL it serves and what each one takes (`endpoints`),
with the ports it really bound: the HTTP socket is bound before anything is built from its port,
so `--port 0` / `--console-port 0` serve, check Host headers and link on the real port.
"""

from __future__ import annotations

import asyncio
import gc
import logging
import os
import signal
import socket
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import anyio

from armwarden import __version__
from armwarden.assembly import build_backend, build_guard, plan_previewer
from armwarden.audit import DEFAULT_COMMIT_WINDOW_S, AuditLog, AuditWriteError, hmac_key_for_serving
from armwarden.backends.base import Backend
from armwarden.core.errors import ArmWardenError, BackendError, BackendUnavailable, ConfigurationError, PolicyError
from armwarden.daemon.options import EXIT_REFUSED, ServeOptions
from armwarden.endpoints import Endpoints, link_host, startup_lines
from armwarden.extras import log_feature_lines
from armwarden.greeting import first_contact_line, started_from_terminal
from armwarden.guard import Guard
from armwarden.metrics import DaemonMetrics
from armwarden.policy import Policy, load_policy, policy_digest
from armwarden.preflight import RuntimeModel, load_runtime_model
from armwarden.robot import RobotModel, build_robot
from armwarden.safety.estop import flatten_reason
from armwarden.safety.refusals import RefusalReports, left_out_recorder
from armwarden.server.app import ArmWardenServer
from armwarden.stopchannel import ConsoleDoor, StopChannel, token_store_authenticator
from armwarden.stopchannel.external import ExternalStops
from armwarden.stopchannel.signals import SignalStop

if TYPE_CHECKING:
    from armwarden.transport.jsonrpc import LatchOnRefusal, RefusedCallback, RefusedRequest

logger = logging.getLogger("armwarden")

#: the daemon served, then stopped the arm and closed everything, but its final audit record
#: (`shutdown`) could not be written (e.g. the audit disk is full): the log ends without it
EXIT_AUDIT_INCOMPLETE = 3
#: GIL hand-off interval while planning runs on its worker thread: bounds how long a stop request
#: on the event loop can wait for the interpreter [s] (CPython's default is 5 ms)
SWITCH_INTERVAL_S = 0.0005
#: allocations between two young-generation collections (CPython's default is 700; 2000 from 3.13):
#: fewer collections, so fewer of the interpreter-wide pauses that even the stop channel waits out
GC_YOUNG_THRESHOLD = 10_000
#: after SIGTERM/SIGINT on stdio: time for cancelled calls to stop the arm and audit themselves [s]
SIGNAL_GRACE_S = 0.3
#: at the end of a stdio session: time the console's server (`--console-port`) has to close its
#: connections and return before it is cancelled [s] (its own graceful shutdown takes up to 3 s)
CONSOLE_CLOSE_S = 5.0
#: records of requests a transport refused, per principal (or host): this many in a row, then one
#: per second (`RefusalReports`); a client's occasional mistakes are each recorded, a flood is not
REFUSAL_RECORDS_BURST = 20
#: why `serve` refuses a stop channel without a token file
ESTOP_PORT_NEEDS_TOKENS = "--estop-port needs --auth-tokens: the stop channel accepts any role's token, and none without one"


class FinalRecordLost(ArmWardenError):
    """The daemon shut down (arm stopped, backend and log closed) without its final audit record."""


def final_record_lost_message(why: str) -> str:
    """What `serve` says on stderr as it exits with `EXIT_AUDIT_INCOMPLETE`."""
    return (f"armwarden: final audit record could not be written: {why}; the backend and the audit log are "
            f"closed (exit status {EXIT_AUDIT_INCOMPLETE})")


@dataclass
class Assembly:
    policy: Policy
    backend: Backend
    audit: AuditLog
    guard: Guard
    server: ArmWardenServer
    #: what `/metrics` serves (docs/metrics.md)
    metrics: DaemonMetrics | None = None
    #: the limits on records of refused requests of every door: closed (their counts of refusals
    #: left out recorded) before the final record
    refusal_reports: list[RefusalReports] = field(default_factory=list)

    def refusal_reports_for(self, door: str, **options: Any) -> RefusalReports:
        """A limit on records of `door`'s refusals whose counts left out reach this log; closed by
        `close_assembly`."""
        reports = RefusalReports(on_left_out=left_out_recorder(self.audit, door), **options)
        self.refusal_reports.append(reports)
        return reports


def assemble(policy: Policy, backend_name: str, backend_config: str | None, audit_path: str,
             commit_window_s: float = DEFAULT_COMMIT_WINDOW_S) -> tuple[Policy, Backend, AuditLog, RuntimeModel, RobotModel]:
    """Build everything that can fail before serving (each failure is a clean exit 2).
    ``commit_window_s``: the audit log's group-commit window for read-only calls' records."""
    runtime = load_runtime_model(policy)
    state_robot = build_robot(policy)
    backend = build_backend(backend_name, policy, robot=state_robot, config_path=backend_config)
    audit = AuditLog(audit_path, hmac_key=hmac_key_for_serving(), commit_window_s=commit_window_s)
    return policy, backend, audit, runtime, state_robot


async def open_assembly(policy: Policy, backend: Backend, audit: AuditLog, runtime: RuntimeModel,
                        state_robot: RobotModel) -> Assembly:
    try:
        await backend.open()
    except ArmWardenError:
        raise
    except Exception as exc:
        raise BackendUnavailable(f"backend {backend.name} could not be opened: {exc}") from exc
    guard = build_guard(policy, backend, audit, previewer=plan_previewer(), runtime=runtime, robot=state_robot)
    metrics = DaemonMetrics(guard.latch, backend)
    audit.observe_writes(metrics.observe_audit_write)
    server = ArmWardenServer(guard, metrics=metrics)
    return Assembly(policy, backend, audit, guard, server, metrics)


async def close_assembly(assembly: Assembly, why: str) -> str | None:
    """Stop the arm and gripper, close the backend, record the counts of refusals left out, write
    the final record and close the log. Returns None, or why the final record could not be
    written and whether the arm was stopped (the log is closed all the same). Safe to call twice."""
    with anyio.CancelScope(shield=True):
        detail, stopped = why, "the arm was stopped"
        try:
            await assembly.backend.stop()
        except Exception as exc:  # the shutdown must go on; the record says the stop failed
            detail, stopped = f"{why}; stop failed: {exc}", f"the stop at shutdown FAILED: {exc}"
            logger.error("stop at shutdown failed: %s", exc)
        await assembly.backend.close()
        for reports in assembly.refusal_reports:  # handed to the writer before the final record
            reports.close()
        if assembly.audit.closed:
            return None
        try:
            await assembly.audit.append_async("shutdown", outcome="ok", detail=detail)
        except AuditWriteError as exc:  # the arm is stopped either way; the log must still be closed
            return f"{exc}; {stopped}"
        finally:
            assembly.audit.close()
        return None


@dataclass(frozen=True)
class ConsoleStop:
    """What the console shares with the stop channel: its sessions (whose E-STOP tickets the
    channel checks) and where its E-STOP button posts (None: the console's own route)."""

    sessions: Any  # armwarden.console.SessionStore
    estop_url: str | None


def _console_door(options: ServeOptions, external: ExternalStops) -> tuple[ConsoleDoor, Any] | None:
    """The stop channel's door for the console's E-STOP and the console's sessions, if served."""
    address = options.console_address()
    if address is None:
        return None
    from armwarden.console import SessionStore
    from armwarden.transport.http import transport_security_settings
    from armwarden.transport.tokens import TokenStore

    host, port = address
    sessions = SessionStore(TokenStore.load(options.auth_tokens) if options.auth_tokens else None)
    security = transport_security_settings(host, port, allowed_hosts=options.allowed_hosts,
                                           allowed_origins=options.allowed_origins)
    door = ConsoleDoor(
        check_ticket=sessions.principal_for_ticket, latch_and_stop=external.latch_and_stop_for("console"),
        allowed_origins=frozenset(security.allowed_origins or ()),
        allow_loopback_without_ticket=not options.console_estop_needs_sign_in,
        back_url=f"http://{link_host(host)}:{port}/console/safety")
    return door, sessions


def _start_external_stops(options: ServeOptions, external: ExternalStops, console: ConsoleDoor | None = None,
                          refusals: RefusalReports | None = None) -> tuple[SignalStop, StopChannel | None]:
    """SIGUSR1 and (with --estop-port, or when the console is served) the stop channel, each on
    its own thread. Without --estop-port the console gets a channel of its own on an ephemeral
    loopback port, which serves only the console's E-STOP (it takes no bearer token and says so
    to one). `refusals`: the channel's limit on records of its refusals."""
    signals = SignalStop(external.latch_and_stop_for("signal"), on_event=external.record).start()
    if options.estop_port is None and console is None:
        return signals, None
    from armwarden.transport.tokens import TokenStore

    try:
        if options.estop_port is None:
            channel = StopChannel(authenticate=None, latch_and_stop=external.latch_and_stop_for("stop_channel"),
                                  on_event=external.record, on_refused=external.record_refusal, console=console,
                                  host="127.0.0.1", port=0, refusals=refusals).start()
        elif not options.auth_tokens:
            raise ConfigurationError(ESTOP_PORT_NEEDS_TOKENS)
        else:
            channel = StopChannel(
                authenticate=token_store_authenticator(TokenStore.load(options.auth_tokens)),
                latch_and_stop=external.latch_and_stop_for("stop_channel"), on_event=external.record,
                on_refused=external.record_refusal, console=console,
                host=options.estop_host, port=options.estop_port, allow_non_loopback=True,  # tokens are required
                refusals=refusals,
            ).start()
    except BaseException:
        signals.close()
        raise
    return signals, channel


def _console_stop(options: ServeOptions, channel: StopChannel | None, sessions: Any) -> ConsoleStop:
    """Where the console's button posts: the channel, when a browser of the console can reach it.
    A console on a non-loopback address with the channel on loopback keeps its own route."""
    address = options.console_address()
    if channel is None or address is None:
        return ConsoleStop(sessions, None)
    from armwarden.transport.http import is_loopback_host

    channel_host = options.stop_channel_host
    if is_loopback_host(channel_host) and not is_loopback_host(address[0]):
        logger.warning("the console on %s cannot reach the stop channel on %s: its E-STOP button posts to "
                       "the console's own route (give --estop-host/--estop-port the browser can reach)",
                       address[0], channel_host)
        return ConsoleStop(sessions, None)
    return ConsoleStop(sessions, f"http://{link_host(channel_host)}:{channel.port}/console-estop")


def _bind_listener(options: ServeOptions) -> tuple[ServeOptions, socket.socket | None]:
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


def _endpoints(options: ServeOptions, channel: StopChannel | None, console_stop: ConsoleStop) -> Endpoints:
    """What this daemon serves, for its start-up lines (ports already bound)."""
    return Endpoints(
        tokens=options.auth_tokens,
        mcp=(options.host, options.port) if options.transport == "http" else None,
        console=options.console_address(),
        channel=None if channel is None else (options.stop_channel_host, channel.port),
        channel_takes_tokens=options.stop_channel_takes_tokens,
        console_posts_to_channel=console_stop.estop_url is not None)


def _log_startup_lines(served: Endpoints) -> None:
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
                _log_startup_lines(served)

        group.start_soon(announce)
        await serve_http(app, host, port, shutdown=shutdown, ready=ready, sock=listener)
        group.cancel_scope.cancel()


def freeze_long_lived_objects() -> None:
    """Everything built so far lives as long as the daemon: keep it out of every later garbage
    collection, and collect the young generation less often. A collection holds the interpreter
    lock, so its length bounds how long the stop channel's and the servo loop's threads can wait
    (docs/benchmarks.md, "E-stop under a flood"; a physics backend's clock stalls meanwhile)."""
    gc.collect()
    gc.freeze()
    gc.set_threshold(GC_YOUNG_THRESHOLD, *gc.get_threshold()[1:])


async def _run(options: ServeOptions, parts: tuple) -> None:
    assembly = await open_assembly(*parts)
    why = "shutdown"
    lost: str | None = None  # why the final record could not be written
    shutdown = anyio.Event()
    signal_stop, channel = None, None
    listener: socket.socket | None = None
    external = ExternalStops(assembly.guard.stopper, assembly.audit, asyncio.get_running_loop())
    try:
        options, listener = _bind_listener(options)
        door = _console_door(options, external)
        signal_stop, channel = _start_external_stops(options, external, None if door is None else door[0],
                                                     assembly.refusal_reports_for("stop_channel"))
        console_stop = _console_stop(options, channel, None if door is None else door[1])
        served = _endpoints(options, channel, console_stop)
        log_feature_lines(logger, assembly.policy.enabled_tools)  # what each absent optional dependency removes
        freeze_long_lived_objects()
        await assembly.audit.append_async(
            "startup",
            outcome="ok",
            detail=f"armwarden {__version__} serving {options.transport} with the {options.backend} backend",
            extra={"policy": options.policy_label, "policy_digest": policy_digest(assembly.policy),
                   "dry_run": assembly.policy.dry_run,
                   "tools": assembly.server.tools, "stop_channel": None if channel is None else channel.url,
                   "pid": os.getpid()},
        )
        if options.transport == "stdio" and started_from_terminal(sys.stdin):
            print(first_contact_line(backend=options.backend, policy=options.policy_label,
                                     audit_log=assembly.audit.path, tools=len(assembly.server.tools),
                                     dry_run=assembly.policy.dry_run), file=sys.stderr, flush=True)
        async with anyio.create_task_group() as group:
            async def on_signals() -> None:
                nonlocal why
                with anyio.open_signal_receiver(signal.SIGTERM, signal.SIGINT) as signals:
                    async for signum in signals:
                        why = f"signal {signal.Signals(signum).name}"
                        with anyio.CancelScope(shield=True):  # the arm stops first, whatever follows
                            try:
                                await assembly.backend.stop()
                            except Exception as exc:
                                logger.error("stop on %s failed: %s", why, exc)
                        if options.transport == "http":
                            shutdown.set()  # uvicorn drains and returns; in-flight executions stop
                            return
                        group.cancel_scope.cancel()
                        if options.transport == "stdio":
                            # The SDK reads stdin in a worker thread that cancellation cannot interrupt,
                            # so the group would not unwind until the client closes stdin. Let the
                            # cancelled calls stop and record, then stop, close and record here and exit.
                            final_record_lost: str | None = None
                            with anyio.CancelScope(shield=True):
                                await anyio.sleep(SIGNAL_GRACE_S)
                                final_record_lost = await close_assembly(assembly, why)
                            if final_record_lost is not None:
                                print(final_record_lost_message(final_record_lost), file=sys.stderr)
                            logging.shutdown()
                            sys.stderr.flush()
                            os._exit(0 if final_record_lost is None else EXIT_AUDIT_INCOMPLETE)
                        return

            group.start_soon(on_signals)
            if options.transport == "stdio":
                console_closed = anyio.Event()

                async def serve_console() -> None:
                    try:
                        await _serve_console(options, assembly, external, console_stop, shutdown, listener, served)
                    finally:
                        console_closed.set()

                if options.console_port is not None:
                    group.start_soon(serve_console)
                else:
                    _log_startup_lines(served)  # the stop channel of --estop-port, if any: it listens already
                    console_closed.set()
                why = await _serve_stdio(assembly, external)
                # The console's server returns once it has closed its connections; cancelled while
                # it serves, its lifespan task logs a CancelledError traceback on every exit.
                shutdown.set()
                with anyio.move_on_after(CONSOLE_CLOSE_S):
                    await console_closed.wait()
            else:
                await _serve_http(options, assembly, external, shutdown, console_stop, listener, served)
            group.cancel_scope.cancel()
    finally:
        if listener is not None:  # closed by serve_http once it served; not if start-up failed before
            listener.close()
        if channel is not None:
            channel.close()
        try:
            lost = await close_assembly(assembly, why)
        finally:  # last: a SIGUSR1 during the shutdown still stops the arm instead of killing the process
            if signal_stop is not None:
                signal_stop.close()
    if lost is not None:
        raise FinalRecordLost(lost)


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


async def _serve_console(options: ServeOptions, assembly: Assembly, external: ExternalStops,
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
                                 token_store=tokens, on_refused=_refusal_recorder(assembly))
    assembly.guard.approvals.console_url = f"http://{link_host(host)}:{port}/console"
    await _serve_then_announce(app, host, port, shutdown, listener, served)


async def _serve_stdio(assembly: Assembly, external: ExternalStops) -> str:
    """Serve until the client leaves; returns how it left, for the shutdown record."""
    from armwarden.transport.stdio import OutputClosed, serve_stdio

    try:
        await serve_stdio(assembly.server.mcp, on_refused=_refusal_recorder(assembly),
                          on_stop_request=external.stop_on_receipt, on_input_end=external.latch_as_the_client_leaves,
                          on_estop_refused=_refused_estop_latch(assembly, external))
    except OutputClosed:
        logger.warning("the client closed the daemon's stdout: its open calls are cancelled and the daemon stops")
        return "the client closed stdout"
    return "end of stdin"


def _refusal_recorder(assembly: Assembly) -> RefusedCallback:
    """Audits a request a transport refused before the tools saw it (`request_refused`, on disk
    before its answer where the transport waits for it), with what its stop calls did. Pure
    refusals are thinned per principal (or host; stdio has one client) to `REFUSAL_RECORDS_BURST`,
    then one a second, each record counting those left out before it; a refusal whose stop calls
    acted (held the robot, latched the e-stop) is always recorded. Counts left out are recorded on
    their own (`refusals_left_out`) when the principal goes quiet, and at shutdown."""
    thinning = assembly.refusal_reports_for("transport", burst=REFUSAL_RECORDS_BURST)

    async def record(refused: RefusedRequest) -> None:
        left_out = 0
        if not refused.stops:
            admitted = thinning.admit(refused.principal or refused.peer or "the stdio client")
            if admitted is None:
                return
            left_out = admitted
        params = refused.params if refused.method == "tools/call" and isinstance(refused.params, Mapping) else {}
        tool, arguments = params.get("name"), params.get("arguments")
        extra: dict[str, Any] = {}
        if refused.request_id is not None:
            extra["request_id"] = str(refused.request_id)[:64]
        if refused.session is not None:  # the client's claim, never a session the SDK bound
            extra["session_header"] = flatten_reason(refused.session, 128)
        if refused.peer is not None:
            extra["peer"] = refused.peer
        if left_out:
            extra["not_reported_since_last"] = left_out
        detail = refused.why
        if refused.batch is not None:  # named by what acted (an estop first), its elements in extra
            acted = sorted(refused.stops, key=lambda stop: stop.tool != "estop")
            tool = acted[0].tool if acted else None
            extra["batch"] = list(refused.batch)
        if refused.stops:
            extra["stops"] = [stop.tool for stop in refused.stops]
            events = [stop.estop_event for stop in refused.stops if stop.estop_event is not None]
            if events:
                extra["estop_event"] = events[0]
            detail += "; " + "; ".join(stop.describe() for stop in refused.stops)
        await assembly.audit.append_async("request_refused", tool=None if tool is None else str(tool)[:128],
                                          arguments=None if tool is None else arguments, outcome=refused.outcome,
                                          detail=detail, principal=refused.principal, extra=extra or None)

    return record


def _refused_estop_latch(assembly: Assembly, external: ExternalStops) -> LatchOnRefusal:
    """Latches the e-stop for an `estop` request a transport read but that will not run
    (docs/threat-model.md: a clumsy stop still latches) and audits it without waiting, as the
    stop channel does. The source is "estop": its reason is the client's, shown as unverified."""
    latch_and_stop = external.latch_and_stop_for("estop")

    def latch(reason: Any, principal: str | None, why: str) -> int:
        text = flatten_reason(reason)
        failure: BackendError | None = None
        try:
            number = latch_and_stop(text, principal or "")
        except BackendError as exc:  # latched all the same, with a stop_failed e-stop on top
            failure = exc
            event = assembly.guard.latch.current_event
            number = event.number if event is not None else 0
        detail = (f"e-stop #{number} latched: the estop request was read but not run ({flatten_reason(why, 300)})"
                  + ("" if failure is None else f"; the stop could NOT be issued: {failure}"))
        try:
            assembly.audit.submit("estop", tool="estop", principal=principal, arguments={"reason": text},
                                  outcome="latched" if failure is None else "stop_failed", detail=detail,
                                  extra={"estop_event": number})
        except AuditWriteError as exc:  # the latch holds either way
            logger.critical("estop not audited (%s): %s", exc, detail)
        return number

    return latch


async def _serve_http(options: ServeOptions, assembly: Assembly, external: ExternalStops, shutdown: anyio.Event,
                      console_stop: ConsoleStop | None = None, listener: socket.socket | None = None,
                      served: Endpoints | None = None) -> None:
    """``/mcp`` (and the console, ``/metrics``) on `listener`, bound already to ``--port``; logs
    `served`'s start-up lines once it listens."""
    from armwarden.transport.http import build_http_app, current_principal
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
                         on_refused=_refusal_recorder(assembly),
                         on_estop_refused=_refused_estop_latch(assembly, external),
                         allowed_hosts=options.allowed_hosts,
                         allowed_origins=options.allowed_origins,
                         metrics=None if assembly.metrics is None else assembly.metrics.exposition)
    await _serve_then_announce(app, options.host, options.port, shutdown, listener, served)


def serve_command(options: ServeOptions) -> int:
    from armwarden.policy import bundled_policy

    policy_path = Path(options.policy) if options.policy else bundled_policy()
    try:
        policy = load_policy(policy_path).with_dry_run(options.dry_run)
        if options.transport == "http":
            from armwarden.transport.http import check_bind_safety
            from armwarden.transport.tokens import TokenStore

            check_bind_safety(options.host, TokenStore.load(options.auth_tokens) if options.auth_tokens else None)
        if options.console_port is not None:
            from armwarden.transport.http import check_bind_safety
            from armwarden.transport.tokens import TokenStore

            check_bind_safety(options.console_host, TokenStore.load(options.auth_tokens) if options.auth_tokens else None)
        if options.estop_port is not None and not options.auth_tokens:
            raise ConfigurationError(ESTOP_PORT_NEEDS_TOKENS)
        parts = assemble(policy, options.backend, options.backend_config, options.audit_log,
                         options.audit_commit_window_s)
    except PolicyError as exc:
        print(f"armwarden: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    except ArmWardenError as exc:
        print(f"armwarden: refusing to start: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    try:
        anyio.run(_run, options, parts)
    except FinalRecordLost as exc:
        print(final_record_lost_message(str(exc)), file=sys.stderr)
        return EXIT_AUDIT_INCOMPLETE
    except ArmWardenError as exc:
        print(f"armwarden: refusing to start: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    except KeyboardInterrupt:  # pragma: no cover - the signal receiver normally handles it
        pass
    return 0
