"""The one line `armwarden serve` prints on stderr when a person starts it on stdio from a terminal.

Started by hand, the daemon waits silently for an MCP client on stdin, which looks like a hang.
The line says what is being served (transport, backend, policy, audit log, tool count) and where
to read how to connect a client. It goes to stderr only: stdout is the MCP channel. When a
client starts the daemon (stdin is a pipe), nothing is printed: the client's logs stay as they were.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TextIO

QUICKSTART = "docs/quickstart.md"


def started_from_terminal(stdin: TextIO) -> bool:
    """True when stdin is a terminal: a person, not an MCP client, started the daemon."""
    try:
        return stdin.isatty()
    except (AttributeError, ValueError, OSError):  # closed or replaced stdin
        return False


def first_contact_line(*, backend: str, policy: str, audit_log: str | os.PathLike[str], tools: int,
                       dry_run: bool) -> str:
    """What a newcomer needs on one line: what runs, and how to talk to it."""
    mode = ", dry run" if dry_run else ""
    return (f"armwarden: serving MCP on stdio ({backend} backend{mode}, policy {policy}, "
            f"audit log {Path(audit_log).resolve()}, {tools} tools). Waiting for an MCP client on stdin: "
            f"this terminal is not one. Connect a client that starts this command (see {QUICKSTART}); "
            f"Ctrl-C stops.")


__all__ = ["QUICKSTART", "first_contact_line", "started_from_terminal"]
