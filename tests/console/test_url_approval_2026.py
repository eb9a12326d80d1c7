"""Approvals out of band under protocol 2026-07-28, through the SDK client over HTTP: execute_plan
answers with an InputRequiredResult carrying the console link (URL-mode elicitation), the client
retries with its answers and the sealed round state, and the retry proceeds from the server-side
record only. (The same flow under 2025-11-25: test_url_approval.py; over stdio:
test_url_approval_stdio.py.)"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import anyio
import httpx2
import mcp_types as types
import pytest
from mcp import Client, MCPError

from armwarden.server.outofband import FORM_KEY
from tests.console.served import ServedConsole, csrf_of, served_console, sign_in
from tests.helpers import records_of, text_of
from tests.server.harness import plan_down, policy_with, wait_until

pytestmark = pytest.mark.anyio

MODE = "2026-07-28"
URL_POLICY = {"approval.mode": "always", "approval.channel": "url"}
BOTH_POLICY = {"approval.mode": "always", "approval.channel": "both"}
ACCEPT = types.ElicitResult(action="accept")


async def answer_in_console(served: ServedConsole, link: str, decision: str,
                            after_page: Callable[[], Awaitable[None]] | None = None) -> httpx2.Response:
    """Operator dana (not the requesting token, alice) opens `link` in the console and answers `decision`; the console's response."""
    path = link.removeprefix(served.base)
    async with served.browser_client() as http:
        await sign_in(http, served.approver_token)
        page = await http.get(path)
        if after_page is not None:
            await after_page()
        return await http.post(path, data={"decision": decision, "csrf": csrf_of(page.text)})


def console_operator(served: ServedConsole, decision: str | None, seen: list[Any]) -> Any:
    """An elicitation callback: the link is answered in the console with `decision` (None: nobody
    answers), then the client reports that the human opened it. Form questions are not answered."""

    async def callback(context: Any, params: Any) -> types.ElicitResult:
        seen.append(params)
        if getattr(params, "mode", "form") != "url":
            return types.ElicitResult(action="cancel")
        if decision is not None:
            await answer_in_console(served, params.url, decision)
        return ACCEPT

    return callback


async def answered_by_hand(context: Any, params: Any) -> types.ElicitResult:
    """The callback of a client whose rounds the test drives itself (it declares elicitation)."""
    raise AssertionError("the test answers the questions itself")


async def first_round(client: Client, plan_id: str) -> types.InputRequiredResult:
    """Call execute_plan once without answering: the round the server asks in."""
    asked = await client.session.call_tool("execute_plan", {"plan_id": plan_id}, allow_input_required=True)
    assert isinstance(asked, types.InputRequiredResult), asked
    return asked


def link_key(asked: types.InputRequiredResult) -> str:
    """The key of the link's question (the approval request's id)."""
    return next(key for key in asked.input_requests if key != FORM_KEY)


def link_of(asked: types.InputRequiredResult) -> str:
    params = asked.input_requests[link_key(asked)].params
    assert isinstance(params, types.ElicitRequestURLParams)
    return params.url


async def retry(client: Client, plan_id: str, asked: types.InputRequiredResult,
                state: str | None = None) -> types.CallToolResult:
    result = await client.session.call_tool("execute_plan", {"plan_id": plan_id},
                                            input_responses={link_key(asked): ACCEPT},
                                            request_state=asked.request_state if state is None else state,
                                            allow_input_required=True)
    assert isinstance(result, types.CallToolResult), result
    return result


# ---------------------------------------------------------------------------------------------- url
async def test_the_link_goes_out_in_an_input_required_result_with_the_console_page(tmp_path: Path) -> None:
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        async with served.mcp_client(MODE, elicitation=answered_by_hand) as client:
            plan = await plan_down(client, 0.40)
            asked = await first_round(client, plan["plan_id"])
        request = served.harness.guard.approvals.live(served.harness.guard.latch.generation)[0]

    assert list(asked.input_requests) == [request.request_id]
    params = asked.input_requests[request.request_id].params
    assert isinstance(params, types.ElicitRequestURLParams)
    assert params.url == f"{served.console}/approvals/{request.request_id}"
    assert request.code in params.message
    assert served.harness.actuations == []


async def test_approved_in_the_console_the_motion_runs(tmp_path: Path) -> None:
    seen: list[Any] = []
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        async with served.mcp_client(MODE, elicitation=console_operator(served, "approve", seen)) as client:
            plan = await plan_down(client, 0.40)
            result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    assert not result.is_error, text_of(result)
    assert result.structured_content["status"] == "succeeded"
    assert result.structured_content["approval"] == {"required": True, "operator": "dana", "via": "console"}
    assert [p.mode for p in seen] == ["url"]
    assert "execute" in served.harness.actuations


async def test_declined_in_the_console_nothing_moves(tmp_path: Path) -> None:
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        async with served.mcp_client(MODE, elicitation=console_operator(served, "decline", [])) as client:
            plan = await plan_down(client, 0.40)
            result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    assert result.is_error
    assert "APPROVAL_DENIED" in text_of(result) and "declined" in text_of(result)
    assert served.harness.actuations == []


