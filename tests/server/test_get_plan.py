"""get_plan: a client reads back a plan it made and has not run, as its plan_* call summarised it;
a plan that could not run is refused as execute_plan would refuse it, and reading moves nothing."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.scenarios.steps import assert_refused, calls, execute, joints, plan_joints
from tests.server.harness import approve, arm_harness, policy_with

pytestmark = pytest.mark.anyio
#: no human is asked for small motions under this policy: execute_plan runs at once
NO_APPROVAL = policy_with(**{"approval.mode": "never"})


async def test_a_plan_reads_back_as_its_planning_call_summarised_it_and_stays_usable(tmp_path: Path) -> None:
    async with arm_harness(tmp_path, NO_APPROVAL) as arm, arm.client() as client:
        summary = await plan_joints(client, joints(j1=0.1))
        read = await client.call_tool("get_plan", {"plan_id": summary["plan_id"]})
        ran = await execute(client, summary["plan_id"])
    assert not read.is_error and read.structured_content == summary
    assert not ran.is_error and arm.actuations == ["execute"]


async def test_reading_a_plan_is_recorded_without_its_summary(tmp_path: Path) -> None:
    async with arm_harness(tmp_path) as arm, arm.client() as client:
        summary = await plan_joints(client, joints(j1=0.1))
        await client.call_tool("get_plan", {"plan_id": summary["plan_id"]})
    record = calls(arm, "get_plan")[-1]
    assert record["outcome"] == "ok" and record["arguments"] == {"plan_id": summary["plan_id"]}
    assert "result" not in (record["extra"] or {})


async def test_a_used_plan_is_refused_as_used(tmp_path: Path) -> None:
    async with arm_harness(tmp_path, NO_APPROVAL) as arm, arm.client() as client:
        summary = await plan_joints(client, joints(j1=0.1))
        assert not (await execute(client, summary["plan_id"])).is_error
        read = await client.call_tool("get_plan", {"plan_id": summary["plan_id"]})
        assert_refused(arm, read, "USED_PLAN", tool="get_plan", moved_before=("execute",))


async def test_a_plan_made_before_an_estop_is_refused_as_invalidated(tmp_path: Path) -> None:
    async with arm_harness(tmp_path) as arm, arm.client("legacy", approve("alice")) as client:
        summary = await plan_joints(client, joints(j1=0.1))
        await client.call_tool("estop", {"reason": "test"})
        await client.call_tool("reset_estop", {})
        read = await client.call_tool("get_plan", {"plan_id": summary["plan_id"]})
        assert_refused(arm, read, "INVALIDATED_PLAN", tool="get_plan")


async def test_another_clients_plan_is_refused_and_stays_its_owners(tmp_path: Path) -> None:
    async with arm_harness(tmp_path) as arm, arm.client() as owner, arm.client() as other:
        summary = await plan_joints(owner, joints(j1=0.1))
        read = await other.call_tool("get_plan", {"plan_id": summary["plan_id"]})
        assert_refused(arm, read, "NOT_PLAN_OWNER", tool="get_plan")
        again = await owner.call_tool("get_plan", {"plan_id": summary["plan_id"]})
    assert not again.is_error and again.structured_content == summary


async def test_an_id_the_server_never_issued_is_refused_as_unknown(tmp_path: Path) -> None:
    async with arm_harness(tmp_path) as arm, arm.client() as client:
        read = await client.call_tool("get_plan", {"plan_id": "plan_not-one-of-ours"})
        assert_refused(arm, read, "UNKNOWN_PLAN", tool="get_plan")
