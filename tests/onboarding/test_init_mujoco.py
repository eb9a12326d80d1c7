"""An arm the project has never seen, URDF or MJCF, from `armwarden init` straight into the MuJoCo
backend: it serves with a scene camera of its own, and a planned move executes in the physics."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("armwarden.backends.mujoco")  # it chooses the OpenGL platform before mujoco loads

from armwarden.onboarding import InitOptions, run_init
from armwarden.policy import Policy, load_policy
from tests.helpers import text_of
from tests.onboarding.conftest import QUICK_FIT, init_arm
from tests.onboarding.moves import nudged_home, plan_and_execute
from tests.robot.generated_arm import write_mjcf_twin, write_random_arm
from tests.server.harness import approve, arm_harness

pytestmark = pytest.mark.anyio


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


@pytest.mark.parametrize("gripper", [False, True], ids=["arm", "arm with fingers"])
async def test_a_generated_arm_serves_in_mujoco_and_executes_a_planned_move(tmp_path: Path, gripper: bool) -> None:
    run = init_arm(tmp_path, seed=40 + gripper, n_joints=6, gripper=gripper)
    await serve_in_mujoco(load_policy(run.options.output), tmp_path, gripper=gripper)


async def test_an_mjcf_arm_serves_in_mujoco_and_executes_a_planned_move(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path / "urdf", seed=43, n_joints=5)
    options = InitOptions(description=write_mjcf_twin(arm, tmp_path / "mjcf"), output=tmp_path / "policy" / "arm.yaml",
                          fit=QUICK_FIT)
    run_init(options)
    await serve_in_mujoco(load_policy(options.output), tmp_path, gripper=False)


async def serve_in_mujoco(policy: Policy, tmp_path: Path, *, gripper: bool) -> None:
    """Home as the policy says, a camera picture, a planned move executed in the physics, and the fingers."""
    home = policy.robot.home_joint_positions
    async with arm_harness(tmp_path, policy, backend="mujoco") as arm, arm.client("legacy", approve()) as client:
        state = (await client.call_tool("get_robot_state", {})).structured_content
        assert state["joint_positions"] == pytest.approx(list(home), abs=5e-3)
        image = await client.call_tool("camera_snapshot", {"camera": "scene"})
        assert not image.is_error, text_of(image)
        await plan_and_execute(client, nudged_home(home), tolerance_rad=5e-3)
        if gripper:  # the fingers are found from the description, not by any robot's names
            moved = await client.call_tool("gripper_move", {"width_m": 0.03})
            assert not moved.is_error, text_of(moved)
            width = (await client.call_tool("get_robot_state", {})).structured_content["gripper"]["width_m"]
            assert width == pytest.approx(0.03, abs=2e-3)