async def test_a_link_the_client_opened_but_nobody_answered_is_refused_when_the_plan_expires(tmp_path: Path) -> None:
    policy = policy_with(**URL_POLICY, **{"motion.plan_ttl_s": 3.0})
    async with served_console(tmp_path, policy) as served:
        async with served.mcp_client(MODE, elicitation=console_operator(served, None, [])) as client:
            plan = await plan_down(client, 0.40)
            with anyio.fail_after(20):
                result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})
        still_open = served.harness.guard.approvals.live(served.harness.guard.latch.generation)

    assert result.is_error
    assert served.harness.actuations == []
    assert still_open == []


async def test_a_declined_link_is_refused(tmp_path: Path) -> None:
    async def decline_link(context: Any, params: Any) -> types.ElicitResult:
        return types.ElicitResult(action="decline")

    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        async with served.mcp_client(MODE, elicitation=decline_link) as client:
            plan = await plan_down(client, 0.40)
            result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    assert result.is_error and "did not open the approval link" in text_of(result)
    assert served.harness.actuations == []


async def test_a_forged_round_state_is_refused_and_nothing_moves(tmp_path: Path) -> None:
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        async with served.mcp_client(MODE, elicitation=answered_by_hand) as client:
            plan = await plan_down(client, 0.40)
            asked = await first_round(client, plan["plan_id"])
            await answer_in_console(served, link_of(asked), "approve")
            state = asked.request_state or ""
            forged = state[:-6] + ("AAAAAA" if not state.endswith("AAAAAA") else "BBBBBB")
            with pytest.raises(MCPError):
                await retry(client, plan["plan_id"], asked, forged)

    assert served.harness.actuations == []


async def test_a_replayed_round_state_does_not_run_the_plan_twice(tmp_path: Path) -> None:
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        async with served.mcp_client(MODE, elicitation=answered_by_hand) as client:
            plan = await plan_down(client, 0.40)
            asked = await first_round(client, plan["plan_id"])
            await answer_in_console(served, link_of(asked), "approve")
            ran = await retry(client, plan["plan_id"], asked)
            moved = list(served.harness.actuations)
            replayed = await retry(client, plan["plan_id"], asked)

    assert not ran.is_error, text_of(ran)
    assert replayed.is_error
    assert served.harness.actuations == moved


async def test_the_state_of_an_earlier_round_is_refused_once_the_question_was_asked_again(tmp_path: Path) -> None:
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        async with served.mcp_client(MODE, elicitation=answered_by_hand) as client:
            plan = await plan_down(client, 0.40)
            earlier = await first_round(client, plan["plan_id"])
            later = await first_round(client, plan["plan_id"])  # the same request, a new round
            await answer_in_console(served, link_of(later), "approve")
            result = await retry(client, plan["plan_id"], earlier)

    assert link_of(earlier) == link_of(later)
    assert result.is_error and "replayed" in text_of(result)
    assert served.harness.actuations == []


async def test_an_estop_between_the_console_approval_and_the_retry_refuses(tmp_path: Path) -> None:
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        async with served.mcp_client(MODE, elicitation=answered_by_hand) as client:
            plan = await plan_down(client, 0.40)
            asked = await first_round(client, plan["plan_id"])
            await answer_in_console(served, link_of(asked), "approve")
            await served.harness.guard.emergency_stop("someone stopped", source="estop")
            result = await retry(client, plan["plan_id"], asked)

    assert result.is_error and "e-stop" in text_of(result)
    assert "execute" not in served.harness.actuations


async def test_an_estop_while_the_retry_waits_for_the_console_refuses_at_once(tmp_path: Path) -> None:
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        guard = served.harness.guard

        def retry_waits() -> bool:  # the round was spent and the retry listens for the console
            return any(r.round_nonce is None and r.listeners for r in guard.approvals.live(guard.latch.generation))

        async def estop_once_the_retry_waits() -> None:
            await wait_until(retry_waits, 10.0, "the retry waiting for the console")
            await guard.emergency_stop("someone stopped", source="estop")

        async with served.mcp_client(MODE, elicitation=console_operator(served, None, [])) as client:
            plan = await plan_down(client, 0.40)
            async with anyio.create_task_group() as group:
                group.start_soon(estop_once_the_retry_waits)
                with anyio.fail_after(20):  # far less than the plan's lifetime
                    result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    assert result.is_error and "e-stop" in text_of(result)
    assert "execute" not in served.harness.actuations


async def test_an_estop_while_the_operator_looks_at_the_link_makes_it_stale(tmp_path: Path) -> None:
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        async def estop() -> None:
            await served.harness.guard.emergency_stop("someone stopped", source="estop")

        answers: list[httpx2.Response] = []

        async def operator(context: Any, params: Any) -> types.ElicitResult:
            answers.append(await answer_in_console(served, params.url, "approve", after_page=estop))
            return ACCEPT

        async with served.mcp_client(MODE, elicitation=operator) as client:
            plan = await plan_down(client, 0.40)
            result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    assert answers[0].status_code == 409 and "e-stop" in answers[0].text
    assert result.is_error
    assert "execute" not in served.harness.actuations


