"""The stops that bypass MCP and the event loop (docs/architecture.md, "Independent stop channel"):
SIGUSR1 always, the stop channel with `--estop-port`, and the console's E-STOP, which posts to the
stop channel whenever a browser of the console can reach it."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

from armwarden.core.errors import ConfigurationError
from armwarden.daemon.options import ServeOptions
from armwarden.endpoints import link_host
from armwarden.safety.refusals import RefusalReports
from armwarden.stopchannel import ConsoleDoor, StopChannel, token_store_authenticator
from armwarden.stopchannel.external import ExternalStops
from armwarden.stopchannel.signals import SignalStop

logger = logging.getLogger("armwarden")

#: why `serve` refuses a stop channel without a token file
ESTOP_PORT_NEEDS_TOKENS = "--estop-port needs --auth-tokens: the stop channel accepts any role's token, and none without one"


@dataclass(frozen=True)
class ConsoleStop:
    """What the console shares with the stop channel: its sessions (whose E-STOP tickets the
    channel checks) and where its E-STOP button posts (None: the console's own route)."""

    sessions: Any  # armwarden.console.SessionStore
    estop_url: str | None


def console_door(options: ServeOptions, external: ExternalStops) -> tuple[ConsoleDoor, Any] | None:
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


def start_external_stops(options: ServeOptions, external: ExternalStops, console: ConsoleDoor | None = None,
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


def route_console_estop(options: ServeOptions, channel: StopChannel | None, sessions: Any) -> ConsoleStop:
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
