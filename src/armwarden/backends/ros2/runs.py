"""What the ROS 2 backend sends and keeps track of: the trajectory and hold messages, one record
per goal or published trajectory in flight and the stops it carried out.

The run records are written under the backend's motion lock (event loop, stopping threads) and by
rclpy callbacks on the executor thread; see `armwarden.backends.ros2.backend`.
"""

from __future__ import annotations

import time
import uuid
from dataclasses import dataclass
from typing import Any

import numpy as np
import rclpy.action.client
import rclpy.client
import rclpy.publisher
import rclpy.subscription
import rclpy.timer
from trajectory_msgs.msg import JointTrajectory as JointTrajectoryMsg
from trajectory_msgs.msg import JointTrajectoryPoint
from unique_identifier_msgs.msg import UUID

from armwarden.core.trajectory import JointTrajectory


def _duration(seconds: float) -> tuple[int, int]:
    """(sec, nanosec) of a non-negative duration [s]."""
    nanoseconds = round(seconds * 1e9)
    return nanoseconds // 1_000_000_000, nanoseconds % 1_000_000_000


def trajectory_message(trajectory: JointTrajectory, ros_names: tuple[str, ...]) -> JointTrajectoryMsg:
    """The validated waypoints and times, unchanged, under the controller's joint names (header
    stamp zero: start on receipt)."""
    msg = JointTrajectoryMsg()
    msg.joint_names = list(ros_names)
    points = []
    for t, q in zip(trajectory.times, trajectory.positions, strict=True):
        point = JointTrajectoryPoint(positions=[float(v) for v in q])
        point.time_from_start.sec, point.time_from_start.nanosec = _duration(float(t))
        points.append(point)
    msg.points = points
    return msg


def hold_message(positions: np.ndarray, ros_names: tuple[str, ...], hold_time_s: float) -> JointTrajectoryMsg:
    """A one-point trajectory at `positions`, reached after `hold_time_s` [s]: the topic stop."""
    msg = JointTrajectoryMsg()
    msg.joint_names = list(ros_names)
    point = JointTrajectoryPoint(positions=[float(v) for v in positions], velocities=[0.0] * len(ros_names))
    point.time_from_start.sec, point.time_from_start.nanosec = _duration(hold_time_s)
    msg.points = [point]
    return msg


@dataclass(frozen=True)
class StopRecord:
    """One stop as the backend carried it out: `stamp` = monotonic time [s] the cancel request
    (or the topic hold) was sent; `what` = "cancel", "hold", "gripper cancel"."""

    what: str
    stamp: float


@dataclass
class GoalRun:
    """One trajectory goal: written under the motion lock (event loop, stopping threads) and by
    the goal-response and feedback callbacks (the executor thread)."""

    goal_id: UUID
    epoch: int
    duration_s: float
    sent_at: float
    handle: rclpy.action.client.ClientGoalHandle | None = None
    cancel_sent: bool = False
    terminal: bool = False  # a result (any status) arrived
    stopped: bool = False  # a stop reached it (under the motion lock): its end is no FINISH of the arm state
    feedback_s: float = 0.0  # the latest feedback's trajectory time [s]

    def on_feedback(self, message: Any) -> None:
        desired = message.feedback.desired.time_from_start
        t = float(desired.sec) + float(desired.nanosec) * 1e-9
        if t <= 0.0:  # a server that does not fill in the time: time since the goal was sent
            t = time.monotonic() - self.sent_at
        self.feedback_s = max(self.feedback_s, t)

    def fraction(self) -> float:
        if self.duration_s <= 0.0:
            return 0.0
        return min(1.0, self.feedback_s / self.duration_s)


@dataclass(frozen=True)
class Fault:
    """A fault the backend found (idle or mid-motion): `problem` names it; `epoch` is the stop
    epoch before the stop it caused, so an execution decided under `epoch` or earlier ran into it."""

    problem: str
    epoch: int


@dataclass
class TopicRun:
    """One trajectory published on the fallback topic."""

    epoch: int
    duration_s: float
    sent_at: float
    trajectory: JointTrajectory | None = None  # what was published: where the controller is told to be
    held_at: float | None = None  # when the stop's hold was published (monotonic [s])
    held_measured: float | None = None  # header stamp of the latest joint state then [s, the cell's clock]
    stopped: bool = False  # a stop reached it (under the motion lock): its end is no FINISH of the arm state


@dataclass
class GripperRun:
    goal_id: UUID
    epoch: int
    handle: rclpy.action.client.ClientGoalHandle | None = None
    cancel_sent: bool = False


def new_goal_id() -> UUID:
    return UUID(uuid=list(uuid.uuid4().bytes))


__all__ = ["Fault", "GoalRun", "GripperRun", "StopRecord", "TopicRun", "hold_message", "new_goal_id",
           "trajectory_message"]
