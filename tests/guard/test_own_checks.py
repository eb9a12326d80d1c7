"""Guarantees that a policy cannot loosen, checked at the Guard itself.

- A policy with `approval.mode: never` still has a human asked before an e-stop is released.
- The gripper's grasp force and the collision thresholds are held to the policy's caps by the
  Guard's own argument checks (`safety.checks`), not only by the tools' input schemas, which
  publish the same caps and so refuse first over MCP: a caller that reaches the Guard without a
  schema (the operator console, a future transport, a schema bug) is refused above the cap too.
- A camera is read only when the policy enables the `perception` tool group: without it no client
  is served `camera_snapshot`, and the Guard refuses any other caller (the console) the same way.
"""

from __future__ import annotations

from typing import Any

import pytest
from mcp.server.mcpserver import AcceptedElicitation

from armwarden.approval.decision import ServerDecision
from armwarden.core.errors import RefusalCode, SafetyRefusal
from tests.helpers import text_of
from tests.server.harness import answer, arm_harness, policy_with

pytestmark = pytest.mark.anyio


async def test_under_approval_mode_never_a_reset_still_asks_a_human_and_a_no_keeps_the_latch(tmp_path) -> None:
    human = answer("decline")
    async with arm_harness(tmp_path, policy_with(**{"approval.mode": "never"})) as arm, \
            arm.client("legacy", human) as client:
        latched = await client.call_tool("estop", {"reason": "test"})
        assert latched.structured_content["estopped"] is True

        result = await client.call_tool("reset_estop", {})

        assert len(human.prompts) == 1 and "e-stop" in human.prompts[0].lower(), human.prompts
        assert result.is_error and "[APPROVAL_DENIED]" in text_of(result), text_of(result)
        assert arm.guard.latch.is_latched


async def test_a_grasp_force_above_the_policy_cap_is_refused_by_the_guard_itself(tmp_path) -> None:
    """The policy caps the grasp at 40 N (the Hand is rated for 70 N); 50 N reaches the Guard
    directly, past any schema. Refused OUT_OF_RANGE, and the fingers get no command."""
    policy = policy_with(**{"gripper.max_grasp_force_n": 40.0})
    async with arm_harness(tmp_path, policy) as arm:
        with pytest.raises(SafetyRefusal) as refused:
            await arm.guard.gripper("gripper_grasp", width_m=0.02, force_n=50.0)

        assert refused.value.code is RefusalCode.OUT_OF_RANGE
        assert "force_n 50 must be in (0, 40] N" in str(refused.value)
        assert arm.actuations == []


async def test_collision_thresholds_above_the_policy_cap_are_refused_by_the_guard_itself(tmp_path) -> None:
    """Under `approval.mode: never` nobody is asked, so the argument check is all that stands
    between a 500 N threshold (the policy allows 30 N) and the robot's collision detection."""
    policy = policy_with(**{"approval.mode": "never"})
    no_human_needed = AcceptedElicitation[Any].model_construct(data=ServerDecision(True, "not_required"))  # as the SDK hands it over
    async with arm_harness(tmp_path, policy) as arm:
        with pytest.raises(SafetyRefusal) as refused:
            await arm.guard.run_action("set_collision_thresholds", no_human_needed, None, force_n=500.0, torque_nm=10.0)

        assert refused.value.code is RefusalCode.OUT_OF_RANGE
        assert "force_n 500 N must be in (0, 30] N" in str(refused.value)
        assert arm.actuations == []
        assert arm.fake.collision_thresholds is None


async def test_a_camera_read_with_the_perception_group_disabled_is_refused_by_the_guard_itself(tmp_path) -> None:
    """The policy still allowlists the cameras, but `camera_snapshot` is not served: a caller that
    reaches the Guard directly gets no picture either, and the backend is not asked for one."""
    policy = policy_with(**{"tools.enabled": ["introspect", "motion", "gripper", "control", "safety"]})
    async with arm_harness(tmp_path, policy) as arm:
        reads: list[str] = []
        cameras = arm.fake.cell.cameras
        assert cameras is not None
        original = cameras.snapshot

        async def counted(camera: str) -> Any:
            reads.append(camera)
            return await original(camera)

        cameras.snapshot = counted  # type: ignore[method-assign]
        with pytest.raises(SafetyRefusal) as refused:
            await arm.guard.camera("scene")

        assert refused.value.code is RefusalCode.NOT_ALLOWED
        assert "perception" in str(refused.value) and "tools.enabled" in str(refused.value)
        assert reads == []
