"""Who may approve a motion in the console (`approval.channel: url`): a principal other than the
token that requested it. The agent's own client must not be able to sign in to the console with
its operator token and approve its own motion (issue 24, item 3), under either protocol revision.
`approval.allow_self_approval: true` (single-user desks) lets it, and says so on the page and in
the audit log. The elicitation path is answered by the requesting client's human by design; its
audit record says so ("via elicitation")."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import anyio
import httpx2
import mcp_types as types
import pytest

from tests.console.served import ServedConsole, csrf_of, served_console, sign_in
from tests.helpers import records_of, text_of
from tests.server.harness import MODES, answer, plan_down, policy_with

pytestmark = pytest.mark.anyio

URL_POLICY = {"approval.mode": "always", "approval.channel": "url"}
SELF_POLICY = {**URL_POLICY, "approval.allow_self_approval": True}


def console_human(served: ServedConsole, token: str, decisions: list[str], pages: list[str],
                  answers: list[httpx2.Response], link: str = "decline") -> Any:
    """An elicitation callback: the link is opened in the console with `token`, each of
    `decisions` is posted in turn, then the client answers the link with `link` (accept: the
    human opened it; decline: they did not, which ends a call the console left undecided)."""

    async def callback(context: Any, params: Any) -> types.ElicitResult:
        if getattr(params, "mode", "form") != "url":
            return types.ElicitResult(action="cancel")
        path = params.url.removeprefix(served.base)
        # shielded: a console answer ends the call, and the client then cancels this callback
        # before the console's reply has been read
        with anyio.CancelScope(shield=True):
            async with served.browser_client() as http:
                await sign_in(http, token)
                page = await http.get(path)
                pages.append(page.text)
                for decision in decisions:
                    answers.append(await http.post(path, data={"decision": decision, "csrf": csrf_of(page.text)}))
        return types.ElicitResult(action=link)  # type: ignore[arg-type]

    return callback


@pytest.mark.parametrize("mode", MODES)
async def test_the_requesting_token_cannot_approve_its_own_motion_in_the_console(tmp_path: Path, mode: str) -> None:
    pages: list[str] = []
    answers: list[httpx2.Response] = []
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        human = console_human(served, served.operator_token, ["approve"], pages, answers)
        async with served.mcp_client(mode, elicitation=human) as client:  # the agent's client: alice's token
            plan = await plan_down(client, 0.40)
            result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    assert answers[0].status_code == 403
    assert "another operator" in answers[0].text
    assert 'id="approve"' not in pages[0] and 'id="self-approval-refused"' in pages[0]
    assert result.is_error, text_of(result)
    assert "execute" not in served.harness.actuations
    refused = [r for r in records_of(served.harness.audit_path) if r["event"] == "console_approval"]
    assert [(r["principal"], r["outcome"]) for r in refused] == [("alice", "refused_self_approval")]
    assert refused[0]["extra"]["requester"] == "alice"


@pytest.mark.parametrize("mode", MODES)
async def test_another_operator_approves_in_the_console_and_the_motion_runs(tmp_path: Path, mode: str) -> None:
    answers: list[httpx2.Response] = []
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        human = console_human(served, served.approver_token, ["approve"], [], answers, link="accept")
        async with served.mcp_client(mode, elicitation=human) as client:
            plan = await plan_down(client, 0.40)
            result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    assert answers[0].status_code == 303
    assert not result.is_error, text_of(result)
    assert result.structured_content["approval"] == {"required": True, "operator": "dana", "via": "console"}
    approvals = [r for r in records_of(served.harness.audit_path) if r["event"] == "console_approval"]
    assert approvals[0]["extra"]["requester"] == "alice" and approvals[0]["extra"]["self_approval"] is False


async def test_the_requesting_token_may_decline_its_own_motion(tmp_path: Path) -> None:
    answers: list[httpx2.Response] = []
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        human = console_human(served, served.operator_token, ["decline"], [], answers, link="accept")
        async with served.mcp_client(elicitation=human) as client:
            plan = await plan_down(client, 0.40)
            result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    assert answers[0].status_code == 303
    assert result.is_error and "declined" in text_of(result)
    assert served.harness.actuations == []


@pytest.mark.parametrize("mode", MODES)
async def test_self_approval_allowed_by_the_policy_is_said_on_the_page_and_in_the_audit(tmp_path: Path, mode: str) -> None:
    pages: list[str] = []
    answers: list[httpx2.Response] = []
    async with served_console(tmp_path, policy_with(**SELF_POLICY)) as served:
        human = console_human(served, served.operator_token, ["approve"], pages, answers, link="accept")
        async with served.mcp_client(mode, elicitation=human) as client:
            plan = await plan_down(client, 0.40)
            result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    assert not result.is_error, text_of(result)
    assert result.structured_content["approval"] == {"required": True, "operator": "alice", "via": "console"}
    assert 'id="self-approval-allowed"' in pages[0] and 'id="approve"' in pages[0]
    records = records_of(served.harness.audit_path)
    console = [r for r in records if r["event"] == "console_approval"]
    assert console[0]["outcome"] == "approved" and console[0]["extra"]["self_approval"] is True
    assert "its own requester" in console[0]["detail"]
    executed = [r for r in records if r["event"] == "tool_call" and r["tool"] == "execute_plan" and r["outcome"] == "ok"]
    assert executed[0]["extra"]["approval"]["self_approval"] is True


async def test_an_approval_through_elicitation_is_audited_as_via_elicitation(tmp_path: Path) -> None:
    """The form is answered by the requesting client's own human, by design: the record says so."""
    async with served_console(tmp_path, policy_with(**{"approval.mode": "always"})) as served:
        human = answer("accept", {"approve": True, "operator": "erin"})
        async with served.mcp_client(elicitation=human) as client:
            plan = await plan_down(client, 0.40)
            result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    assert not result.is_error, text_of(result)
    executed = [r for r in records_of(served.harness.audit_path)
                if r["event"] == "tool_call" and r["tool"] == "execute_plan"]
    assert executed[-1]["principal"] == "alice"
    assert executed[-1]["extra"]["approval"]["via"] == "elicitation"
    assert executed[-1]["extra"]["approval"]["operator"] == "erin"


