"""The fault runs' daemons (`faults`, `backend_death`): `armwarden serve` over stdio as a user
runs it (optionally under a file-size limit), a client that approves as a human would with the
daemon's stderr kept, its pid and flags from its own `startup` record, and calls bounded so that
a daemon wedged by the fault injected fails the fault instead of hanging the evaluation."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, TextIO

import anyio
from mcp import Client, StdioServerParameters
from mcp.client.stdio import stdio_client

from armwarden.audit.verify import decode_records
from armwarden.evaluation.daemon_process import DAEMON_COMMAND, stdio_params
from armwarden.evaluation.runner import SCENARIO_TIMEOUT_S, DaemonSession, approver

#: a fault comes once the motion's progress passes a fraction drawn uniformly from this range
FAULT_AT_PROGRESS = (0.05, 0.5)
#: how long a motion may take to start, or a killed daemon to be gone [s]
FAULT_STEP_TIMEOUT_S = 60.0


def daemon_params(arguments: list[str], file_size_limit: int | None = None) -> StdioServerParameters:
    """`armwarden serve` as a user runs it; under `file_size_limit` through a small launcher that
    sets RLIMIT_FSIZE and then execs the daemon."""
    command = DAEMON_COMMAND
    if file_size_limit is not None:
        launcher = ("import os, resource, sys; "
                    f"resource.setrlimit(resource.RLIMIT_FSIZE, ({file_size_limit}, {file_size_limit})); "
                    "os.execv(sys.argv[1], sys.argv[1:])")
        command = (sys.executable, "-c", launcher, *command)
    return stdio_params(command, arguments)


def fault_client(params: StdioServerParameters, errlog: TextIO, ref: list[DaemonSession]) -> Client:
    """A client session that approves as a human would; the daemon's stderr goes to `errlog` (a
    daemon whose log is full says so loudly, and a killed one's last words are kept there)."""
    return Client(stdio_client(params, errlog=errlog), mode="legacy", elicitation_callback=approver(ref))


def last_words(errlog: Path) -> str:
    lines = errlog.read_text(encoding="utf-8", errors="replace").strip().splitlines() if errlog.exists() else []
    return f" (the daemon's last stderr line: {lines[-1][:200]})" if lines else ""


def last_startup(audit: Path) -> dict[str, Any]:
    starts = [r for r in decode_records(audit.read_bytes().split(b"\n")) if r.get("event") == "startup"]
    if not starts:
        raise RuntimeError(f"no startup record in {audit}")
    return starts[-1]


async def bounded_call(session: DaemonSession, tool: str, arguments: dict[str, Any]) -> tuple[bool, dict[str, Any], str]:
    """`call_raw` within `SCENARIO_TIMEOUT_S`: a daemon wedged by the fault injected fails the
    fault, it does not hang the evaluation."""
    try:
        with anyio.fail_after(SCENARIO_TIMEOUT_S):
            return await session.call_raw(tool, arguments)
    except TimeoutError:
        return True, {}, f"{tool}: no answer within {SCENARIO_TIMEOUT_S:g} s"


__all__ = ["FAULT_AT_PROGRESS", "FAULT_STEP_TIMEOUT_S", "bounded_call", "daemon_params", "fault_client",
           "last_startup", "last_words"]
