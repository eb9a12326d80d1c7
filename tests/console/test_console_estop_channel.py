"""The console's E-STOP goes through the independent stop channel: the page's button posts to the
channel with its session's ticket, and the stop is issued even while the daemon's event loop is
blocked."""

from __future__ import annotations

import asyncio
import http.client
import re
import threading
from pathlib import Path
from typing import Any

import anyio
import anyio.lowlevel
import pytest

from tests.console.served import ServedConsole, served_console, sign_in
from tests.helpers import records_of, text_of
from tests.server.harness import HOME_TCP_X, wait_until

pytestmark = pytest.mark.anyio

TICKET_FIELD = re.compile(r'name="ticket" value="([^"]*)"')
ESTOP_FORM = re.compile(r'<form method="post" action="([^"]*)" class="estop" id="estop-form"')
WAIT_S = 30.0  # only there so a broken stop fails the test instead of hanging it


def ticket_of(html: str) -> str:
    found = TICKET_FIELD.search(html)
    assert found is not None, "no E-STOP ticket on the page"
    return found.group(1)


def press_estop(served: ServedConsole, ticket: str | None, origin: str | None = None) -> tuple[int, str]:
    """What the page's E-STOP form sends to the stop channel (from any thread): (status, HTML)."""
    channel = served.channel
    connection = http.client.HTTPConnection("127.0.0.1", channel.port, timeout=WAIT_S)
    headers = {"Content-Type": "application/x-www-form-urlencoded", "Origin": origin or served.base}
    try:
        connection.request("POST", "/console-estop", body=b"" if ticket is None else f"ticket={ticket}".encode(),
                           headers=headers)
        response = connection.getresponse()
        return response.status, response.read().decode()
    finally:
        connection.close()


async def test_every_page_posts_its_estop_to_the_stop_channel_with_the_sessions_ticket(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        login = await http.get("/console/login")
        await sign_in(http, served.observer_token)
        page = await http.get("/console/")

    assert ESTOP_FORM.search(login.text).group(1) == served.channel.console_url  # type: ignore[union-attr]
    assert ESTOP_FORM.search(page.text).group(1) == served.channel.console_url  # type: ignore[union-attr]
    assert 'name="csrf"' not in page.text.split('id="estop-form"')[1].split("</form>")[0]
    assert ticket_of(page.text)
    channel_origin = served.channel.console_url.removesuffix("/console-estop")
    csp = page.headers["content-security-policy"]
    assert f"form-action 'self' {channel_origin}" in csp and f"connect-src 'self' {channel_origin}" in csp


async def test_the_ticket_stops_and_is_audited_with_the_token_name(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await sign_in(http, served.observer_token)
        ticket = ticket_of((await http.get("/console/")).text)
        status, answer = await anyio.to_thread.run_sync(press_estop, served, ticket)
        latched = served.harness.guard.latch.is_latched

    assert status == 200 and "E-STOP latched: event #1" in answer and "/console/safety" in answer
    assert latched
    estops = [r for r in records_of(served.harness.audit_path) if r["event"] == "estop"]
    assert estops[-1]["principal"] == "bob" and estops[-1]["outcome"] == "latched"
    assert estops[-1]["extra"]["peer"].startswith("console via stop channel")


async def test_a_signed_out_sessions_ticket_still_stops_from_this_machine(tmp_path: Path) -> None:
    """The page of a session that is gone stops where a page without a ticket would (loopback)."""
    async with served_console(tmp_path) as served, served.browser_client() as http:
        await sign_in(http, served.observer_token)
        page = await http.get("/console/")
        await http.post("/console/logout", data={"csrf": re.search(r'name="csrf" value="([^"]*)"', page.text).group(1)})  # type: ignore[union-attr]
        status, _ = await anyio.to_thread.run_sync(press_estop, served, ticket_of(page.text))
        latched = served.harness.guard.latch.is_latched

    assert status == 200
    assert latched


async def test_a_post_from_another_web_site_is_refused(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served:
        status, _ = await anyio.to_thread.run_sync(press_estop, served, None, "http://evil.example")
        latched = served.harness.guard.latch.is_latched

    assert status == 403
    assert not latched


async def test_console_estop_stops_the_motion_while_the_event_loop_is_blocked(tmp_path: Path) -> None:
    async with served_console(tmp_path, speedup=0.05) as served, served.browser_client() as http:  # ~20 s of travel
        guard = served.harness.guard
        await sign_in(http, served.observer_token)
        ticket = ticket_of((await http.get("/console/")).text)
        async with served.mcp_client() as client:
            planned = await client.call_tool("plan_to_pose", {"position": {"x": HOME_TCP_X, "y": 0.0, "z": 0.30}})
            assert not planned.is_error, text_of(planned)
            outcome: dict[str, Any] = {}

            async def execute() -> None:
                outcome["result"] = await client.call_tool("execute_plan",
                                                           {"plan_id": planned.structured_content["plan_id"]})

            async with anyio.create_task_group() as group:
                group.start_soon(execute)
                await wait_until(lambda: guard.motion_status().progress > 0, WAIT_S, what="the arm moving")
                seen = await _press_while_the_loop_is_blocked(served, ticket)

    assert seen["status"] == 200, seen["answer"]
    assert seen["loop_still_blocked"] is True
    assert seen["latched"] is True and seen["emergency_stops"] == 1
    result = outcome["result"]
    assert result.structured_content is not None, text_of(result)
    assert result.structured_content["status"] == "aborted"


async def _press_while_the_loop_is_blocked(served: ServedConsole, ticket: str) -> dict[str, Any]:
    """Block the event loop in a callback that returns only when an operator thread has pressed
    E-STOP through the channel and looked at the latch and the backend; what that thread saw."""
    guard, backend = served.harness.guard, served.harness.backend
    blocked, release = threading.Event(), threading.Event()
    seen: dict[str, Any] = {}

    def operator() -> None:
        try:
            assert blocked.wait(WAIT_S), "the loop was never blocked"
            seen["status"], seen["answer"] = press_estop(served, ticket)
            seen["latched"] = guard.latch.is_latched
            seen["emergency_stops"] = backend.emergency_stops
            seen["loop_still_blocked"] = not release.is_set()  # only this thread releases the loop
        finally:
            release.set()

    def block_the_loop() -> None:  # runs on the event loop: nothing else there runs until it returns
        blocked.set()
        release.wait(WAIT_S)

    thread = threading.Thread(target=operator, name="operator")
    thread.start()
    asyncio.get_running_loop().call_soon(block_the_loop)
    await anyio.lowlevel.checkpoint()  # the loop runs block_the_loop now
    await anyio.to_thread.run_sync(thread.join, WAIT_S)
    return seen
