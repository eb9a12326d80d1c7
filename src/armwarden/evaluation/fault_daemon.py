"""The fault runs' daemons (`faults`, `backend_death`): `armwarden serve` over stdio as a user
runs it (optionally under a file-size limit), a client that approves as a human would with the
daemon's stderr kept, its pid and flags from its own `startup` record, and calls bounded so that
a daemon wedged by the fault injected fails the fault instead of hanging the evaluation."""

from __future__ import annotations

import sys
from collections.abc import Callable
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


#: an execute's answer: (an error or a protocol failure, its structured content, its text)
Answer = tuple[bool, dict[str, Any], str]


async def strike_mid_motion(session: DaemonSession, plan_id: str, at: float,
                            strike: Callable[[], None]) -> tuple[bool, Answer | None]:
    """Execute `plan_id` and `strike` (kill the daemon, kill the backend) once the motion's reported
    progress passes the fraction `at` of it, or, were the motion answered first, right then; then
    wait for the execute's answer, each step within `FAULT_STEP_TIMEOUT_S`. Returns whether the
    strike found the motion unanswered (mid-motion), and the answer (None: none came)."""
    answered, cue = anyio.Event(), anyio.Event()
    answer: list[Answer] = []
    mid_motion = False

    async def on_progress(progress: float, total: float | None, message: str | None) -> None:
        if at * (total or 1.0) <= progress < (total or 1.0):  # moving, past the drawn fraction
            cue.set()

    async def execute() -> None:
        try:
            result = await session.client.call_tool("execute_plan", {"plan_id": plan_id},
                                                    progress_callback=on_progress)
            text = " ".join(getattr(block, "text", "") for block in result.content)
            answer.append((bool(result.is_error), dict(result.structured_content or {}), text))
        except Exception as exc:  # a protocol error (a killed daemon's pipe): not a success either
            answer.append((True, {}, f"protocol error: {exc}"))
        finally:
            answered.set()
            cue.set()

    async with anyio.create_task_group() as group:
        group.start_soon(execute)
        with anyio.move_on_after(FAULT_STEP_TIMEOUT_S):
            await cue.wait()
        mid_motion = not answered.is_set()
        strike()
        with anyio.move_on_after(FAULT_STEP_TIMEOUT_S):
            await answered.wait()
        group.cancel_scope.cancel()
    return mid_motion, (answer[0] if answer else None)


__all__ = ["FAULT_AT_PROGRESS", "FAULT_STEP_TIMEOUT_S", "Answer", "bounded_call", "daemon_params", "fault_client",
           "last_startup", "last_words", "strike_mid_motion"]
