"""A stop from another thread (the stop channel, SIGUSR1) that lands after the Guard's last check
of an action but before the backend receives it, or right after its latch check: the action must
not start, and a plan made across it is discarded. A stop while a human decides about an action
voids the approval. The arm's trajectory is covered in tests/scenarios/test_motion.py; here the
gripper, the control actions, planning and the approval."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import mcp_types as types
import pytest

from armwarden.safety import checks
from tests.helpers import READY, text_of
from tests.server.harness import approve, arm_harness, plan_down, policy_with

pytestmark = pytest.mark.anyio


def estop_from_another_thread(guard) -> None:
    """What the stop channel's thread does: latch and `stop_now`, off the event loop."""
    worker = threading.Thread(target=lambda: guard.stopper.latch_and_stop("channel", "stop_channel", lambda _work: None))
    worker.start()
    worker.join()


async def test_a_gripper_move_decided_before_a_channel_estop_does_not_start_after_it(tmp_path: Path, monkeypatch) -> None:
    async with arm_harness(tmp_path) as arm:
        original = checks.check_gripper

        def check_then_estop_elsewhere(*args, **kwargs):
            speed = original(*args, **kwargs)
            estop_from_another_thread(arm.guard)  # after the latch check, before the backend command
            return speed

        monkeypatch.setattr(checks, "check_gripper", check_then_estop_elsewhere)
        before = (await arm.inner.gripper_state()).width_m
        async with arm.client() as client:
            result = await client.call_tool("gripper_move", {"width_m": before / 2})
        assert arm.guard.latch.is_latched
        assert result.is_error and "STOPPED" in text_of(result), text_of(result)
        assert (await arm.inner.gripper_state()).width_m == pytest.approx(before)


@pytest.mark.parametrize(("tool", "arguments"), [
    ("switch_controllers", {"activate": [], "deactivate": ["fr3_arm_controller"]}),
    ("set_collision_thresholds", {"force_n": 20.0, "torque_nm": 10.0}),
])
async def test_a_control_action_decided_before_a_channel_estop_does_nothing(tmp_path: Path, monkeypatch, tool,
                                                                            arguments) -> None:
    policy = policy_with(**{"controllers.allowlist": ["fr3_arm_controller", "joint_impedance_controller"]})
    async with arm_harness(tmp_path, policy) as arm:
        interpret = arm.guard.state.interpret_approval

        def approve_then_estop_elsewhere(*args, **kwargs):
            approval = interpret(*args, **kwargs)
            estop_from_another_thread(arm.guard)  # after the latch check, before the backend command
            return approval

        monkeypatch.setattr(arm.guard.state, "interpret_approval", approve_then_estop_elsewhere)
        controllers_before = await arm.inner.list_controllers()
        async with arm.client("legacy", approve()) as client:
            result = await client.call_tool(tool, arguments)
        assert result.is_error and "STOPPED" in text_of(result), text_of(result)
        assert await arm.inner.list_controllers() == controllers_before
        assert arm.fake.collision_thresholds is None


def estop_right_after_the_latch_check(arm, monkeypatch, what: str) -> None:
    """The stop channel's thread latches in the gap right after the Guard's latch check for `what`."""
    original = arm.guard.state.require_not_estopped
    fired: list[bool] = []

    def check_then_estop_elsewhere(checked: str) -> None:
        original(checked)
        if checked == what and not fired:
            fired.append(True)
            estop_from_another_thread(arm.guard)

    monkeypatch.setattr(arm.guard.state, "require_not_estopped", check_then_estop_elsewhere)


async def test_a_gripper_move_whose_latch_check_a_channel_estop_just_missed_does_not_start(tmp_path: Path,
                                                                                           monkeypatch) -> None:
    async with arm_harness(tmp_path) as arm:
        estop_right_after_the_latch_check(arm, monkeypatch, "gripper_move")
        before = (await arm.inner.gripper_state()).width_m
        async with arm.client() as client:
            result = await client.call_tool("gripper_move", {"width_m": before / 2})
        assert arm.guard.latch.is_latched and result.is_error, text_of(result)
        assert (await arm.inner.gripper_state()).width_m == pytest.approx(before)


async def test_a_control_action_whose_latch_check_a_channel_estop_just_missed_does_nothing(tmp_path: Path,
                                                                                           monkeypatch) -> None:
    async with arm_harness(tmp_path) as arm:
        estop_right_after_the_latch_check(arm, monkeypatch, "set_collision_thresholds")
        async with arm.client("legacy", approve()) as client:
            result = await client.call_tool("set_collision_thresholds", {"force_n": 20.0, "torque_nm": 10.0})
        assert arm.guard.latch.is_latched and result.is_error, text_of(result)
        assert arm.fake.collision_thresholds is None


async def test_a_plan_made_across_a_channel_estop_is_discarded(tmp_path: Path, monkeypatch) -> None:
    """Nothing planned before an e-stop may survive its reset."""
    async with arm_harness(tmp_path) as arm:
        estop_right_after_the_latch_check(arm, monkeypatch, "planning")
        async with arm.client("legacy", approve()) as client:
            result = await client.call_tool("plan_to_joints", {"joint_positions": list(READY + 0.1), "preview": False})
        assert arm.guard.latch.is_latched
        assert result.is_error and "ESTOPPED" in text_of(result), text_of(result)


def approving_after(action):
    """An operator who approves, but only after `action` (another client's call) has run."""
    async def callback(context: Any, params: types.ElicitRequestParams) -> types.ElicitResult:
        await action()
        return types.ElicitResult(action="accept", content={"approve": True, "operator": "alice"})
    return callback


async def test_a_stop_while_a_human_decides_voids_the_approval_of_the_motion(tmp_path: Path) -> None:
    policy = policy_with(**{"approval.mode": "always"})
    async with arm_harness(tmp_path, policy) as arm, arm.client("legacy") as other:
        async def stop() -> None:
            assert not (await other.call_tool("stop_motion", {})).is_error

        async with arm.client("legacy", approving_after(stop)) as client:
            summary = await plan_down(client, z=0.40)
            result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
        assert result.is_error and "STOPPED" in text_of(result) and "while a human was deciding" in text_of(result)
        assert arm.actuations == []


async def test_a_stop_while_a_human_decides_voids_the_approval_of_a_control_action(tmp_path: Path) -> None:
    async with arm_harness(tmp_path) as arm, arm.client("legacy") as other:
        async def stop() -> None:
            assert not (await other.call_tool("stop_motion", {})).is_error

        async with arm.client("legacy", approving_after(stop)) as client:
            result = await client.call_tool("set_collision_thresholds", {"force_n": 20.0, "torque_nm": 10.0})
        assert result.is_error, text_of(result)
        assert arm.fake.collision_thresholds is None
