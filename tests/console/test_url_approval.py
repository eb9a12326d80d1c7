"""Approvals out of band (`approval.channel: url | both`) through the SDK client over HTTP: the
link arrives as URL-mode elicitation, the operator answers in the console, and execute_plan
proceeds from the server-side record only."""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import anyio
import httpx2
import mcp_types as types
import pytest

from tests.console.served import ServedConsole, csrf_of, served_console, sign_in
from tests.helpers import records_of, text_of
from tests.server.harness import plan_down, policy_with

pytestmark = pytest.mark.anyio

URL_POLICY = {"approval.mode": "always", "approval.channel": "url"}


def console_operator(served: ServedConsole, decision: str, links: list[str],
                     after: Callable[[], Awaitable[None]] | None = None) -> Any:
    """An elicitation callback: a URL-mode request is opened in the console as operator dana (not the
    requesting token, alice) and
    answered with `decision`; the client then reports that the human opened the link."""

    async def callback(context: Any, params: Any) -> types.ElicitResult:
        if getattr(params, "mode", "form") != "url":
            await anyio.sleep(60)  # a form question nobody answers (the console wins)
            return types.ElicitResult(action="cancel")
        links.append(params.url)
        path = params.url.removeprefix(served.base)
        async with httpx2.AsyncClient(base_url=served.base, timeout=30) as http:
            await sign_in(http, served.approver_token)
            page = await http.get(path)
            if after is not None:
                await after()
            answer = await http.post(path, data={"decision": decision, "csrf": csrf_of(page.text)})
            callback.answers.append(answer)  # type: ignore[attr-defined]
        return types.ElicitResult(action="accept")

    callback.answers = []  # type: ignore[attr-defined]
    return callback


async def test_approved_in_the_console_the_motion_runs(tmp_path: Path) -> None:
    links: list[str] = []
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        operator = console_operator(served, "approve", links)
        async with served.mcp_client(elicitation=operator) as client:
            plan = await plan_down(client, 0.40)
            result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    assert not result.is_error, text_of(result)
    assert result.structured_content["status"] == "succeeded"
    assert result.structured_content["approval"] == {"required": True, "operator": "dana", "via": "console"}
    assert links and links[0].startswith(served.console + "/approvals/")
    assert "execute" in served.harness.actuations


async def test_declined_in_the_console_nothing_moves(tmp_path: Path) -> None:
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        operator = console_operator(served, "decline", [])
        async with served.mcp_client(elicitation=operator) as client:
            plan = await plan_down(client, 0.40)
            result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    assert result.is_error
    assert "declined" in text_of(result)
    assert served.harness.actuations == []


async def test_a_replayed_link_is_refused(tmp_path: Path) -> None:
    links: list[str] = []
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        operator = console_operator(served, "approve", links)
        async with served.mcp_client(elicitation=operator) as client:
            plan = await plan_down(client, 0.40)
            await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})
        async with served.browser_client() as http:
            await sign_in(http, served.approver_token)
            path = links[0].removeprefix(served.base)
            page = await http.get(path)
            replay = await http.post(path, data={"decision": "approve", "csrf": csrf_of(page.text)})

    assert replay.status_code == 409
    assert "already" in replay.text


async def test_a_link_made_stale_by_an_estop_is_refused(tmp_path: Path) -> None:
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        async def estop() -> None:
            await served.harness.guard.emergency_stop("someone stopped", source="estop")

        operator = console_operator(served, "approve", [], after=estop)
        async with served.mcp_client(elicitation=operator) as client:
            plan = await plan_down(client, 0.40)
            result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    assert operator.answers[0].status_code == 409
    assert "e-stop" in operator.answers[0].text
    assert result.is_error
    assert "execute" not in served.harness.actuations


async def test_an_observer_cannot_answer_a_link(tmp_path: Path) -> None:
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        seen: list[int] = []

        async def observer(context: Any, params: Any) -> types.ElicitResult:
            path = params.url.removeprefix(served.base)
            async with httpx2.AsyncClient(base_url=served.base, timeout=30) as http:
                await sign_in(http, served.observer_token)
                page = await http.get(path)
                seen.append((await http.post(path, data={"decision": "approve", "csrf": csrf_of(page.text)})).status_code)
            return types.ElicitResult(action="decline")

        async with served.mcp_client(elicitation=observer) as client:
            plan = await plan_down(client, 0.40)
            result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    assert seen == [403]
    assert result.is_error
    assert "execute" not in served.harness.actuations


async def test_both_channels_the_console_answer_wins_and_the_form_is_withdrawn(tmp_path: Path) -> None:
    policy = policy_with(**{"approval.mode": "always", "approval.channel": "both"})
    async with served_console(tmp_path, policy) as served:
        form_asked = anyio.Event()

        async def form_left_open(context: Any, params: Any) -> types.ElicitResult:
            form_asked.set()
            await anyio.sleep(60)
            return types.ElicitResult(action="accept", content={"approve": False})

        async def approve_in_console() -> None:
            with anyio.fail_after(10):
                await form_asked.wait()
            request = served.harness.guard.approvals.live(served.harness.guard.latch.generation)[0]
            async with served.browser_client() as http:
                await sign_in(http, served.approver_token)
                path = f"/console/approvals/{request.request_id}"
                page = await http.get(path)
                await http.post(path, data={"decision": "approve", "csrf": csrf_of(page.text)})

        async with served.mcp_client(elicitation=form_left_open) as client:
            plan = await plan_down(client, 0.40)
            async with anyio.create_task_group() as group:
                group.start_soon(approve_in_console)
                with anyio.fail_after(20):
                    result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    assert not result.is_error, text_of(result)
    assert result.structured_content["approval"]["via"] == "console"


async def test_both_channels_the_form_answer_wins_and_the_console_request_closes(tmp_path: Path) -> None:
    policy = policy_with(**{"approval.mode": "always", "approval.channel": "both"})
    async with served_console(tmp_path, policy) as served:
        async def approve_in_form(context: Any, params: Any) -> types.ElicitResult:
            return types.ElicitResult(action="accept", content={"approve": True, "operator": "carol"})

        async with served.mcp_client(elicitation=approve_in_form) as client:
            plan = await plan_down(client, 0.40)
            result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})
        still_open = served.harness.guard.approvals.live(served.harness.guard.latch.generation)

    assert not result.is_error, text_of(result)
    assert result.structured_content["approval"]["via"] == "elicitation"
    assert still_open == []


async def test_console_answers_are_audited_with_the_token_name(tmp_path: Path) -> None:
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        operator = console_operator(served, "approve", [])
        async with served.mcp_client(elicitation=operator) as client:
            plan = await plan_down(client, 0.40)
            await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    answers = [r for r in records_of(served.harness.audit_path) if r["event"] == "console_approval"]
    assert [(r["principal"], r["outcome"]) for r in answers] == [("dana", "approved")]
