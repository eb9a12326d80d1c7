"""The cause, not the symptom (issue 24, item 12): when the ROS 2 cell dies, or the backend's
executor thread does, during an execution, the wrench goes stale first — but the answer, the
latched e-stop and `get_safety_status` name the backend fault, not a force limit.

Found by review: a dead cell was first reported as `FORCE_LIMIT … wrench 0.10 s old` with
`force_violation_latched: true`, and the backend fault followed only afterwards.
"""

from __future__ import annotations

from typing import Any

import pytest
from mcp import Client
from tests.helpers import text_of
from tests.scenarios.steps import executing, joints, plan_joints
from tests.server.harness import approve, arm_harness, wait_until

pytestmark = pytest.mark.anyio


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


async def safety(client: Client) -> dict[str, Any]:
    result = await client.call_tool("get_safety_status", {})
    assert not result.is_error, text_of(result)
    return result.structured_content


def assert_reported_as_a_backend_fault(arm: Any, result: Any, status: dict[str, Any], cause: str) -> None:
    text = text_of(result)
    assert result.is_error and "BACKEND_FAULT" in text and cause in text, text
    assert "FORCE_LIMIT" not in text, text
    assert status["estopped"] and not status["force_violation_latched"], status
    assert status["estop_event"]["source"] == "backend_fault", status
    assert [event.source for event in arm.guard.latch.held_events if event.source == "force_monitor"] == []


async def test_a_cell_that_dies_mid_motion_is_answered_as_a_backend_fault_not_a_force_limit(tmp_path) -> None:
    async with arm_harness(tmp_path, backend="ros2") as arm, arm.client("legacy", approve()) as client:
        summary = await plan_joints(client, joints(j1=0.3), velocity_scaling=0.1, acceleration_scaling=0.1)
        async with executing(arm, client, summary["plan_id"], past=0.05) as outcome:
            arm.cell.die()
        assert_reported_as_a_backend_fault(arm, outcome["result"], await safety(client),
                                           "joint states on /joint_states stopped arriving")


async def test_an_executor_thread_that_dies_mid_motion_is_answered_as_a_backend_fault(tmp_path) -> None:
    async with arm_harness(tmp_path, backend="ros2") as arm, arm.client("legacy", approve()) as client:
        summary = await plan_joints(client, joints(j1=0.3), velocity_scaling=0.1, acceleration_scaling=0.1)
        async with executing(arm, client, summary["plan_id"], past=0.05) as outcome:
            arm.inner.inject_worker_failure("executor", RuntimeError("injected: the executor dies"))
        assert_reported_as_a_backend_fault(arm, outcome["result"], await safety(client),
                                           "the executor thread stopped (RuntimeError: injected: the executor dies)")
        # the dying thread's stop still reached the cell: the cell counts a goal cancelled once its own
        # execute loop has seen the cancel, a moment after the request arrived (CI read it in between)
        await wait_until(lambda: arm.cell.counters().goals_canceled >= 1, timeout_s=10.0,
                         what="the cell saw the goal cancelled")


async def test_a_wrench_topic_that_stops_alone_is_still_a_force_monitor_abort(tmp_path) -> None:
    """The other side: the cell lives (its joint states keep coming), only the wrench stopped —
    the force monitor's finding stands (no backend fault is claimed): a lost wrench, latched at
    once, and no force violation (no force over the limit was measured)."""
    async with arm_harness(tmp_path, backend="ros2") as arm, arm.client("legacy", approve()) as client:
        summary = await plan_joints(client, joints(j1=0.3), velocity_scaling=0.1, acceleration_scaling=0.1)
        async with executing(arm, client, summary["plan_id"], past=0.05) as outcome:
            arm.cell.stop_wrench()
        text = text_of(outcome["result"])
        assert outcome["result"].is_error and "FORCE_LIMIT" in text and "BACKEND_FAULT" not in text, text
        assert "wrench stream was lost" in text, text
        status = await safety(client)
        assert status["estopped"] and not status["force_violation_latched"], status
        assert status["estop_event"]["source"] == "wrench_lost" and status["faults"] == [], status