async def test_the_round_and_the_console_answer_are_audited(tmp_path: Path) -> None:
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        async with served.mcp_client(MODE, elicitation=console_operator(served, "approve", [])) as client:
            plan = await plan_down(client, 0.40)
            await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    records = records_of(served.harness.audit_path)
    calls = [r for r in records if r["event"] == "tool_call" and r["tool"] == "execute_plan"]
    assert [r["outcome"] for r in calls] == ["input_required", "ok"]
    assert "operator console" in calls[0]["detail"]
    assert calls[1]["operator"] == "dana"
    assert [r["principal"] for r in records if r["event"] == "console_approval"] == ["dana"]


# ---------------------------------------------------------------------------------------------- both
async def test_both_channels_go_out_in_one_round(tmp_path: Path) -> None:
    async with served_console(tmp_path, policy_with(**BOTH_POLICY)) as served:
        async with served.mcp_client(MODE, elicitation=answered_by_hand) as client:
            plan = await plan_down(client, 0.40)
            asked = await first_round(client, plan["plan_id"])

    assert len(asked.input_requests) == 2 and link_of(asked).startswith(served.console + "/approvals/")
    assert isinstance(asked.input_requests[FORM_KEY].params, types.ElicitRequestFormParams)


async def test_both_channels_the_form_answer_wins_and_the_console_request_closes(tmp_path: Path) -> None:
    async def human(context: Any, params: Any) -> types.ElicitResult:
        if getattr(params, "mode", "form") == "url":
            return ACCEPT  # opened, but nobody answers in the console
        return types.ElicitResult(action="accept", content={"approve": True, "operator": "carol"})

    async with served_console(tmp_path, policy_with(**BOTH_POLICY)) as served:
        async with served.mcp_client(MODE, elicitation=human) as client:
            plan = await plan_down(client, 0.40)
            result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})
        still_open = served.harness.guard.approvals.live(served.harness.guard.latch.generation)

    assert not result.is_error, text_of(result)
    assert result.structured_content["approval"] == {"required": True, "operator": "carol", "via": "elicitation"}
    assert still_open == []


async def test_both_channels_a_console_decision_before_the_retry_wins_over_the_form(tmp_path: Path) -> None:
    async with served_console(tmp_path, policy_with(**BOTH_POLICY)) as served:
        decided = anyio.Event()

        async def human(context: Any, params: Any) -> types.ElicitResult:
            if getattr(params, "mode", "form") == "url":
                await answer_in_console(served, params.url, "approve")
                decided.set()
                return ACCEPT
            await decided.wait()  # the form is answered after the console decided
            return types.ElicitResult(action="accept", content={"approve": False, "operator": "carol"})

        async with served.mcp_client(MODE, elicitation=human) as client:
            plan = await plan_down(client, 0.40)
            with anyio.fail_after(20):
                result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    assert not result.is_error, text_of(result)
    assert result.structured_content["approval"] == {"required": True, "operator": "dana", "via": "console"}


async def test_both_channels_a_form_declined_after_the_console_stayed_silent_is_refused(tmp_path: Path) -> None:
    async def human(context: Any, params: Any) -> types.ElicitResult:
        return ACCEPT if getattr(params, "mode", "form") == "url" else types.ElicitResult(action="decline")

    async with served_console(tmp_path, policy_with(**BOTH_POLICY)) as served:
        async with served.mcp_client(MODE, elicitation=human) as client:
            plan = await plan_down(client, 0.40)
            result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    assert result.is_error and "declined" in text_of(result)
    assert served.harness.actuations == []


async def test_a_round_state_sealed_by_another_daemon_is_refused(tmp_path: Path) -> None:
    # Clients never see our seal (the SDK seals request_state once more): this is the retry's
    # own check, called as the tool body calls it, with a state another daemon's key sealed.
    from types import SimpleNamespace

    from armwarden.approval.decision import ConsoleAnswer, ConsoleChannel, Prompt
    from armwarden.server.outofband import answer_round
    from armwarden.server.roundstate import RoundClaims, RoundSeal

    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        async with served.mcp_client(MODE, elicitation=answered_by_hand) as client:
            plan = await plan_down(client, 0.40)
            await first_round(client, plan["plan_id"])
        guard = served.harness.guard
        request = guard.approvals.live(guard.latch.generation)[0]
        await answer_in_console(served, f"{served.console}/approvals/{request.request_id}", "approve")
        claims = RoundClaims(plan["plan_id"], request.request_id, request.digest, request.round_nonce or "", "url")
        ctx = SimpleNamespace(request_state=RoundSeal().seal(claims), input_responses={request.request_id: ACCEPT})
        asked = ConsoleChannel(Prompt(request.prompt, request.digest), "url")
        outcome = await answer_round(ctx, guard, asked, plan["plan_id"], RoundSeal())  # type: ignore[arg-type]

    assert isinstance(outcome, ConsoleAnswer)
    assert not outcome.approved and "not issued by this daemon" in (outcome.missing or "")
