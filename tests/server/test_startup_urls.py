"""`armwarden serve` names, on stderr at start-up, every URL it serves and what each one takes
(issue 31, item 5: HTTP mode printed only the console's stop channel, as a WARNING that looked
like the MCP endpoint and refused every bearer token), and with port 0 the port it really bound
(item 2: `http://127.0.0.1:0/console/`). Each URL a test reads from the log is then used: the
line is only right if what it names answers there."""

from __future__ import annotations

import re
import subprocess
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import httpx2
import pytest

from tests.helpers import CLI, REPO, child_env, stop_process
from tests.server.http_daemon import HOST, add_token

START_DEADLINE_S = 60.0  # generous: a loaded machine starts the daemon slowly, a broken one never


@dataclass
class Served:
    process: subprocess.Popen
    stderr_path: Path
    tokens: Path
    operator_token: str

    def log(self) -> str:
        return self.stderr_path.read_text(encoding="utf-8") if self.stderr_path.exists() else ""

    def wait_for_line(self, pattern: str) -> re.Match[str]:
        """The first stderr line matching `pattern`, once the daemon has written it."""
        deadline = time.monotonic() + START_DEADLINE_S
        while True:
            for line in self.log().splitlines():
                if (found := re.search(pattern, line)) is not None:
                    return found
            assert self.process.poll() is None, f"the daemon exited:\n{self.log()}"
            assert time.monotonic() < deadline, f"no line matching {pattern!r}:\n{self.log()}"
            time.sleep(0.05)


@pytest.fixture
def serve(tmp_path: Path) -> Iterator:
    """Start `armwarden serve ARGS` (fake backend, an operator token in tokens.json, INFO log);
    every daemon started is stopped at teardown."""
    tokens = tmp_path / "tokens.json"
    operator_token = add_token(tokens, "operator", "alice")
    config = tmp_path / "fake.yaml"
    config.write_text("speedup: 20\n", encoding="utf-8")
    started: list[subprocess.Popen] = []

    def start(args: Sequence[str], *, with_tokens: bool = True) -> Served:
        stderr_path = tmp_path / f"stderr-{len(started)}.log"
        token_args = ["--auth-tokens", str(tokens)] if with_tokens else []
        with open(stderr_path, "wb") as stderr:
            process = subprocess.Popen(
                [*CLI, "serve", *args, *token_args, "--audit-log", str(tmp_path / f"audit-{len(started)}.jsonl"),
                 "--backend-config", str(config), "--log-level", "INFO"],
                cwd=REPO, env=child_env(), stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=stderr)
        started.append(process)
        return Served(process, stderr_path, tokens, operator_token)

    yield start
    for process in started:
        stop_process(process, 10)


def bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


def test_http_on_port_0_logs_the_mcp_url_it_bound_and_that_it_needs_a_token(serve) -> None:
    daemon = serve(["--transport", "http", "--host", HOST, "--port", "0"])
    found = daemon.wait_for_line(r" INFO armwarden: MCP endpoint \(streamable HTTP\): (http://127\.0\.0\.1:(\d+)/mcp)\b(.*)")
    url, port, rest = found.group(1), int(found.group(2)), found.group(3)

    without_token = httpx2.post(url, json={"jsonrpc": "2.0", "id": 1, "method": "ping"}, timeout=10)
    health = httpx2.get(f"http://{HOST}:{port}/healthz", timeout=10)

    assert port != 0
    assert "Bearer" in rest and str(daemon.tokens) in rest
    assert health.status_code == 200  # the Host check knows the bound port, not 0
    assert without_token.status_code == 401 and without_token.json()["error"] == "unauthorized"


def test_http_logs_the_console_and_metrics_urls_and_no_warning(serve) -> None:
    daemon = serve(["--transport", "http", "--host", HOST, "--port", "0"])
    console = daemon.wait_for_line(r" INFO armwarden: operator console: (http://\S+/console/)")
    metrics = daemon.wait_for_line(r" INFO armwarden: Prometheus metrics: (http://\S+/metrics)\b(.*)")
    daemon.wait_for_line(r" INFO armwarden: stop channel")  # the last of the start-up lines

    login = httpx2.get(console.group(1) + "login", timeout=10)
    scrape = httpx2.get(metrics.group(1), headers=bearer(daemon.operator_token), timeout=10)

    assert login.status_code == 200 and 'id="login-form"' in login.text
    assert scrape.status_code == 200 and "armwarden_" in scrape.text
    assert "bearer token" in metrics.group(2)
    assert [line for line in daemon.log().splitlines() if " WARNING " in line] == []


def test_http_logs_the_consoles_stop_channel_as_console_only_and_it_says_so_to_a_bearer_token(serve) -> None:
    daemon = serve(["--transport", "http", "--host", HOST, "--port", "0"])
    found = daemon.wait_for_line(r" INFO armwarden: stop channel for the console's E-STOP button only: "
                                 r"POST (http://127\.0\.0\.1:(\d+))/console-estop\b(.*)")
    mcp = daemon.wait_for_line(r"MCP endpoint \(streamable HTTP\): http://127\.0\.0\.1:(\d+)/mcp")

    with_token = httpx2.post(found.group(1) + "/estop", headers=bearer(daemon.operator_token), json={}, timeout=10)

    assert found.group(2) != mcp.group(1)  # its own port, not the MCP endpoint's
    assert "not an MCP endpoint" in found.group(3) and "--estop-port" in found.group(3)
    assert with_token.status_code == 404  # not "401 unknown bearer token" for a token /mcp takes
    error = with_token.json()["error"]
    assert "unknown bearer token" not in error
    assert "/console-estop" in error and "--estop-port" in error


def test_http_with_estop_port_0_logs_the_bound_stop_channel_that_takes_the_tokens(serve) -> None:
    daemon = serve(["--transport", "http", "--host", HOST, "--port", "0", "--estop-port", "0"])
    found = daemon.wait_for_line(r" INFO armwarden: stop channel: POST (http://127\.0\.0\.1:(\d+)/estop)\b(.*)")

    stop = httpx2.post(found.group(1), headers=bearer(daemon.operator_token), json={"reason": "test"}, timeout=10)

    assert int(found.group(2)) != 0
    assert str(daemon.tokens) in found.group(3) and "not an MCP endpoint" in found.group(3)
    assert stop.status_code == 200 and stop.json()["estopped"] is True


def test_stdio_with_console_port_0_logs_the_console_url_it_bound(serve) -> None:
    daemon = serve(["--console-port", "0"])
    found = daemon.wait_for_line(r" INFO armwarden: operator console: (http://127\.0\.0\.1:(\d+)/console/)")

    login = httpx2.get(found.group(1) + "login", timeout=10)

    assert int(found.group(2)) != 0
    assert login.status_code == 200 and 'id="login-form"' in login.text


def test_http_without_tokens_logs_that_mcp_needs_none(serve) -> None:
    daemon = serve(["--transport", "http", "--host", HOST, "--port", "0"], with_tokens=False)
    found = daemon.wait_for_line(r" INFO armwarden: MCP endpoint \(streamable HTTP\): (http://\S+/mcp)\b(.*)")

    ping = httpx2.post(found.group(1), json={"jsonrpc": "2.0", "id": 1, "method": "initialize", "params": {
        "protocolVersion": "2025-11-25", "capabilities": {}, "clientInfo": {"name": "t", "version": "1"}}},
        headers={"Accept": "application/json, text/event-stream"}, timeout=10)

    assert "no bearer token" in found.group(2)
    assert ping.status_code == 200
