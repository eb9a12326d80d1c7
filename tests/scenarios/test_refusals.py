"""Refusals move nothing, on every backend: each scenario is refused with its code on the wire
and in the audit log, and not one actuation command reaches the backend (the harness's counting
wrapper). Scenarios that need one motion first (a replay) assert the refusal added nothing."""

from __future__ import annotations

import anyio
import mcp_types as types
import pytest
from mcp import Client, MCPError
from mcp_types import InputRequiredResult

from tests.scenarios.steps import (
    assert_invalid,
    assert_refused,
    calls,
    execute,
    joints,
    plan,
    plan_joints,
    safety,
    text_of,
)
from tests.server.harness import MODES, answer, approve

pytestmark = pytest.mark.anyio
ALWAYS_ASK = {"approval.mode": "always"}


# ------------------------------------------------------------------ the envelope
async def test_a_plan_into_a_keep_out_zone_is_rejected_and_its_execution_refused(arm) -> None:
    async with arm.client() as client:
        summary = await plan(client, "plan_to_pose", {"position": {"x": 0.5, "y": 0.42, "z": 0.40}})  # 'monitor'
        assert summary["status"] == "rejected"
        assert ("KEEP_OUT", "hard") in [(v["code"], v["severity"]) for v in summary["violations"]]

        result = await execute(client, summary["plan_id"])

        record = assert_refused(arm, result, "REJECTED_PLAN")
        assert "KEEP_OUT" in record["detail"] and "monitor" in record["detail"]


async def test_a_plan_leaving_the_workspace_is_rejected_and_its_execution_refused(arm) -> None:
    async with arm.client() as client:
        summary = await plan(client, "plan_to_joints", {"joint_positions": joints(j2=1.4, j6=0.7)})  # TCP below the table
        assert summary["status"] == "rejected"
        assert ("WORKSPACE", "hard") in [(v["code"], v["severity"]) for v in summary["violations"]]

        result = await execute(client, summary["plan_id"])

        record = assert_refused(arm, result, "REJECTED_PLAN")
        assert "WORKSPACE" in record["detail"]


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), 1e6, 1e308], ids=["nan", "inf", "1e6", "1e308"])
async def test_non_finite_and_huge_joint_targets_are_refused_before_planning(arm, bad) -> None:
    async with arm.client() as client:  # the client sends NaN/Inf as null (JSON has no NaN)
        result = await client.call_tool("plan_to_joints", {"joint_positions": [*joints()[:6], bad]})

        record = assert_invalid(arm, result, "plan_to_joints")
        assert "joint_positions" in record["detail"]
        assert calls(arm, "execute_plan") == []


async def test_a_huge_plan_id_is_refused_before_the_tool_runs(arm) -> None:
    async with arm.client() as client:
        result = await execute(client, "plan_" + "x" * 100_000)
        record = assert_invalid(arm, result, "execute_plan")
        assert len(record["arguments"]["plan_id"]) < 1_000  # recorded, truncated


# ------------------------------------------------------------------ the plan store
async def test_an_unknown_plan_id_is_refused(arm) -> None:
    async with arm.client() as client:
        assert_refused(arm, await execute(client, "plan_doesnotexist"), "UNKNOWN_PLAN")


async def test_a_replayed_plan_is_refused_and_the_replay_moves_nothing(arm) -> None:
    async with arm.client() as client:
        summary = await plan_joints(client, joints(j1=0.2))
        done = await execute(client, summary["plan_id"])
        assert done.structured_content["status"] == "succeeded", text_of(done)

        again = await execute(client, summary["plan_id"])

        assert_refused(arm, again, "USED_PLAN", moved_before=("execute",))


@pytest.mark.policy(**{"motion.plan_ttl_s": 0.05})
async def test_an_expired_plan_is_refused(arm) -> None:
    async with arm.client() as client:
        summary = await plan_joints(client, joints(j1=0.2))
        await anyio.sleep(0.1)
        assert_refused(arm, await execute(client, summary["plan_id"]), "EXPIRED_PLAN")


async def test_a_plan_of_another_client_is_refused_and_stays_its_owners(arm) -> None:
    async with arm.client("legacy") as alice, arm.client("legacy") as bob:  # one connection each
        summary = await plan_joints(alice, joints(j1=0.2))

        taken = await execute(bob, summary["plan_id"])

        record = assert_refused(arm, taken, "NOT_PLAN_OWNER")
        mine = await execute(alice, summary["plan_id"])  # Bob's attempt spent nothing
        assert not mine.is_error and mine.structured_content["status"] == "succeeded", text_of(mine)
    assert record["session"] != calls(arm, "execute_plan")[-1]["session"]


