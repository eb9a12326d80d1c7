"""Under `approval.channel: url` the human approves in the operator console, never in the
requesting client's own form (outside review 2, item 1). The form is answered by the very client
that asked, so falling back to it when the client declares no URL-mode elicitation would let the
agent approve its own motion. Instead the call is refused with a message naming the console, for
execute_plan under both protocol revisions and for every other approval-gated action
(reset_estop: release it in the console; switch_controllers and the rest: no console page, so
refused). `approval.allow_self_approval: true` lets the form stand in, saying so in the prompt
and in the audit record. The Guard itself refuses a form answer under `url` too, whatever the
tool layer let through."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from mcp.client.session import ClientSession
from mcp.server.mcpserver import AcceptedElicitation

from armwarden.approval.decision import ApprovalForm
from armwarden.core.errors import RefusalCode, SafetyRefusal
from tests.console.served import served_console
from tests.helpers import records_of, text_of
from tests.server.harness import MODES, approve, arm_harness, plan_down, policy_with

pytestmark = pytest.mark.anyio

URL_POLICY = {"approval.mode": "always", "approval.channel": "url"}
SELF_POLICY = {**URL_POLICY, "approval.allow_self_approval": True}


@pytest.fixture
def form_only(monkeypatch: pytest.MonkeyPatch) -> None:
    """MCP clients of this test declare form elicitation only (no URL mode): they cannot be sent
    the console link."""
    build = ClientSession._build_capabilities

    def without_url(self: ClientSession, version: str) -> Any:
        capabilities = build(self, version)
        if capabilities.elicitation is None:
            return capabilities
        return capabilities.model_copy(update={"elicitation": capabilities.elicitation.model_copy(update={"url": None})})

    monkeypatch.setattr(ClientSession, "_build_capabilities", without_url)


def tool_records(path: Path, tool: str) -> list[dict[str, Any]]:
    return [r for r in records_of(path) if r["event"] == "tool_call" and r["tool"] == tool]


@pytest.mark.parametrize("mode", MODES)
async def test_a_client_without_url_elicitation_is_refused_not_asked_in_its_own_form(
        tmp_path: Path, mode: str, form_only: None) -> None:
    human = approve("the agent itself")
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        async with served.mcp_client(mode, elicitation=human) as client:
            plan = await plan_down(client, 0.40)
            result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    assert result.is_error
    assert "operator console" in text_of(result) and "URL-mode" in text_of(result)
    assert human.prompts == []  # type: ignore[attr-defined]
    assert "execute" not in served.harness.actuations
    assert tool_records(served.harness.audit_path, "execute_plan")[-1]["extra"]["code"] == RefusalCode.APPROVAL_UNAVAILABLE.value


@pytest.mark.parametrize("mode", MODES)
async def test_with_self_approval_allowed_the_form_stands_in_and_says_so(tmp_path: Path, mode: str, form_only: None) -> None:
    human = approve("alice at her desk")
    async with served_console(tmp_path, policy_with(**SELF_POLICY)) as served:
        async with served.mcp_client(mode, elicitation=human) as client:
            plan = await plan_down(client, 0.40)
            result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    assert not result.is_error, text_of(result)
    assert "allow_self_approval" in human.prompts[0]  # type: ignore[attr-defined]
    assert result.structured_content["approval"]["via"] == "elicitation"
    executed = tool_records(served.harness.audit_path, "execute_plan")[-1]
    assert executed["outcome"] == "ok" and executed["extra"]["approval"]["self_approval"] is True


@pytest.mark.parametrize("mode", MODES)
async def test_reset_estop_is_not_asked_in_the_form_but_sent_to_the_console(tmp_path: Path, mode: str) -> None:
    human = approve("the agent itself")
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        await served.harness.guard.emergency_stop("a human pressed stop", source="estop")
        async with served.mcp_client(mode, elicitation=human) as client:
            result = await client.call_tool("reset_estop", {})

    assert result.is_error
    assert "operator console" in text_of(result)
    assert human.prompts == []  # type: ignore[attr-defined]
    assert served.harness.guard.latch.is_latched


async def test_switch_controllers_is_not_asked_in_the_form_under_channel_url(tmp_path: Path) -> None:
    human = approve("the agent itself")
    async with served_console(tmp_path, policy_with(**URL_POLICY)) as served:
        async with served.mcp_client(elicitation=human) as client:
            result = await client.call_tool("switch_controllers", {"activate": ["joint_impedance_controller"],
                                                                   "deactivate": ["fr3_arm_controller"]})

    assert result.is_error
    assert "approval.channel" in text_of(result)
    assert human.prompts == []  # type: ignore[attr-defined]
    assert served.harness.actuations == []


async def test_the_guard_refuses_a_form_answer_under_channel_url(tmp_path: Path) -> None:
    """Whatever the tool layer let through: under `url` the Guard takes no form answer."""
    async with arm_harness(tmp_path, policy_with(**URL_POLICY)) as harness:
        event = (await harness.guard.emergency_stop("stop", source="estop")).estop_event.number
        form = AcceptedElicitation[ApprovalForm](data=ApprovalForm(approve=True, operator="the agent"))
        with pytest.raises(SafetyRefusal) as refused:
            await harness.guard.reset_estop(form, str(event))

    assert refused.value.code == RefusalCode.APPROVAL_UNAVAILABLE
    assert harness.guard.latch.is_latched
