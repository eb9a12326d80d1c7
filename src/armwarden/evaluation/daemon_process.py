"""The evaluation's view of a daemon process: `armwarden serve --transport http` started on
127.0.0.1 and waited for, an MCP session on it under a token, and what /proc says about a pid
(its RSS, whether it still runs). Shared by the fuzzing and the load run."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from collections.abc import AsyncIterator, Callable, Sequence
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import anyio
from mcp import Client, StdioServerParameters

#: the loopback address an evaluation's HTTP daemon binds (never anything else)
HOST = "127.0.0.1"
#: how long the daemon may take to start and answer its health check [s]
START_TIMEOUT_S = 300.0
#: the daemon's command line up to `serve` (tests put a deliberately broken daemon here)
DAEMON_COMMAND: tuple[str, ...] = (sys.executable, "-m", "armwarden.cli")


@dataclass(frozen=True)
class HttpDaemon:
    base_url: str
    pid: int


def stdio_params(command: Sequence[str], serve_args: Sequence[str]) -> StdioServerParameters:
    """`command serve_args` as the SDK's stdio client starts it, with this process's environment
    (the SDK passes a minimal one unless given one: PYTHONPATH and the audit key must reach it)."""
    return StdioServerParameters(command=command[0], args=[*command[1:], *serve_args], env=dict(os.environ),
                                 cwd=str(Path.cwd()))


def stop_process(process: subprocess.Popen[Any], timeout_s: float) -> None:
    """SIGTERM `process` if it still runs, wait up to `timeout_s` for it to exit, else kill it."""
    if process.poll() is None:
        process.send_signal(signal.SIGTERM)
        try:
            process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((HOST, 0))
        return int(sock.getsockname()[1])


def rss_mb(pid: int | None) -> float | None:
    """The process's resident memory [MB] (VmRSS), None when unknown."""
    if pid is None:
        return None
    try:
        for line in Path(f"/proc/{pid}/status").read_text(encoding="ascii").splitlines():
            if line.startswith("VmRSS:"):
                return round(int(line.split()[1]) / 1024, 1)
    except OSError:
        return None
    return None


def alive(pid: int | None) -> bool:
    return pid is not None and Path(f"/proc/{pid}").exists() and "zombie" not in _proc_state(pid)


def _proc_state(pid: int) -> str:
    try:
        for line in Path(f"/proc/{pid}/status").read_text(encoding="ascii").splitlines():
            if line.startswith("State:"):
                return line
    except OSError:
        return "gone zombie"
    return ""


def _tail(path: Path, chars: int = 2000) -> str:
    return path.read_text(encoding="utf-8", errors="replace")[-chars:]


@asynccontextmanager
async def http_daemon(command: Sequence[str], serve_args: list[str], tokens: Path, stderr_path: Path,
                      extra: Sequence[str] = ()) -> AsyncIterator[HttpDaemon]:
    """`command serve_args --transport http` on 127.0.0.1 and a free port with the token file
    `tokens` (no console), once its /healthz answers; SIGTERM (then SIGKILL) on leaving."""
    import httpx2

    port = free_port()
    with stderr_path.open("wb") as stderr:
        process = await anyio.open_process(
            [*command, *serve_args, "--transport", "http", "--host", HOST, "--port", str(port),
             "--auth-tokens", str(tokens), "--no-console", *extra],
            env=dict(os.environ), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=stderr)
    try:
        base = f"http://{HOST}:{port}"
        with anyio.fail_after(START_TIMEOUT_S):
            while True:
                if process.returncode is not None:
                    tail = _tail(stderr_path)
                    raise RuntimeError(f"the HTTP daemon exited with {process.returncode}: {tail}")
                try:
                    async with httpx2.AsyncClient(timeout=2.0) as probe:
                        if (await probe.get(f"{base}/healthz")).status_code == 200:
                            break
                except httpx2.HTTPError:
                    pass
                await anyio.sleep(0.2)
        yield HttpDaemon(base, process.pid)
    finally:
        with anyio.CancelScope(shield=True):
            if process.returncode is None:
                process.send_signal(signal.SIGTERM)
                with anyio.move_on_after(30):
                    await process.wait()
                if process.returncode is None:
                    process.kill()
                    await process.wait()


@asynccontextmanager
async def http_session(daemon: HttpDaemon, token: str, call_timeout_s: float,
                       elicitation: Callable[..., Any] | None) -> AsyncIterator[Client]:
    """An MCP session (legacy mode) on `daemon` under `token`, answering approval prompts with
    `elicitation` (None: a client without elicitation)."""
    import httpx2
    from mcp.client.streamable_http import streamable_http_client

    async with (httpx2.AsyncClient(headers={"Authorization": f"Bearer {token}"},
                                   timeout=httpx2.Timeout(call_timeout_s)) as http,
                Client(streamable_http_client(f"{daemon.base_url}/mcp", http_client=http), mode="legacy",
                       elicitation_callback=elicitation) as client):
        yield client
