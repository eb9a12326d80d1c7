"""The MuJoCo cell driven through the tools, as an agent drives it: the SDK client against the real
Guard and server (`arm_harness`) on the physics backend. What is checked is measured in the
simulation — where the arm ended, how far it strayed from its trajectory, how deep the hand went
into the table, whether the box rose — never what the backend was told."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

import armwarden.backends.mujoco  # noqa: F401 - chooses the offscreen GL platform before mujoco loads

pytest.importorskip("mujoco")

from mcp import Client
from PIL import Image

from armwarden.backends.mujoco.backend import MujocoBackend
from armwarden.policy.motion import MAX_WRENCH_TIMEOUT_S
from tests.backends.test_mujoco_backend import published_position
from tests.helpers import text_of
from tests.scenarios.steps import READY, assert_still, calls, execute, plan, plan_joints
from tests.server.harness import ArmHarness, approve, arm_harness, policy_with

pytestmark = pytest.mark.anyio

EXAMPLE_SCENE = Path(__file__).resolve().parents[2] / "examples" / "mujoco_scene.yaml"
#: the issue's bar: every move ends this close to its planned goal [rad]
GOAL_ERROR_RAD = 2e-3
#: how far out the hand reaches 3 cm below the table top, pointing down (closer to the base the
#: bundled FR3's capsules keep the wrist from folding that far)
BELOW_TABLE_X_M = 0.66
#: a loaded host can stall the physics thread past the bundled 0.1 s wrench age, which rightly aborts
#: a motion (NO_WRENCH; tests/safety prove it); these tests are about what physics does, so they
#: allow the longest age the policy schema takes. The force limit itself is unchanged.
STALL_TOLERANT = {"force.wrench_timeout_s": MAX_WRENCH_TIMEOUT_S}


def mujoco_of(arm: ArmHarness) -> MujocoBackend:
    assert isinstance(arm.inner, MujocoBackend)
    return arm.inner


async def move_tcp_to(client: Client, x: float, z: float) -> dict[str, Any]:
    """A straight TCP line to (x, 0, z), hand pointing down as it is; executed; the report."""
    summary = await plan(client, "plan_cartesian_path",
                         {"waypoints": [{"position": {"x": x, "y": 0.0, "z": z}}], "velocity_scaling": 0.3})
    assert summary["status"] in ("ok", "needs_approval"), summary
    result = await execute(client, summary["plan_id"])
    assert not result.is_error, text_of(result)
    return result.structured_content


async def test_thirty_random_safe_moves_end_within_2_mrad_of_their_goal(tmp_path: Path, record_property) -> None:
    rng = np.random.default_rng(20261123)
    final_errors: list[float] = []
    tracking_errors: list[float] = []
    # thirty executions in well under a minute: above the bundled policy's rate limits. What this
    # measures is accuracy, so a stalled physics thread must not abort a move (STALL_TOLERANT).
    busy = policy_with(**{"rate_limits.global_per_minute": 600, "rate_limits.default_per_minute": 300,
                          "rate_limits.per_tool.execute_plan": 100, "rate_limits.per_tool.plan_to_joints": 300,
                          **STALL_TOLERANT})
    async with arm_harness(tmp_path, busy, backend="mujoco") as arm, arm.client(elicitation=approve()) as client:
        attempts = 0
        while len(final_errors) < 30:
            attempts += 1
            assert attempts < 90, "too few random targets passed the envelope"
            goal = (np.asarray(READY) + rng.uniform(-0.3, 0.3, size=len(READY))).tolist()
            summary = await plan(client, "plan_to_joints", {"joint_positions": goal, "velocity_scaling": 0.3})
            if summary["status"] == "rejected":
                continue  # unsafe target: the envelope refused it, nothing to execute
            result = await execute(client, summary["plan_id"])
            assert not result.is_error, text_of(result)
            report = result.structured_content
            assert report["status"] == "succeeded", report
            measured = (await client.call_tool("get_robot_state", {})).structured_content["joint_positions"]
            assert measured == pytest.approx(goal, abs=GOAL_ERROR_RAD)
            final_errors.append(report["final_joint_error_rad"])
            tracking_errors.append(report["max_tracking_error_rad"])
    record_property("final_joint_error_rad_max", max(final_errors))
    record_property("max_tracking_error_rad_max", max(tracking_errors))
    print(f"30 random moves: final joint error max {max(final_errors) * 1e3:.3f} mrad, "
          f"mean {np.mean(final_errors) * 1e3:.3f} mrad; tracking error max {max(tracking_errors) * 1e3:.3f} mrad")
    assert max(final_errors) <= GOAL_ERROR_RAD
    assert 0.0 < max(tracking_errors) < 0.05  # measured, not assumed: a physical arm lags a little


async def test_a_move_down_into_the_table_is_aborted_by_the_force_monitor_from_physics(tmp_path: Path) -> None:
    # The policy believes the floor is 10 cm lower than the real table (a misconfigured cell): the
    # envelope lets the plan through, the table stops the hand, and only contact physics is left to
    # trip the force limit.
    policy = policy_with(**{"workspace.box.min": [-0.45, -0.70, -0.10], **STALL_TOLERANT})
    async with arm_harness(tmp_path, policy, backend="mujoco", speedup=1.0, table_top_z_m=0.0) as arm, \
            arm.client(elicitation=approve()) as client:
        cell = mujoco_of(arm)
        await move_tcp_to(client, BELOW_TABLE_X_M, 0.15)
        cell.arm.peak_robot_penetration_m = 0.0
        summary = await plan(client, "plan_cartesian_path",
                             {"waypoints": [{"position": {"x": BELOW_TABLE_X_M, "y": 0.0, "z": -0.03}}], "velocity_scaling": 0.1})
        assert summary["status"] == "ok", summary
        result = await execute(client, summary["plan_id"])
        assert result.is_error and "REFUSED [FORCE_LIMIT]" in text_of(result), text_of(result)
        safety = (await client.call_tool("get_safety_status", {})).structured_content
        assert safety["estopped"] and safety["estop_event"]["source"] == "force_monitor"
        await assert_still(arm, client)  # the arm comes to rest where the stop held it
        state = (await client.call_tool("get_robot_state", {})).structured_content
        assert state["tcp_pose"]["position"]["z"] > -0.03 + 0.02  # far short of the planned depth
        assert cell.arm.peak_robot_penetration_m < 0.005  # into the table by less than 5 mm
        forces = [r for r in calls(arm, "execute_plan") if (r["extra"] or {}).get("code") == "FORCE_LIMIT"]
        assert len(forces) == 1


async def test_the_example_box_is_grasped_by_friction_and_lifted_5_cm_with_a_plan(tmp_path: Path) -> None:
    scene = yaml.safe_load(EXAMPLE_SCENE.read_text(encoding="utf-8"))
    box_x, box_y, box_z = scene["objects"][0]["position_m"]
    async with arm_harness(tmp_path, policy_with(**STALL_TOLERANT), backend="mujoco", **{**scene, "speedup": 4.0}) as arm, \
            arm.client(elicitation=approve()) as client:
        cell = mujoco_of(arm)
        await move_tcp_to(client, box_x, 0.15)
        await move_tcp_to(client, box_x, box_z + 0.01)  # fingers around the box, above the table
        grasp = (await client.call_tool("gripper_grasp", {"width_m": 0.04, "force_n": 20.0})).structured_content
        assert grasp["status"] == "succeeded" and grasp["is_grasped"], grasp
        resting_z = published_position(cell, "box")[2]
        await move_tcp_to(client, box_x, box_z + 0.06)
        lifted = published_position(cell, "box")
        assert lifted[2] - resting_z == pytest.approx(0.05, abs=0.005)  # it came along: contact and friction only
        assert abs(lifted[0] - box_x) < 0.01 and abs(lifted[1] - box_y) < 0.01


@pytest.mark.parametrize(("arguments", "field"), [
    ({"width_m": 0.04, "force_n": 80.0}, "force"),
    ({"width_m": 0.09, "force_n": 20.0}, "width"),
])
async def test_a_grasp_over_the_policy_caps_is_refused_and_the_fingers_do_not_move(tmp_path: Path, arguments, field) -> None:
    async with arm_harness(tmp_path, backend="mujoco") as arm, arm.client() as client:
        before = (await client.call_tool("get_robot_state", {})).structured_content["gripper"]
        result = await client.call_tool("gripper_grasp", arguments)
        assert result.is_error and field in text_of(result).lower(), text_of(result)
        assert arm.actuations == []
        after = (await client.call_tool("get_robot_state", {})).structured_content["gripper"]
        assert after["width_m"] == pytest.approx(before["width_m"], abs=1e-4)
        assert calls(arm, "gripper_grasp")[-1]["outcome"] in ("refused", "invalid")


def pixels(result: Any) -> np.ndarray:
    images = [block for block in result.content if getattr(block, "type", "") == "image"]
    assert len(images) == 1 and images[0].mime_type == "image/png"
    import base64

    return np.asarray(Image.open(io.BytesIO(base64.b64decode(images[0].data))).convert("RGB"), dtype=float)


async def test_a_camera_snapshot_changes_when_the_arm_moves_and_the_audit_log_keeps_no_image(tmp_path: Path) -> None:
    async with arm_harness(tmp_path, policy_with(**STALL_TOLERANT), backend="mujoco") as arm, \
            arm.client(elicitation=approve()) as client:
        before = await client.call_tool("camera_snapshot", {"camera": "scene"})
        assert not before.is_error, text_of(before)
        first = pixels(before)
        assert first.shape[1] <= 640 and first.std() > 10.0  # a rendered scene, not a cleared buffer
        summary = await plan_joints(client, [READY[0] + 0.8, *READY[1:]], velocity_scaling=0.3)
        assert (await execute(client, summary["plan_id"])).structured_content["status"] == "succeeded"
        second = pixels(await client.call_tool("camera_snapshot", {"camera": "scene"}))
        changed = np.abs(second - first).max(axis=2) > 30.0
        assert changed.mean() > 0.01  # over 1 % of the pixels changed clearly
    audit = arm.audit_path.read_bytes()
    assert len(calls(arm, "camera_snapshot")) == 2
    assert b"iVBORw0KGgo" not in audit and b"\x89PNG" not in audit  # no PNG, raw or base64


async def test_a_wide_render_is_downscaled_to_the_policy_image_width(tmp_path: Path) -> None:
    async with arm_harness(tmp_path, backend="mujoco", camera_width_px=1280, camera_height_px=960) as arm, \
            arm.client() as client:
        result = await client.call_tool("camera_snapshot", {"camera": "wrist"})
        assert not result.is_error, text_of(result)
        assert result.structured_content["width"] == 640 and pixels(result).shape[:2] == (480, 640)
        assert arm.actuations == []
