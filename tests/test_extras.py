"""`serve` names, at start-up, every feature an absent optional dependency removes (issue 31,
item 4: an install without Pillow silently lost camera_snapshot and every preview picture)."""

from __future__ import annotations

import logging
import subprocess
import sys
from pathlib import Path

import pytest

from armwarden import extras
from tests.helpers import CLI, REPO, SRC, child_env
from tests.server.harness import arm_harness

#: a sitecustomize that makes `PIL` unimportable and unfindable, as on an install without Pillow
#: (`importlib.util.find_spec("PIL")` is None, `import PIL` raises ModuleNotFoundError)
REFUSE_PIL = """import sys

sys.modules["PIL"] = None
"""


def serve_until_stdin_ends(tmp_path: Path, site: Path | None = None) -> subprocess.CompletedProcess[str]:
    """`armwarden serve` over stdio with stdin at its end: it starts, logs, and exits."""
    env = child_env()
    if site is not None:
        env["PYTHONPATH"] = f"{site}:{SRC}"
    return subprocess.run([*CLI, "serve", "--audit-log", str(tmp_path / "audit.jsonl")], cwd=REPO, env=env,
                          stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=120)


def test_without_pillow_serve_warns_naming_every_tool_that_loses_its_pictures(tmp_path: Path) -> None:
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(REFUSE_PIL, encoding="utf-8")
    result = serve_until_stdin_ends(tmp_path, site)
    assert result.returncode == 0, result.stderr
    warnings = [line for line in result.stderr.splitlines() if " WARNING " in line and "Pillow missing" in line]
    assert len(warnings) == 1, result.stderr
    for tool in ("camera_snapshot", "plan_to_joints", "plan_to_pose", "plan_cartesian_path"):
        assert tool in warnings[0], tool
    assert "pip install pillow" in warnings[0]


def test_with_every_dependency_there_serve_says_so_in_one_info_line(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(extras, "why_missing", lambda dependency: None)
    assert extras.feature_lines() == [(logging.INFO, extras.ALL_AVAILABLE)]


@pytest.mark.parametrize(("module", "feature"), [("mujoco", "the mujoco backend"), ("can", "the can backend"),
                                                 ("rclpy", "the ros2 backend")])
def test_a_missing_backend_dependency_is_one_info_line_naming_the_backend(monkeypatch, module: str, feature: str) -> None:
    monkeypatch.setitem(sys.modules, module, None)  # as if it were not installed
    lines = [message for level, message in extras.feature_lines() if feature in message]
    assert len(lines) == 1 and f"{feature} is unavailable" in lines[0]
    assert all(level == logging.INFO for level, message in extras.feature_lines() if feature in message)


def test_only_the_picture_tools_the_policy_enables_are_named(monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "PIL.Image", None)
    (level, line), = [entry for entry in extras.feature_lines({"plan_to_pose", "get_state"}) if "Pillow" in entry[1]]
    assert level == logging.WARNING and "plan_to_pose" in line
    assert "camera_snapshot" not in line and "plan_to_joints" not in line


@pytest.mark.anyio
async def test_the_picture_tools_are_the_plan_tools_with_a_preview_and_camera_snapshot(tmp_path: Path) -> None:
    async with arm_harness(tmp_path) as arm, arm.client() as client:
        tools = (await client.list_tools()).tools
    drawing = {tool.name for tool in tools if "preview" in (tool.input_schema.get("properties") or {})}
    assert "camera_snapshot" in {tool.name for tool in tools}
    assert set(extras.PICTURE_TOOLS) == drawing | {"camera_snapshot"}


def test_a_missing_ros_stack_points_to_the_ros_venv_not_into_this_one():
    """The ROS wheels live in .venv-ros, a venv of their own (README): the hint must not send the
    user to install them beside this venv's Pinocchio and MuJoCo, nor to a test README."""
    ros = next(d for d in extras.DEPENDENCIES if "rclpy" in d.modules)
    assert "--backend ros2" in ros.install and ".venv-ros" in ros.install
    assert "pip install" not in ros.install and "tests_ros" not in ros.install
