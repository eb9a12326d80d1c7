"""Contact from joint torques against physics: in MuJoCo, the arm moves down into a box the policy
does not know (no keep-out zone). The observer over the actuators' torques stops the motion,
latches the e-stop and the audit says why; the arm stops short of the plan, pressing far less than
it would have. And a motion that touches nothing is not stopped."""

from __future__ import annotations

from typing import Any

import pytest

from tests.helpers import records_of, text_of
from tests.server.harness import HOME_TCP_X, approve, arm_harness, policy_with

pytestmark = pytest.mark.anyio

JOINT_TORQUES = {"force.source": "joint_torques"}  # the MuJoCo cell has a sensor too: not this time
BOX_TOP_Z = 0.36
#: a rigid box under the hand (centre and full size [m]), welded to the world
BOX = {"name": "unknown_box", "shape": "box", "position_m": [HOME_TCP_X, 0.0, BOX_TOP_Z - 0.05],
       "size_m": [0.12, 0.12, 0.10], "mass_kg": 1.0, "fixed": True}


async def plan_down(client: Any, z: float) -> dict[str, Any]:
    result = await client.call_tool("plan_to_pose", {"position": {"x": HOME_TCP_X, "y": 0.0, "z": z}})
    assert not result.is_error, text_of(result)
    summary = result.structured_content
    assert summary["status"] == "ok" and summary["force_monitoring"] is True, summary
    return summary


async def test_moving_into_a_box_the_policy_does_not_know_stops_and_latches(tmp_path) -> None:
    policy = policy_with(**JOINT_TORQUES)
    async with arm_harness(tmp_path, policy, backend="mujoco", objects=[BOX]) as arm, \
            arm.client("legacy", approve()) as client:
        summary = await plan_down(client, z=0.25)  # the hand would end 11 cm inside the box

        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})

        assert result.is_error and "[FORCE_LIMIT]" in text_of(result), text_of(result)
        event = arm.guard.latch.current_event
        assert event is not None and event.source == "force_monitor"
        refusal = [r for r in records_of(arm.audit_path) if r["event"] == "tool_call"][-1]
        assert refusal["extra"]["code"] == "FORCE_LIMIT" and "estimated from the motors' torques" in refusal["detail"]
        tcp_z = arm.guard.robot.tcp_pose((await arm.inner.read_joint_state()).positions).position[2]
        assert tcp_z > 0.25 + 0.05  # stopped at the box, far short of the plan


async def test_a_motion_that_touches_nothing_is_not_stopped(tmp_path) -> None:
    policy = policy_with(**JOINT_TORQUES)
    async with arm_harness(tmp_path, policy, backend="mujoco") as arm, arm.client("legacy", approve()) as client:
        summary = await plan_down(client, z=0.30)

        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})

        assert not result.is_error, text_of(result)
        assert result.structured_content["status"] == "succeeded"
        assert not arm.guard.latch.is_latched
