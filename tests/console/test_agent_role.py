"""Who may release the e-stop in the console (outside review 2, item 2).

An MCP client's token must not double as a human's console sign-in: the agent could otherwise
sign in with it, like a script, and release an e-stop a human latched. So:

- tokens have an `agent` role (`armwarden tokens add --role agent`): the MCP tools an operator
  may call, but no console sign-in at all (so no approving or releasing there);
- a console release by the principal whose MCP call latched one of the held e-stops, or who
  asked to release it over MCP, is refused (another operator must release it), unless
  `approval.allow_self_approval` is on; then the release says so in the audit log.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from armwarden.cli import main as cli_main
from armwarden.transport.tokens import TokenStore
from tests.console.served import ServedConsole, csrf_of, served_console, sign_in
from tests.helpers import records_of, text_of
from tests.server.harness import answer, approve, plan_down, policy_with

pytestmark = pytest.mark.anyio


def add_agent(served: ServedConsole, name: str = "claude") -> str:
    """An agent token in the served console's token file (re-read on its next use)."""
    assert served.tokens_path is not None
    return TokenStore.add(served.tokens_path, "agent", name=name)


async def release(served: ServedConsole, token: str, event: int) -> tuple[object, object]:
    """Sign in with `token` and type `event` into the Safety page's release form: the sign-in's
    and the release's answers (None for the release when the sign-in got no session)."""
    async with served.browser_client() as http:
        signed = await sign_in(http, token)
        page = await http.get("/console/safety")
        if page.status_code != 200:
            return signed, None
        return signed, await http.post("/console/reset", data={"event": str(event), "csrf": csrf_of(page.text)})


def console_records(served: ServedConsole, event: str) -> list[dict]:
    return [r for r in records_of(served.harness.audit_path) if r["event"] == event]


async def test_an_agent_token_cannot_sign_in_to_release_an_estop_a_human_latched(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served:
        agent = add_agent(served)
        event = (await served.harness.guard.emergency_stop("dana stops the arm", source="estop")).estop_event.number
        signed, released = await release(served, agent, event)

    assert signed.headers["location"].endswith("/console/login?msg=agent_token")  # type: ignore[attr-defined]
    assert released is None
    assert served.harness.guard.latch.is_latched
    refused = console_records(served, "console_sign_in")
    assert [(r["principal"], r["outcome"], r["extra"]["reason"]) for r in refused] == [("claude", "refused", "agent_token")]


async def test_an_agent_token_calls_the_tools_an_operator_may(tmp_path: Path) -> None:
    async with served_console(tmp_path, policy_with(**{"approval.mode": "always"})) as served:
        agent = add_agent(served)
        async with served.mcp_client(elicitation=approve("alice, watching the arm"), token=agent) as client:
            tools = {tool.name for tool in (await client.list_tools()).tools}
            plan = await plan_down(client, 0.40)
            result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

    assert {"execute_plan", "reset_estop", "switch_controllers", "gripper_move"} <= tools
    assert not result.is_error, text_of(result)
    assert "execute" in served.harness.actuations


def test_tokens_add_takes_the_agent_role(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "tokens.json"

    status = cli_main(["tokens", "add", str(path), "--role", "agent", "--name", "claude"])

    assert status == 0
    assert [(info.name, info.role) for info in TokenStore.list(path)] == [("claude", "agent")]


async def test_the_operator_whose_call_latched_the_estop_cannot_release_it_in_the_console(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served:
        async with served.mcp_client() as client:  # the agent's client, with alice's operator token
            stopped = await client.call_tool("estop", {"reason": "the agent stops"})
        event = stopped.structured_content["estop_event"]["number"]
        _, own = await release(served, served.operator_token, event)
        still_latched = served.harness.guard.latch.is_latched
        _, other = await release(served, served.approver_token, event)

    assert own.status_code == 403 and "another operator" in own.text  # type: ignore[attr-defined]
    assert still_latched
    assert other.status_code == 303  # type: ignore[attr-defined]
    assert not served.harness.guard.latch.is_latched
    resets = console_records(served, "console_reset_estop")
    assert [(r["principal"], r["outcome"]) for r in resets] == [("alice", "refused_self_release"), ("dana", "released")]


async def test_the_operator_who_asked_over_mcp_to_release_cannot_release_it_in_the_console(tmp_path: Path) -> None:
    async with served_console(tmp_path) as served:
        event = (await served.harness.guard.emergency_stop("dana stops the arm", source="estop")).estop_event.number
        async with served.mcp_client(elicitation=answer("decline")) as client:  # alice asks; the form is declined
            asked = await client.call_tool("reset_estop", {})
        _, own = await release(served, served.operator_token, event)

    assert asked.is_error
    assert own.status_code == 403  # type: ignore[attr-defined]
    assert served.harness.guard.latch.is_latched


async def test_a_self_release_allowed_by_the_policy_is_said_in_the_audit(tmp_path: Path) -> None:
    async with served_console(tmp_path, policy_with(**{"approval.allow_self_approval": True})) as served:
        async with served.mcp_client() as client:
            stopped = await client.call_tool("estop", {"reason": "the agent stops"})
        _, own = await release(served, served.operator_token, stopped.structured_content["estop_event"]["number"])

    assert own.status_code == 303  # type: ignore[attr-defined]
    assert not served.harness.guard.latch.is_latched
    (reset,) = console_records(served, "console_reset_estop")
    assert reset["outcome"] == "released" and reset["extra"]["self_release"] is True


async def test_a_force_violation_during_an_operators_motion_is_not_released_by_that_operator(tmp_path: Path) -> None:
    """A latch by the force monitor during alice's execute_plan is her call's latch."""
    async with served_console(tmp_path, table_height_m=0.32, speedup=2.0) as served:  # the table top above the target
        async with served.mcp_client() as client:
            plan = await plan_down(client, 0.30, status="ok")
            result = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})
        event = served.harness.guard.latch.current_event
        assert event is not None and event.source == "force_monitor", text_of(result)
        _, own = await release(served, served.operator_token, event.number)

    assert own.status_code == 403  # type: ignore[attr-defined]
    assert served.harness.guard.latch.is_latched