async def test_a_caller_of_a_motion_another_caller_waits_for_cannot_approve_it_through_the_others_request(
        tmp_path: Path) -> None:
    """dana asks for motion M and waits; alice plans the very same M (one digest) and asks too:
    alice gets a request of her own, so she cannot approve her M through dana's (outside review
    2, item 3)."""
    pages: list[str] = []
    answers: list[httpx2.Response] = []
    dana_asked, alice_done = anyio.Event(), anyio.Event()

    async def danas_human_is_away(context: Any, params: Any) -> types.ElicitResult:
        dana_asked.set()
        await alice_done.wait()
        return types.ElicitResult(action="decline")

    results: dict[str, Any] = {}
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        alices_client = console_human(served, served.operator_token, ["approve"], pages, answers)
        async with served.mcp_client(elicitation=danas_human_is_away, token=served.approver_token) as dana, \
                served.mcp_client(elicitation=alices_client) as alice:
            danas, alices = await plan_down(dana, 0.40), await plan_down(alice, 0.40)

            async def dana_executes() -> None:
                results["dana"] = await dana.call_tool("execute_plan", {"plan_id": danas["plan_id"]})

            with anyio.fail_after(60):
                async with anyio.create_task_group() as group:
                    group.start_soon(dana_executes)
                    await dana_asked.wait()
                    results["alice"] = await alice.call_tool("execute_plan", {"plan_id": alices["plan_id"]})
                    alice_done.set()

    assert answers[0].status_code == 403 and "another operator" in answers[0].text
    assert results["alice"].is_error and results["dana"].is_error
    assert "execute" not in served.harness.actuations
    refused = [r for r in records_of(served.harness.audit_path) if r["event"] == "console_approval"]
    assert [(r["principal"], r["outcome"], r["extra"]["requester"]) for r in refused] == [
        ("alice", "refused_self_approval", "alice")]
