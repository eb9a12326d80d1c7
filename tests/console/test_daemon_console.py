"""`armwarden serve` serves the console: at /console beside /mcp over HTTP, and on
--console-port beside stdio; the E-STOP there latches the daemon's e-stop."""

from __future__ import annotations

import re
import subprocess
import time
from pathlib import Path

import httpx2

from tests.helpers import CLI, REPO, child_env, free_port, records_of, stop_process
from tests.server.http_daemon import HOST, add_token, http_daemon


def test_http_daemon_serves_the_console_beside_mcp(tmp_path: Path) -> None:
    with http_daemon(tmp_path, speedup=50.0) as daemon:
        login = httpx2.get(f"{daemon.base}/console/login", timeout=10)
        mcp = httpx2.post(daemon.url, json={"jsonrpc": "2.0", "id": 1, "method": "ping"}, timeout=10)
        stop = httpx2.post(f"{daemon.base}/console/estop", headers={"Accept": "application/json"}, timeout=10)

    assert login.status_code == 200 and 'id="login-form"' in login.text
    assert mcp.status_code == 401
    assert stop.status_code == 200 and stop.json()["estopped"] is True


def estop_form_action(html: str) -> str:
    found = re.search(r'action="([^"]*)" class="estop" id="estop-form"', html)
    assert found is not None, "no E-STOP form on the page"
    return found.group(1)


def test_http_daemons_console_estop_goes_through_a_stop_channel(tmp_path: Path) -> None:
    with http_daemon(tmp_path, speedup=50.0) as daemon:
        login = httpx2.get(f"{daemon.base}/console/login", timeout=10)
        channel_url = estop_form_action(login.text)
        stop = httpx2.post(channel_url, headers={"Origin": daemon.base}, timeout=10,
                           data={})  # the page's form without sign-in: no ticket, from loopback
        foreign = httpx2.post(channel_url, headers={"Origin": "http://evil.example"}, timeout=10)
        stderr = daemon.stderr_path.read_text() if daemon.stderr_path.exists() else ""

    assert channel_url.startswith(f"http://{HOST}:") and channel_url.endswith("/console-estop")
    assert not channel_url.startswith(daemon.base)  # its own port and thread, not the event loop's
    assert stop.status_code == 200 and "E-STOP latched: event #1" in stop.text, stderr
    assert foreign.status_code == 403
    estops = [r for r in records_of(daemon.audit) if r["event"] == "estop"]
    assert [r["principal"] for r in estops] == ["console (not signed in, loopback)"]
    assert estops[0]["extra"]["peer"].startswith("console via stop channel")


def test_stdio_daemon_serves_the_console_on_its_port(tmp_path: Path) -> None:
    tokens = tmp_path / "tokens.json"
    add_token(tokens, "operator", "alice")
    port = free_port(HOST)
    audit = tmp_path / "audit.jsonl"
    process = subprocess.Popen(
        [*CLI, "serve", "--console-port", str(port), "--auth-tokens", str(tokens), "--audit-log", str(audit),
         "--log-level", "WARNING"],
        cwd=REPO, env=child_env(), stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 30
        login = None
        while login is None:
            assert process.poll() is None, "the daemon exited"
            try:
                login = httpx2.get(f"http://{HOST}:{port}/console/login", timeout=1.0)
            except httpx2.HTTPError:
                assert time.monotonic() < deadline, "the console did not come up"
                time.sleep(0.1)
        channel_url = estop_form_action(login.text)
        stop = httpx2.post(channel_url, headers={"Origin": f"http://{HOST}:{port}"}, timeout=10)
    finally:
        stop_process(process, 10)

    assert login.status_code == 200
    assert channel_url.endswith("/console-estop") and f":{port}/" not in channel_url
    assert stop.status_code == 200
    assert any(r["event"] == "estop" and r["outcome"] == "latched" for r in records_of(audit))


def test_console_port_on_a_public_address_without_tokens_is_refused(tmp_path: Path) -> None:
    result = subprocess.run([*CLI, "serve", "--console-port", str(free_port(HOST)), "--console-host", "0.0.0.0",
                             "--audit-log", str(tmp_path / "audit.jsonl")],
                            cwd=REPO, env=child_env(), stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=60)

    assert result.returncode == 2
    assert "without bearer tokens" in result.stderr
