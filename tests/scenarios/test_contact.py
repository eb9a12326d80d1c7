"""Contact from the motors' joint torques, on every backend that measures them: a push of 30 N on
the forearm mid-motion stops the arm and latches the e-stop, with the joint that saw it on record;
and the same motion with nothing touching the arm runs to its goal."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from tests.helpers import records_of, text_of
from tests.server.harness import HOME_TCP_X, ArmHarness, approve

pytestmark = [pytest.mark.anyio, pytest.mark.needs("joint_torques"),
              pytest.mark.policy(**{"force.source": "joint_torques"})]

#: the forearm link (its frame sits at the wrist end, on joint 5's axis) and a push across it
FOREARM = "fr3_link5"
PUSH_N = (0.0, 30.0, 0.0)


async def plan_down(client: Any) -> dict[str, Any]:
    result = await client.call_tool("plan_to_pose", {"position": {"x": HOME_TCP_X, "y": 0.0, "z": 0.34}})
    assert not result.is_error, text_of(result)
    summary = result.structured_content
    assert summary["status"] == "ok" and summary["force_monitoring"] is True, summary
    return summary


def push_once_past(arm: ArmHarness, fraction: float) -> None:
    """Push on the forearm from the first progress report past `fraction` of the motion (it stays:
    the monitor's last sample after the motion sees it even if the motion ended first)."""
    backend = arm.inner
    execute = backend.execute
    pushed = False

    async def execute_and_push(trajectory: Any, progress: Callable[[float], None], **kwargs: Any) -> Any:
        def on_progress(done: float) -> None:
            nonlocal pushed
            if done >= fraction and not pushed:
                pushed = True
                arm.push(FOREARM, PUSH_N)
            progress(done)
        return await execute(trajectory, on_progress, **kwargs)

    backend.execute = execute_and_push  # type: ignore[method-assign]


async def test_a_push_on_the_forearm_mid_motion_stops_the_arm_and_latches_the_estop(arm: ArmHarness) -> None:
    async with arm.client("legacy", approve()) as client:
        summary = await plan_down(client)
        push_once_past(arm, 0.3)

        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})

        assert result.is_error and "[FORCE_LIMIT]" in text_of(result), text_of(result)
        event = arm.guard.latch.current_event
        assert event is not None and event.source == "force_monitor"
        assert event.force_violation is not None and event.force_violation["kind"] == "joint_torque_limit"
        refusal = [r for r in records_of(arm.audit_path) if r["event"] == "tool_call" and r["tool"] == "execute_plan"]
        assert "estimated from the motors' torques" in refusal[-1]["detail"]


async def test_the_same_motion_with_nothing_touching_the_arm_runs_to_its_goal(arm: ArmHarness) -> None:
    async with arm.client("legacy", approve()) as client:
        summary = await plan_down(client)

        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})

        assert not result.is_error, text_of(result)
        assert result.structured_content["status"] == "succeeded"
