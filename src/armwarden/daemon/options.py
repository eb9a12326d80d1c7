"""What `armwarden serve` runs with: one frozen record, built once from the command line by
`armwarden.cli` and passed down, so no part of the daemon reads an argparse namespace or guesses
at a flag with `getattr`. Imports nothing of ArmWarden: the command line builds it before the
daemon's heavy imports."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

#: exit status of a daemon that refused to start (invalid policy, unavailable backend, unopenable
#: audit log, unsafe bind); the command line uses it for every "refused / invalid input"
EXIT_REFUSED = 2

Transport = Literal["stdio", "http"]


@dataclass(frozen=True)
class ServeOptions:
    """The `serve` flags (their help is in `armwarden.cli`). Ports may be 0 until the daemon
    binds them (`with_bound_port`)."""

    policy: str | None
    backend: str
    backend_config: str | None
    transport: Transport
    host: str
    port: int
    audit_log: str
    #: the audit log's group-commit window for read-only calls' records [s] (`--audit-commit-window-ms`)
    audit_commit_window_s: float
    auth_tokens: str | None
    allowed_hosts: tuple[str, ...]
    allowed_origins: tuple[str, ...]
    estop_port: int | None
    estop_host: str
    console_port: int | None
    console_host: str
    #: HTTP: do not serve the operator console at /console
    no_console: bool
    console_estop_needs_sign_in: bool
    dry_run: bool
    #: evaluation only: append every actuating/stopping backend call to this file (`JournalBackend`)
    actuation_journal: str | None = None
    #: evaluation only: SIGUSR2 makes the simulated backend die (`armwarden.daemon.death`)
    eval_backend_death: bool = False

    @property
    def policy_label(self) -> str:
        """How the start-up record and greeting name the policy."""
        return str(self.policy or "bundled fr3")

    @property
    def stop_channel_takes_tokens(self) -> bool:
        """`--estop-port` given: the stop channel is served for any token's role, not only for
        the console's E-STOP on an ephemeral loopback port."""
        return self.estop_port is not None

    @property
    def stop_channel_host(self) -> str:
        """Where the stop channel listens: `--estop-host`, or loopback for the console's own one."""
        return self.estop_host if self.stop_channel_takes_tokens else "127.0.0.1"

    def console_address(self) -> tuple[str, int] | None:
        """Host and port the console is served on, or None when this daemon serves no console."""
        if self.transport == "http":
            return None if self.no_console else (self.host, self.port)
        if self.console_port is not None:
            return self.console_host, self.console_port
        return None

    def with_bound_port(self, port: int) -> ServeOptions:
        """These options with the HTTP socket's real port (`--port`, or `--console-port` on stdio)."""
        if self.transport == "http":
            return dataclasses.replace(self, port=port)
        return dataclasses.replace(self, console_port=port)
