"""An `armwarden serve --transport http` subprocess on 127.0.0.1 with operator and observer tokens,
and SDK clients for it (shared by the HTTP daemon tests)."""

from __future__ import annotations

import contextlib
import json
import re
import socket
import struct
import subprocess
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx2
from mcp import Client
from mcp.client.streamable_http import streamable_http_client

from tests.helpers import CLI, REPO, child_env, free_port, stop_process

HOST = "127.0.0.1"  # never anything else


def add_token(path: Path, role: str, name: str) -> str:
    result = subprocess.run([*CLI, "tokens", "add", str(path), "--role", role, "--name", name], cwd=REPO,
                            env=child_env(), capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    token = result.stdout.strip()
    assert token and "\n" not in token
    return token


@dataclass
class Daemon:
    process: subprocess.Popen
    port: int
    audit: Path
    operator_token: str
    observer_token: str
    stderr_path: Path

    @property
    def base(self) -> str:
        return f"http://{HOST}:{self.port}"

    @property
    def url(self) -> str:
        return f"{self.base}/mcp"


@contextlib.contextmanager
def http_daemon(tmp: Path, speedup: float, extra_args: Sequence[str] = (), *, backend: str = "fake",
                config: Path | None = None) -> Iterator[Daemon]:
    """Start the daemon (`backend`, the fake by default, at `speedup`; or with the `config` file
    given), wait until /healthz answers, SIGTERM it after."""
    tokens = tmp / "tokens.json"
    operator_token = add_token(tokens, "operator", "alice")
    observer_token = add_token(tokens, "observer", "bob")
    if config is None:
        config = tmp / f"{backend}.yaml"
        config.write_text(f"speedup: {speedup}\n", encoding="utf-8")
    audit = tmp / "audit.jsonl"
    port = free_port(HOST)
    stderr_path = tmp / "stderr.log"
    with open(stderr_path, "wb") as stderr:
        process = subprocess.Popen(
            [*CLI, "serve", "--transport", "http", "--host", HOST, "--port", str(port), "--auth-tokens", str(tokens),
             "--audit-log", str(audit), "--backend", backend, "--backend-config", str(config), "--log-level", "WARNING",
             *extra_args],
            cwd=REPO, env=child_env(), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=stderr,
        )
    running = Daemon(process, port, audit, operator_token, observer_token, stderr_path)
    try:
        deadline = time.monotonic() + 30
        while True:
            assert process.poll() is None, stderr_path.read_text()
            try:
                if httpx2.get(f"{running.base}/healthz", timeout=1.0).status_code == 200:
                    break
            except httpx2.HTTPError:
                pass
            assert time.monotonic() < deadline, "the daemon did not become healthy"
            time.sleep(0.1)
        yield running
    finally:
        stop_process(process, 10)


def session(daemon: Daemon, token: str | None, mode: str, elicitation=None) -> tuple[httpx2.AsyncClient, Client]:
    """An httpx2 client carrying an optional bearer token, and an SDK client over it (enter both)."""
    headers = {"Authorization": f"Bearer {token}"} if token is not None else {}
    http = httpx2.AsyncClient(headers=headers)
    return http, Client(streamable_http_client(daemon.url, http_client=http), mode=mode, elicitation_callback=elicitation)


class RawSession:
    """A 2025-11-25 streamable HTTP session driven by hand: calls answered over httpx2, and POSTs
    on a bare socket that can be dropped (RST) at any point of their SSE answer."""

    VERSION = "2025-11-25"

    def __init__(self, daemon: Daemon, token: str) -> None:
        self.daemon, self.token, self.session_id, self.next_id = daemon, token, None, 0
        self.http = httpx2.Client(timeout=30)
        hello = self.post({"jsonrpc": "2.0", "id": self._id(), "method": "initialize", "params": {
            "protocolVersion": self.VERSION, "capabilities": {"elicitation": {"form": {}}},
            "clientInfo": {"name": "raw-http-test", "version": "1"}}})
        self.session_id = hello.headers["mcp-session-id"]
        assert self.post({"jsonrpc": "2.0", "method": "notifications/initialized"}).status_code == 202

    def _id(self) -> int:
        self.next_id += 1
        return self.next_id

    def headers(self) -> dict[str, str]:
        headers = {"Authorization": f"Bearer {self.token}", "Accept": "application/json, text/event-stream",
                   "Content-Type": "application/json", "MCP-Protocol-Version": self.VERSION}
        if self.session_id is not None:
            headers["mcp-session-id"] = self.session_id
        return headers

    def post(self, message: dict[str, Any]):
        return self.http.post(self.daemon.url, json=message, headers=self.headers())

    def call(self, tool: str, arguments: dict[str, Any]) -> dict[str, Any]:
        response = self.post({"jsonrpc": "2.0", "id": self._id(), "method": "tools/call",
                              "params": {"name": tool, "arguments": arguments}})
        for line in response.text.splitlines():
            if line.startswith("data: ") and ('"result"' in line or '"error"' in line):
                return json.loads(line[len("data: "):])
        raise AssertionError(response.text)

    def open_call(self, tool: str, arguments: dict[str, Any]) -> DroppableCall:
        return DroppableCall(self, {"jsonrpc": "2.0", "id": self._id(), "method": "tools/call",
                                    "params": {"name": tool, "arguments": arguments}})


class DroppableCall:
    def __init__(self, owner: RawSession, message: dict[str, Any]) -> None:
        payload = json.dumps(message).encode()
        header = "".join(f"{name}: {value}\r\n" for name, value in owner.headers().items())
        self.sock = socket.create_connection(("127.0.0.1", owner.daemon.port), timeout=30)
        self.sock.sendall(f"POST /mcp HTTP/1.1\r\nHost: 127.0.0.1:{owner.daemon.port}\r\n{header}"
                          f"Content-Length: {len(payload)}\r\n\r\n".encode() + payload)
        self.buffer = b""

    def wait_for(self, predicate) -> dict[str, Any]:
        while True:
            for raw in re.findall(rb"data: (\{.*?\})\r?\n", self.buffer):
                event = json.loads(raw)
                if predicate(event):
                    return event
            chunk = self.sock.recv(65536)
            assert chunk, "the daemon closed the stream"
            self.buffer += chunk

    def drop(self) -> None:
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))  # RST, no FIN
        self.sock.close()
