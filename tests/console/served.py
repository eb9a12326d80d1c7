"""A real ArmWarden (fake backend, in memory) served over HTTP on 127.0.0.1 with its operator
console mounted beside /mcp and a stop channel for its E-STOP button, as the daemon wires them,
for the console tests (plain HTTP and browser)."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import re
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import anyio
import httpx2
from mcp import Client
from mcp.client.streamable_http import streamable_http_client

from armwarden.console import ConsoleSettings, SessionStore, build_console_app, timed_estop
from armwarden.policy import Policy
from armwarden.stopchannel import ConsoleDoor, StopChannel
from armwarden.stopchannel.external import ExternalStops
from armwarden.transport.http import build_http_app, serve_http, transport_security_settings
from armwarden.transport.tokens import TokenStore
from tests.helpers import free_port
from tests.server.harness import ArmHarness, ElicitationCallback, arm_harness

HOST = "127.0.0.1"
CSRF_FIELD = re.compile(r'name="csrf" value="([^"]*)"')


@dataclass
class ServedConsole:
    harness: ArmHarness
    base: str
    operator_token: str
    observer_token: str
    channel: StopChannel
    #: a second operator ("dana"): approves in the console what alice's MCP client asked for
    approver_token: str = ""
    #: the console's sign-ins (the stop channel checks their E-STOP tickets)
    sessions: SessionStore | None = None
    tokens_path: Path | None = None

    @property
    def console(self) -> str:
        return self.base + "/console"

    @property
    def mcp(self) -> str:
        return self.base + "/mcp"

    @contextlib.asynccontextmanager
    async def mcp_client(self, mode: str = "legacy", elicitation: ElicitationCallback | None = None,
                         token: str | None = None) -> AsyncIterator[Client]:
        headers = {"Authorization": f"Bearer {token or self.operator_token}"}
        async with httpx2.AsyncClient(headers=headers, timeout=30) as http, Client(
                streamable_http_client(self.mcp, http_client=http), mode=mode, elicitation_callback=elicitation) as client:
            yield client

    def browser_client(self) -> httpx2.AsyncClient:
        """An HTTP client that behaves like a browser tab of the console (cookies, same origin)."""
        return httpx2.AsyncClient(base_url=self.base, timeout=30, follow_redirects=False)


async def sign_in(http: httpx2.AsyncClient, token: str) -> httpx2.Response:
    """Open the sign-in page (its CSRF cookie and field), post the token; the answer."""
    page = await http.get("/console/login")
    csrf = csrf_of(page.text)
    return await http.post("/console/login", data={"token": token, "csrf": csrf})


def csrf_of(html: str) -> str:
    found = CSRF_FIELD.search(html)
    assert found is not None, "no CSRF field on the page"
    return found.group(1)


@contextlib.asynccontextmanager
async def served_console(tmp_path: Path, policy: Policy | None = None,
                         settings: ConsoleSettings | None = None, session_clock: Callable[[], float] | None = None,
                         **fake_options: Any) -> AsyncIterator[ServedConsole]:
    """The harness's Guard and MCP server, served with the console on a free loopback port
    (`session_clock`: the clock console sessions expire by and camera pictures age by, e.g. a
    `FakeClock`; None: monotonic)."""
    tokens_path = tmp_path / "tokens.json"
    operator = TokenStore.add(tokens_path, "operator", name="alice")
    observer = TokenStore.add(tokens_path, "observer", name="bob")
    approver = TokenStore.add(tokens_path, "operator", name="dana")
    tokens = TokenStore.load(tokens_path)
    async with arm_harness(tmp_path, policy, **fake_options) as harness:
        external = ExternalStops(harness.guard.stopper, harness.audit, asyncio.get_running_loop())
        hook = timed_estop(external.latch_and_stop_for("console"), external.record)
        answer = harness.guard.policy.approval.channel in ("url", "both")
        settings = settings or ConsoleSettings(answer_approvals=answer)
        sessions = SessionStore(tokens) if session_clock is None else SessionStore(tokens, clock=session_clock)
        port = free_port()
        door = ConsoleDoor(sessions.principal_for_ticket, external.latch_and_stop_for("console"),
                           frozenset(transport_security_settings(HOST, port).allowed_origins or ()),
                           settings.estop_from_loopback_without_sign_in, f"http://{HOST}:{port}/console/safety")
        channel = StopChannel(authenticate=lambda _token: None, latch_and_stop=external.latch_and_stop_for("stop_channel"),
                              on_event=external.record, on_refused=external.record_refusal, console=door).start()
        settings = dataclasses.replace(settings, estop_url=channel.console_url)
        console = build_console_app(harness.guard, sessions, hook, settings,
                                    clock=time.monotonic if session_clock is None else session_clock)
        harness.guard.approvals.console_url = f"http://{HOST}:{port}/console"
        app = build_http_app(harness.server.mcp, host=HOST, port=port, token_store=tokens, console=console,
                             on_stop_request=external.stop_on_receipt)
        ready, shutdown = anyio.Event(), anyio.Event()
        async with anyio.create_task_group() as group:
            group.start_soon(lambda: serve_http(app, HOST, port, ready=ready, shutdown=shutdown))
            with anyio.fail_after(10):
                await ready.wait()
            try:
                yield ServedConsole(harness, f"http://{HOST}:{port}", operator, observer, channel, approver,
                                    sessions, tokens_path)
            finally:
                shutdown.set()
                channel.close()
