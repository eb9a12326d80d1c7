"""`armwarden serve`'s flags reach the daemon as one typed record: every flag is carried (a new
one cannot be forgotten on the way down), and the record answers the questions the daemon's
modules used to answer each on their own from the namespace (which port was bound, where the
console and the stop channel are)."""

from __future__ import annotations

import dataclasses

from armwarden.cli import _build_parser, serve_options
from armwarden.daemon.options import ServeOptions

#: serve flags the command line keeps for itself (logging is set up before the daemon runs)
CLI_ONLY = {"command", "log_level"}
#: flags whose field in the options has another name (a repeatable flag, a unit converted)
RENAMED = {"allowed_host": "allowed_hosts", "allowed_origin": "allowed_origins",
           "audit_commit_window_ms": "audit_commit_window_s"}


def options(*flags: str) -> ServeOptions:
    return serve_options(_build_parser().parse_args(["serve", *flags]))


def test_every_serve_flag_has_a_field_in_the_options() -> None:
    flags = set(vars(_build_parser().parse_args(["serve"]))) - CLI_ONLY
    fields = {field.name for field in dataclasses.fields(ServeOptions)}
    assert {RENAMED.get(flag, flag) for flag in flags} == fields


def test_the_flags_values_reach_the_options() -> None:
    got = options("--transport", "http", "--port", "0", "--allowed-host", "a.local", "--allowed-host", "b.local",
                  "--audit-commit-window-ms", "250", "--estop-port", "9000", "--no-console", "--dry-run")
    assert (got.transport, got.port, got.estop_port, got.no_console, got.dry_run) == ("http", 0, 9000, True, True)
    assert got.allowed_hosts == ("a.local", "b.local") and got.allowed_origins == ()
    assert got.audit_commit_window_s == 0.25


def test_the_bound_port_replaces_the_http_port_over_http() -> None:
    bound = options("--transport", "http", "--port", "0").with_bound_port(41234)
    assert (bound.port, bound.console_address()) == (41234, ("127.0.0.1", 41234))


def test_the_bound_port_replaces_the_console_port_on_stdio() -> None:
    bound = options("--console-port", "0").with_bound_port(41235)
    assert (bound.port, bound.console_port, bound.console_address()) == (8765, 41235, ("127.0.0.1", 41235))


def test_no_console_is_served_on_plain_stdio_or_with_no_console_over_http() -> None:
    assert options().console_address() is None
    assert options("--transport", "http", "--no-console").console_address() is None


def test_the_stop_channel_listens_on_estop_host_only_with_estop_port() -> None:
    assert options("--estop-host", "0.0.0.0").stop_channel_host == "127.0.0.1"
    with_port = options("--estop-host", "0.0.0.0", "--estop-port", "9000")
    assert with_port.stop_channel_host == "0.0.0.0" and with_port.stop_channel_takes_tokens
