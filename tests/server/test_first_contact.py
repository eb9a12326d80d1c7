"""`armwarden serve` started by hand on stdio says on stderr, in one line, what it serves and how to
connect a client; stdout (the MCP channel) stays empty. Started by a client, it says nothing."""

from __future__ import annotations

import os
import pty
import select
import signal
import subprocess
import time
from pathlib import Path

from tests.helpers import CLI, REPO, child_env

GREETING = "armwarden: serving MCP on stdio"


def serve_from_a_terminal(tmp_path: Path) -> tuple[str, str]:
    """Run `armwarden serve` with a terminal as stdin until it has greeted, then SIGTERM; its
    (stdout, stderr)."""
    controller, terminal = pty.openpty()
    process = subprocess.Popen(
        [*CLI, "serve", "--audit-log", str(tmp_path / "audit.jsonl"), "--log-level", "WARNING"],
        cwd=REPO, env=child_env(), stdin=terminal, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )
    os.close(terminal)
    early = b""
    try:
        assert process.stderr is not None
        deadline = time.monotonic() + 60  # a bound on a hung test, not a timing threshold
        while GREETING.encode() not in early or not early.endswith(b"\n"):
            assert process.poll() is None, f"the daemon exited before greeting: {early.decode()}"
            remaining = deadline - time.monotonic()
            assert remaining > 0, f"no greeting within 60 s: {early.decode()}"
            if select.select([process.stderr], [], [], remaining)[0]:
                early += os.read(process.stderr.fileno(), 65536)
        process.send_signal(signal.SIGTERM)
        stdout, stderr = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
        os.close(controller)
    stderr = early + stderr
    return stdout.decode(), stderr.decode()


def test_serve_from_a_terminal_says_what_it_serves_on_one_stderr_line(tmp_path) -> None:
    _, stderr = serve_from_a_terminal(tmp_path)
    lines = [line for line in stderr.splitlines() if line.startswith(GREETING)]
    assert len(lines) == 1, stderr
    line = lines[0]
    for fact in ("fake backend", "policy bundled fr3", str((tmp_path / "audit.jsonl").resolve()), "23 tools",
                 "docs/quickstart.md"):
        assert fact in line, line


def test_serve_from_a_terminal_writes_nothing_on_stdout(tmp_path) -> None:
    stdout, _ = serve_from_a_terminal(tmp_path)
    assert stdout == ""


def test_serve_started_by_a_client_prints_no_greeting(tmp_path) -> None:
    result = subprocess.run(
        [*CLI, "serve", "--audit-log", str(tmp_path / "audit.jsonl"), "--log-level", "WARNING"],
        cwd=REPO, env=child_env(), stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert GREETING not in result.stderr and result.stdout == ""
