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

Evaluation only: with `--eval-backend-death` (refused unless the backend is a simulation) SIGUSR2
makes the backend die mid-run (`armwarden.daemon.death`); the start-up record says whether it is on.

Once it listens, `serve` logs (INFO) every URL it serves and what each one takes (`endpoints`),
with the ports it really bound: the HTTP socket is bound before anything is built from its port,
so `--port 0` / `--console-port 0` serve, check Host headers and link on the real port.
"""

from __future__ import annotations

import asyncio
import logging
import os
import socket
import sys
from pathlib import Path

import anyio

from armwarden import __version__
from armwarden.core.errors import ArmWardenError, ConfigurationError, PolicyError
from armwarden.daemon import startup
from armwarden.daemon.death import die_on_signal, refuse_unless_simulated
from armwarden.daemon.http import bind_listener, log_startup_lines, serve_console_alone, serve_http_clients, served_endpoints
from armwarden.daemon.options import EXIT_REFUSED, ServeOptions
from armwarden.daemon.previous_run import latch_at_start
from armwarden.daemon.shutdown import (
    EXIT_AUDIT_INCOMPLETE,
    FinalRecordLost,
    close_assembly,
    final_record_lost_message,
    stop_on_signals,
)
from armwarden.daemon.startup import AssemblyParts, assemble, freeze_long_lived_objects, open_assembly
from armwarden.daemon.stdio import serve_stdio_client
from armwarden.daemon.stops import ESTOP_PORT_NEEDS_TOKENS, console_door, route_console_estop, start_external_stops
from armwarden.extras import log_feature_lines
from armwarden.greeting import first_contact_line, started_from_terminal
from armwarden.policy import load_policy, policy_digest
from armwarden.stopchannel.external import ExternalStops

logger = logging.getLogger("armwarden")

#: at the end of a stdio session: time the console's server (`--console-port`) has to close its
#: connections and return before it is cancelled [s] (its own graceful shutdown takes up to 3 s)
CONSOLE_CLOSE_S = 5.0


async def _run(options: ServeOptions, parts: AssemblyParts, claimed: tuple[int, int] | None = None) -> None:
    """Open the assembly, start the independent stops, record the start-up, serve until the client
    leaves or a signal arrives, then shut down (raising `FinalRecordLost` without a final record).
    `claimed`: on stdio, the pipes `serve_command` claimed (None: the SDK's threads serve them)."""
    assembly = await open_assembly(parts)
    why = "shutdown"
    lost: str | None = None  # why the final record could not be written
    shutdown = anyio.Event()
    signal_stop, channel = None, None
    listener: socket.socket | None = None
    external = ExternalStops(assembly.guard.stopper, assembly.audit, asyncio.get_running_loop())
    try:
        if parts.unclean_end is not None:  # first: every way out of this run now records the e-stop as held
            await latch_at_start(assembly.guard, assembly.audit, parts.unclean_end)
        options, listener = bind_listener(options)
        door = console_door(options, external)
        signal_stop, channel = start_external_stops(options, external, None if door is None else door[0],
                                                     assembly.refusal_reports_for("stop_channel"))
        console_stop = route_console_estop(options, channel, None if door is None else door[1])
        served = served_endpoints(options, channel, console_stop)
        log_feature_lines(logger, assembly.policy.enabled_tools)  # what each absent optional dependency removes
        freeze_long_lived_objects()
        await assembly.audit.append_async(
            "startup",
            outcome="ok",
            detail=f"armwarden {__version__} serving {options.transport} with the {options.backend} backend",
            extra={"policy": options.policy_label, "policy_digest": policy_digest(assembly.policy),
                   "dry_run": assembly.policy.dry_run,
                   "tools": assembly.server.tools, "stop_channel": None if channel is None else channel.url,
                   "pid": os.getpid(), "previous_run_unclean": parts.unclean_end,
                   "eval_backend_death": options.eval_backend_death},
        )
        if options.transport == "stdio" and started_from_terminal(sys.stdin):
            print(first_contact_line(backend=options.backend, policy=options.policy_label,
                                     audit_log=assembly.audit.path, tools=len(assembly.server.tools),
                                     dry_run=assembly.policy.dry_run), file=sys.stderr, flush=True)
        async with anyio.create_task_group() as group:
            def signalled(signal_why: str) -> None:
                nonlocal why
                why = signal_why

            group.start_soon(stop_on_signals, assembly, options.transport, shutdown, group.cancel_scope, signalled)
            if options.eval_backend_death:  # evaluation only, a simulated backend (checked at start-up)
                group.start_soon(die_on_signal, assembly)
            if options.transport == "stdio":
                console_closed = anyio.Event()

                async def serve_console() -> None:
                    try:
                        await serve_console_alone(options, assembly, external, console_stop, shutdown, listener, served)
                    finally:
                        console_closed.set()

                if options.console_port is not None:
                    group.start_soon(serve_console)
                else:
                    log_startup_lines(served)  # the stop channel of --estop-port, if any: it listens already
                    console_closed.set()
                why = await serve_stdio_client(assembly, external, claimed)
                # The console's server returns once it has closed its connections; cancelled while
                # it serves, its lifespan task logs a CancelledError traceback on every exit.
                shutdown.set()
                with anyio.move_on_after(CONSOLE_CLOSE_S):
                    await console_closed.wait()
            else:
                await serve_http_clients(options, assembly, external, shutdown, console_stop, listener, served)
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


def serve_command(options: ServeOptions) -> int:
    """`armwarden serve`: refuse (exit 2) before serving anything that cannot start safely, then run."""
    if options.transport != "stdio":
        return _serve_command(options, None)
    from armwarden.transport.pipes import claimed_pipes

    # stdout is the MCP channel: claimed before anything is built, so that a native library of a
    # backend (Fast DDS, a GL driver) writing to fd 1 as it starts or shuts down writes to stderr
    with claimed_pipes() as claimed:
        return _serve_command(options, claimed)


def _serve_command(options: ServeOptions, claimed: tuple[int, int] | None) -> int:
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
        if options.eval_backend_death:
            refuse_unless_simulated(options.backend)  # by name, before anything is built
        parts = assemble(policy, options.backend, options.backend_config, options.audit_log,
                         options.audit_commit_window_s, options.actuation_journal)
        if options.eval_backend_death:
            refuse_unless_simulated(options.backend, parts.backend)  # the backend's own word (can: the emulator)
    except PolicyError as exc:
        print(f"armwarden: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    except ArmWardenError as exc:
        print(f"armwarden: refusing to start: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    sys.setswitchinterval(startup.SWITCH_INTERVAL_S)  # read here: a benchmark may replace it
    try:
        anyio.run(_run, options, parts, claimed)
    except FinalRecordLost as exc:
        print(final_record_lost_message(str(exc)), file=sys.stderr)
        return EXIT_AUDIT_INCOMPLETE
    except ArmWardenError as exc:
        print(f"armwarden: refusing to start: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    except KeyboardInterrupt:  # pragma: no cover - the signal receiver normally handles it
        pass
    return 0
