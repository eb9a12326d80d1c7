"""An arm the project has never seen goes from its URDF to an executed motion with no manual step:
`armwarden init`, then `armwarden serve` on the policy it wrote, driven by the MCP SDK over stdio."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from mcp import Client, StdioServerParameters

from tests.helpers import REPO, SRC, text_of
from tests.onboarding.conftest import init_arm
from tests.server.harness import approve

pytestmark = pytest.mark.anyio


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


@pytest.mark.parametrize("n_joints", [4, 7])
async def test_a_generated_arm_plans_and_executes_a_small_move_after_init(tmp_path: Path, n_joints: int) -> None:
    run = init_arm(tmp_path, seed=100 + n_joints, n_joints=n_joints)
    config = tmp_path / "fake.yaml"
    config.write_text("speedup: 10\n", encoding="utf-8")
    params = StdioServerParameters(
        command=sys.executable,
        args=["-m", "armwarden.cli", "serve", "--policy", str(run.options.output), "--backend-config", str(config),
              "--audit-log", str(tmp_path / "audit.jsonl"), "--log-level", "WARNING"],
        env={"PYTHONPATH": str(SRC)}, cwd=str(REPO))
    home = np.array(run.result.runtime.policy.robot.home_joint_positions)
    goal = home.copy()
    goal[0] += 0.2
    async with Client(params, elicitation_callback=approve()) as client:
        state = (await client.call_tool("get_robot_state", {})).structured_content
        assert state["joint_positions"] == pytest.approx(home.tolist(), abs=2e-3)
        plan = await client.call_tool("plan_to_joints", {"joint_positions": goal.tolist(), "preview": False})
        assert plan.structured_content["status"] == "ok", plan.structured_content
        done = await client.call_tool("execute_plan", {"plan_id": plan.structured_content["plan_id"]})
        assert not done.is_error and done.structured_content["status"] == "succeeded", text_of(done)
        after = (await client.call_tool("get_robot_state", {})).structured_content
        assert after["joint_positions"] == pytest.approx(goal.tolist(), abs=2e-3)
