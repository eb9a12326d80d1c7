"""An arm the project has never seen goes from its URDF to an executed motion with no manual step:
`armwarden init`, then `armwarden serve` on the policy it wrote, driven by the MCP SDK over stdio."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from mcp import Client, StdioServerParameters

from tests.helpers import REPO, SRC
from tests.onboarding.conftest import init_arm
from tests.onboarding.moves import nudged_home, plan_and_execute
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
    home = run.result.runtime.policy.robot.home_joint_positions
    async with Client(params, elicitation_callback=approve()) as client:
        state = (await client.call_tool("get_robot_state", {})).structured_content
        assert state["joint_positions"] == pytest.approx(list(home), abs=2e-3)
        await plan_and_execute(client, nudged_home(home, delta_rad=0.2), tolerance_rad=2e-3)
