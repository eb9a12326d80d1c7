"""A stop from another thread (the stop channel, SIGUSR1) that lands after the Guard's last check
of an action but before the backend receives it: the action must not start. The arm's trajectory
is covered in tests/scenarios/test_motion.py; here the gripper and the control actions."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from armwarden.safety import checks
from tests.helpers import text_of
from tests.server.harness import approve, arm_harness, policy_with

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
        interpret = arm.guard.interpret_approval

        def approve_then_estop_elsewhere(*args, **kwargs):
            approval = interpret(*args, **kwargs)
            estop_from_another_thread(arm.guard)  # after the latch check, before the backend command
            return approval

        monkeypatch.setattr(arm.guard, "interpret_approval", approve_then_estop_elsewhere)
        controllers_before = await arm.inner.list_controllers()
        async with arm.client("legacy", approve()) as client:
            result = await client.call_tool(tool, arguments)
        assert result.is_error and "STOPPED" in text_of(result), text_of(result)
        assert await arm.inner.list_controllers() == controllers_before
        assert arm.fake.collision_thresholds is None
