"""`armwarden serve --backend mujoco --backend-config examples/mujoco_scene.yaml` as a real
subprocess, driven by the SDK client over stdio and over streamable HTTP: the example scene in real
time, a planned and approved move measured by the physics, a rendered camera image."""

from __future__ import annotations

import base64
import io
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcp import Client, StdioServerParameters

pytest.importorskip("mujoco")

from PIL import Image

from tests.helpers import HOME, REPO, SRC, text_of
from tests.server.harness import approve
from tests.server.http_daemon import http_daemon, session

pytestmark = pytest.mark.anyio

EXAMPLE_SCENE = REPO / "examples" / "mujoco_scene.yaml"
#: the move both transports run: joint 1 by 0.3 rad, at the bundled policy's default speed
GOAL = [HOME[0] + 0.3, *HOME[1:]]


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


async def drive_the_example_cell(client: Client) -> None:
    """What an agent does first: list, look, plan, execute; everything measured by the physics."""
    tools = {tool.name for tool in (await client.list_tools()).tools}
    assert {"camera_snapshot", "gripper_grasp", "plan_to_pose", "execute_plan", "estop"} <= tools
    state = (await client.call_tool("get_robot_state", {})).structured_content
    assert state["joint_positions"] == pytest.approx(HOME, abs=2e-3)
    assert state["gripper"]["width_m"] == pytest.approx(0.08, abs=1e-3)

    image = await client.call_tool("camera_snapshot", {"camera": "scene"})
    assert not image.is_error, text_of(image)
    blocks = [block for block in image.content if getattr(block, "type", "") == "image"]
    pixels = np.asarray(Image.open(io.BytesIO(base64.b64decode(blocks[0].data))).convert("RGB"), dtype=float)
    assert pixels.shape == (480, 640, 3) and pixels.std() > 10.0

    plan = await client.call_tool("plan_to_joints", {"joint_positions": GOAL, "preview": False})
    assert plan.structured_content["status"] in ("ok", "needs_approval"), plan.structured_content
    done = await client.call_tool("execute_plan", {"plan_id": plan.structured_content["plan_id"]})
    assert not done.is_error, text_of(done)
    report: dict[str, Any] = done.structured_content
    assert report["status"] == "succeeded" and report["final_joint_error_rad"] <= 2e-3
    assert report["max_tracking_error_rad"] > 0.0  # a physical arm, measured
    after = (await client.call_tool("get_robot_state", {})).structured_content
    assert after["joint_positions"] == pytest.approx(GOAL, abs=2e-3)


async def test_the_example_scene_serves_over_stdio(tmp_path: Path) -> None:
    params = StdioServerParameters(
        command=sys.executable,
        args=["-m", "armwarden.cli", "serve", "--backend", "mujoco", "--backend-config", str(EXAMPLE_SCENE),
              "--audit-log", str(tmp_path / "audit.jsonl"), "--log-level", "WARNING"],
        env={"PYTHONPATH": str(SRC)},
        cwd=str(REPO),
    )
    async with Client(params, elicitation_callback=approve()) as client:
        await drive_the_example_cell(client)


async def test_the_example_scene_serves_over_http(tmp_path: Path) -> None:
    with http_daemon(tmp_path, speedup=1.0, backend="mujoco", config=EXAMPLE_SCENE) as daemon:
        http, client = session(daemon, daemon.operator_token, "legacy", approve())
        async with http, client:
            await drive_the_example_cell(client)
