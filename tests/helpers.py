"""Small helpers shared by the test modules: poses, tool-result text, audit files, child processes.

Helpers that need a running ArmWarden (the in-memory harness, elicitation callbacks, plans through
the SDK client) live in `tests/server/harness.py`; the daemon-as-a-subprocess ones in
`tests/server/http_daemon.py`. This module imports nothing from `armwarden`.
"""

from __future__ import annotations

import asyncio
import json
import os
import socket
import subprocess
import sys
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any, TypeVar

import anyio
import numpy as np

from armwarden.evaluation.daemon_process import stop_process as stop_process  # re-exported: one stop for every child process
from armwarden.policy import ALL_TOOLS

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / "src"
#: the CLI as a child process runs it (with `child_env()`, so this worktree's `src` wins)
CLI = [sys.executable, "-m", "armwarden.cli"]
#: tools a daemon serves with the bundled policy (every group) on the fake (every capability)
BUNDLED_TOOL_COUNT = len(ALL_TOOLS)

#: the FR3 ready pose, exact (rad)
READY = np.array([0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4])
#: the bundled fr3 policy's `robot.home_joint_positions`, as written there (rad; where the fake starts)
HOME = [0.0, -0.785398, 0.0, -2.356194, 0.0, 1.570796, 0.785398]
#: a tool-flange orientation pointing straight down (rotation matrix)
DOWN = np.diag([1.0, -1.0, -1.0])


class FakeClock:
    """A clock the test moves by hand: call it for the time, set `now` or `advance` it."""

    def __init__(self, now: float) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now

    def advance(self, seconds: float) -> None:
        self.now += seconds


def text_of(result: Any) -> str:
    """All the text of a `CallToolResult`, one string (refusal codes and messages are in it)."""
    return " ".join(getattr(block, "text", "") for block in result.content)


def records_of(path: Path) -> list[dict[str, Any]]:
    """Every record of a JSON-lines audit log."""
    return [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]


async def wait_for_record(path: Path, predicate, timeout_s: float = 10.0) -> list[dict[str, Any]]:
    """Every record of the daemon's audit log, once one of them satisfies `predicate` (a read-only
    call's record reaches the file within the audit log's commit window, not before the reply)."""
    with anyio.fail_after(timeout_s):
        while True:
            if await anyio.Path(path).exists():
                records = records_of(path)
                if any(predicate(r) for r in records):
                    return records
            await anyio.sleep(0.05)


def child_env() -> dict[str, str]:
    """The environment for a child `armwarden` process: this checkout's `src` first, no audit key."""
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    env.pop("ARMWARDEN_AUDIT_KEY", None)
    return env


def modules_the_parser_loads(package: str) -> list[str]:
    """The modules of `package` loaded by building the command-line parser, in a fresh interpreter
    (every subcommand builds it, `armwarden estop` among them: a heavy command must not load there)."""
    probe = ("import json, sys; from armwarden.cli import _build_parser; _build_parser(); "
             f"print(json.dumps(sorted(m for m in sys.modules if m.startswith({package!r}))))")
    result = subprocess.run([sys.executable, "-c", probe], cwd=REPO, env=child_env(), capture_output=True, text=True,
                            timeout=120, check=True)
    return json.loads(result.stdout)


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port nothing listens on right now (for a server the test starts)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((host, 0))
        return sock.getsockname()[1]


B = TypeVar("B")
R = TypeVar("R")


def run_opened(build: Callable[[], B], scenario: Callable[[B], Awaitable[R]]) -> R:
    """Build a backend, open it, run `scenario(backend)` on a fresh event loop, always close it."""

    async def main() -> R:
        backend: Any = build()
        await backend.open()
        try:
            return await scenario(backend)
        finally:
            await backend.close()

    return asyncio.run(main())
