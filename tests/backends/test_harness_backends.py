"""Every harness backend runs the daemon's tools end to end: the first scenarios of the suite a
new backend joins with one harness entry (`tests/server/harness.py`, `BACKENDS`)."""

from __future__ import annotations

import pytest

from tests.server.harness import BACKENDS, approve, arm_harness

pytestmark = pytest.mark.anyio
NEAR_READY = [0.1, -0.785398, 0.0, -2.356194, 0.0, 1.570796, 0.785398]


@pytest.mark.parametrize("backend", BACKENDS)
async def test_a_plan_executes_once_and_its_replay_is_refused(tmp_path, backend: str) -> None:
    async with arm_harness(tmp_path, backend=backend) as arm, arm.client("legacy", approve()) as client:
        plan = await client.call_tool("plan_to_joints", {"joint_positions": NEAR_READY, "preview": False})
        plan_id = plan.structured_content["plan_id"]
        done = await client.call_tool("execute_plan", {"plan_id": plan_id})
        assert not done.is_error and done.structured_content["status"] == "succeeded"
        state = (await client.call_tool("get_robot_state", {})).structured_content
        assert state["joint_positions"] == pytest.approx(NEAR_READY, abs=max(arm.inner.goal_accuracy_rad, 1e-9))
        again = await client.call_tool("execute_plan", {"plan_id": plan_id})
        assert again.is_error and "USED_PLAN" in again.content[0].text
        assert arm.actuations == ["execute"]


@pytest.mark.parametrize("backend", BACKENDS)
async def test_a_plan_beyond_the_joint_limits_is_rejected_and_nothing_moves(tmp_path, backend: str) -> None:
    async with arm_harness(tmp_path, backend=backend) as arm, arm.client("legacy", approve()) as client:
        beyond = [3.5, *NEAR_READY[1:]]
        plan = await client.call_tool("plan_to_joints", {"joint_positions": beyond, "preview": False})
        assert plan.is_error or plan.structured_content["status"] == "rejected"
        stop = await client.call_tool("stop_motion", {})
        assert not stop.is_error
        assert arm.actuations == [] and arm.backend.stops >= 1


async def test_the_minimal_backend_registers_no_gripper_or_camera_tools(tmp_path) -> None:
    async with arm_harness(tmp_path, backend="minimal") as arm, arm.client() as client:
        names = {tool.name for tool in (await client.list_tools()).tools}
    assert "execute_plan" in names and "stop_motion" in names
    assert not names & {"gripper_move", "gripper_grasp", "gripper_home", "camera_snapshot", "list_controllers"}
    assert arm.inner.name == "minimal"
