"""Watching a cell in another process through ROS alone: its joint states (`RosClient`) and the
goal status topic of its FollowJointTrajectory action server.

Every action server publishes `action_msgs/GoalStatusArray` on `<action>/_action/status`
(reliable, transient local) with the status of each goal it still keeps, so a test can tell
from outside which goals reached the cell and how each one ended (succeeded, canceled, aborted)
without asking the cell's own counters.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence

import numpy as np
from action_msgs.msg import GoalStatus, GoalStatusArray
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from tests_ros.cell import CellConfig
from tests_ros.client import DISCOVERY_TIMEOUT_S, RosClient, eventually

#: `GoalStatus` codes by name, for messages
STATUS_NAMES = {
    GoalStatus.STATUS_UNKNOWN: "unknown", GoalStatus.STATUS_ACCEPTED: "accepted",
    GoalStatus.STATUS_EXECUTING: "executing", GoalStatus.STATUS_CANCELING: "canceling",
    GoalStatus.STATUS_SUCCEEDED: "succeeded", GoalStatus.STATUS_CANCELED: "canceled",
    GoalStatus.STATUS_ABORTED: "aborted",
}
#: the action server's status topic QoS (rcl_action's default for status)
STATUS_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


class CellWatch(RosClient):
    """A `RosClient` that also follows the trajectory action's goal statuses."""

    def __init__(self, config: CellConfig | None = None) -> None:
        super().__init__(config or CellConfig())
        self._status_lock = threading.Lock()
        self._goals: dict[bytes, int] = {}  # goal id -> latest status, in the order first seen

    def start(self) -> CellWatch:
        super().start()
        topic = f"{self.config.trajectory_action}/_action/status"
        self.node.create_subscription(GoalStatusArray, topic, self._on_status, STATUS_QOS)
        return self

    def _on_status(self, message: GoalStatusArray) -> None:
        with self._status_lock:
            for status in message.status_list:
                self._goals[bytes(status.goal_info.goal_id.uuid)] = status.status

    def goal_statuses(self) -> list[str]:
        """The latest status of every goal the cell's action server has reported, oldest first."""
        with self._status_lock:
            return [STATUS_NAMES.get(code, str(code)) for code in self._goals.values()]

    def wait_for_goals(self, *expected: str, timeout: float = DISCOVERY_TIMEOUT_S) -> list[str]:
        """Wait until the goal statuses are exactly `expected` (e.g. "succeeded", "canceled");
        fail naming what the cell reported instead."""
        try:
            return eventually(lambda: (seen := self.goal_statuses()) == list(expected) and seen, timeout,
                              f"goal statuses {list(expected)}")
        except TimeoutError as exc:
            raise AssertionError(f"the cell's goals are {self.goal_statuses()}, not {list(expected)}") from exc

    def wait_still(self, settle_s: float = 0.2, timeout: float = DISCOVERY_TIMEOUT_S) -> list[float]:
        """Wait until two joint states `settle_s` apart are equal (the cell holds exactly); the positions."""
        deadline = time.monotonic() + timeout
        while True:
            first = self.positions()
            time.sleep(settle_s)
            second = self.positions()
            if np.array_equal(first, second):
                return second
            assert time.monotonic() < deadline, f"the cell still moves after {timeout} s: {first} -> {second}"

    def wait_at(self, goal: Sequence[float], tolerance: float, timeout: float = DISCOVERY_TIMEOUT_S) -> list[float]:
        """Wait until the cell's joint state is within `tolerance` [rad] of `goal`; the positions."""

        def at_goal() -> list[float] | None:
            q = self.positions()
            return q if np.allclose(q, goal, atol=tolerance, rtol=0) else None

        return eventually(at_goal, timeout, f"joint state at {list(goal)}")
