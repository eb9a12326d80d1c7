"""The first move an agent makes on a new arm, through any MCP client: plan a joint goal, expect it
accepted, execute it, and find the arm there."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from tests.helpers import text_of


def nudged_home(home: Any, joint: int = 0, delta_rad: float = 0.15) -> np.ndarray:
    goal = np.array(home, dtype=float)
    goal[joint] += delta_rad
    return goal


async def plan_and_execute(client: Any, goal: np.ndarray, tolerance_rad: float) -> None:
    plan = await client.call_tool("plan_to_joints", {"joint_positions": goal.tolist(), "preview": False})
    assert plan.structured_content["status"] == "ok", plan.structured_content
    done = await client.call_tool("execute_plan", {"plan_id": plan.structured_content["plan_id"]})
    assert not done.is_error and done.structured_content["status"] == "succeeded", text_of(done)
    after = (await client.call_tool("get_robot_state", {})).structured_content
    assert after["joint_positions"] == pytest.approx(goal.tolist(), abs=tolerance_rad)
