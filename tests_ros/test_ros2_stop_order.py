"""A stop reaches the gripper even when the arm's half of it fails (the hold cannot be published).

Unit level: the backend is built but not opened; its endpoints are stand-ins, so the test needs no
cell. Found by review: the arm's stop ran first and an exception from it skipped the gripper's."""

from __future__ import annotations

import time
from types import SimpleNamespace

import pytest

from armwarden.backends.ros2.runs import GripperRun, TopicRun, new_goal_id
from tests_ros.backend_setup import build_backend


class _BrokenPublisher:
    def publish(self, msg: object) -> None:
        raise RuntimeError("injected: rcl publisher invalid (context shut down)")


class _GoalHandle:
    def __init__(self) -> None:
        self.cancels = 0

    def cancel_goal_async(self) -> None:
        self.cancels += 1


def test_a_stop_whose_arm_hold_fails_still_cancels_the_gripper_goal() -> None:
    backend = build_backend()
    assert backend.cell.gripper is not None
    backend._endpoints.trajectory_topic = _BrokenPublisher()  # the hold goes out on the topic: it fails
    backend._endpoints.gripper_action = object()
    backend.arm.run = TopicRun(0, 1.0, time.monotonic())
    backend.arm.joint_states.latest_with_age = lambda: (SimpleNamespace(positions=[0.0] * 7), 0.0)
    handle = _GoalHandle()
    backend.cell.gripper.run = GripperRun(new_goal_id(), 0, handle=handle)  # type: ignore[attr-defined]
    with pytest.raises(RuntimeError, match="publisher invalid"):
        backend._stop_now()
    assert handle.cancels == 1