# ------------------------------------------------------------------ the e-stop
async def test_execution_is_refused_while_estopped(arm) -> None:
    """Every plan made before the e-stop was invalidated by it (and none can be made while it is
    latched), so the refusal names the plan's state: invalidated by e-stop #1."""
    async with arm.client() as client:
        summary = await plan_joints(client, joints(j1=0.2))
        stopped = await client.call_tool("estop", {"reason": "person in the cell"})
        assert stopped.structured_content["estopped"] is True

        record = assert_refused(arm, await execute(client, summary["plan_id"]), "INVALIDATED_PLAN")

        assert "e-stop #1" in record["detail"]
        assert (await safety(client))["estopped"] is True
        refused = await client.call_tool("plan_to_joints", {"joint_positions": joints(j1=0.2), "preview": False})
        assert_refused(arm, refused, "ESTOPPED", tool="plan_to_joints")


@pytest.mark.needs("gripper")
async def test_the_gripper_is_refused_while_estopped(arm) -> None:
    async with arm.client() as client:
        await client.call_tool("estop", {"reason": "person in the cell"})
        assert_refused(arm, await client.call_tool("gripper_move", {"width_m": 0.04}), "ESTOPPED", tool="gripper_move")


# ------------------------------------------------------------------ approval
@pytest.mark.policy(**ALWAYS_ASK)
@pytest.mark.parametrize("mode", MODES)
async def test_an_execution_the_human_declines_is_refused(arm, mode) -> None:
    human = answer("decline")
    async with arm.client(mode, human) as client:
        summary = await plan_joints(client, joints(j1=0.2))

        record = assert_refused(arm, await execute(client, summary["plan_id"]), "APPROVAL_DENIED")

        assert len(human.prompts) == 1 and summary["plan_id"] in human.prompts[0]
        assert "declined" in record["detail"] and record["operator"] is None


@pytest.mark.policy(**ALWAYS_ASK)
@pytest.mark.parametrize("mode", MODES)
async def test_an_execution_needing_approval_is_refused_for_a_client_that_cannot_ask_a_human(arm, mode) -> None:
    async with arm.client(mode) as client:  # no elicitation callback
        summary = await plan_joints(client, joints(j1=0.2))
        record = assert_refused(arm, await execute(client, summary["plan_id"]), "APPROVAL_UNAVAILABLE")
        assert "elicitation" in record["detail"]


async def reuse_the_approval_of_a_for_b(client: Client) -> str:
    """2026-07-28 carries the human's answer in a second round together with the sealed request
    state of the first: send plan A's state, with an approving answer, under plan B's id."""
    a = await plan_joints(client, joints(j1=0.2))
    b = await plan_joints(client, joints(j1=-0.2))
    asked = await client.session.call_tool("execute_plan", {"plan_id": a["plan_id"]}, allow_input_required=True)
    assert isinstance(asked, InputRequiredResult)
    yes = types.ElicitResult(action="accept", content={"approve": True, "operator": "mallory"})
    with pytest.raises(MCPError, match="requestState"):
        await client.session.call_tool("execute_plan", {"plan_id": b["plan_id"]}, request_state=asked.request_state,
                                       input_responses=dict.fromkeys(asked.input_requests or {}, yes),
                                       allow_input_required=True)
    return b["plan_id"]


@pytest.mark.policy(**ALWAYS_ASK)
async def test_an_approval_given_for_one_plan_does_not_run_another(arm) -> None:
    async with arm.client("2026-07-28", answer("decline")) as client:
        b = await reuse_the_approval_of_a_for_b(client)

        assert arm.actuations == []
        assert all(record["operator"] is None for record in calls(arm, "execute_plan"))
    human = approve("alice")
    async with arm.client("2026-07-28", human) as client:  # B was not spent: its own approval runs it
        done = await execute(client, b)
        assert done.structured_content["status"] == "succeeded", text_of(done)
        assert len(human.prompts) == 1 and b in human.prompts[0]
        assert arm.actuations == ["execute"]


@pytest.mark.policy(**ALWAYS_ASK)
async def test_an_approval_replayed_for_another_plan_is_on_the_audit_record(arm) -> None:
    async with arm.client("2026-07-28", answer("decline")) as client:
        b = await reuse_the_approval_of_a_for_b(client)

        assert arm.actuations == []
        refused = calls(arm, "execute_plan")[-1]
        assert refused["arguments"]["plan_id"] == b
        assert refused["outcome"] == "error" and "requestState" in refused["detail"], refused


@pytest.mark.parametrize("mode", MODES)
async def test_reset_estop_without_a_human_is_refused(arm, mode) -> None:
    async with arm.client(mode) as client:
        await client.call_tool("estop", {"reason": "test"})
        assert_refused(arm, await client.call_tool("reset_estop", {}), "APPROVAL_UNAVAILABLE", tool="reset_estop")
        assert (await safety(client))["estopped"] is True


async def test_nobody_is_asked_to_approve_a_refused_plan(arm) -> None:
    human = approve()
    async with arm.client("legacy", human) as client:
        summary = await plan(client, "plan_to_joints", {"joint_positions": joints(j4=-0.744)})  # past fr3_joint4's limit
        assert_refused(arm, await execute(client, summary["plan_id"]), "REJECTED_PLAN")
        assert human.prompts == []
