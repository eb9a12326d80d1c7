"""A plain rclpy client of the fake cell (tests of the cell itself, before any backend)."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import rclpy
from control_msgs.action import FollowJointTrajectory, GripperCommand
from controller_manager_msgs.srv import ListControllers, SwitchController
from geometry_msgs.msg import WrenchStamped
from rclpy.action.client import ClientGoalHandle
from rclpy.context import Context
from rclpy.executors import MultiThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from rclpy.utilities import try_shutdown
from sensor_msgs.msg import Image, JointState
from tf2_msgs.msg import TFMessage
from trajectory_msgs.msg import JointTrajectoryPoint

from armwarden.backends.ros2.action_client import ActionClient  # rclpy's, without its lost-answer race
from tests_ros.cell import CellConfig

DISCOVERY_TIMEOUT_S = 15.0  # peers were found in 0.25–2.75 s here; generous on a loaded machine
T = TypeVar("T")


def wait_for(future: Future, timeout: float) -> Any:
    """Block the calling (test) thread until an rclpy future, spun elsewhere, is done."""
    done = threading.Event()
    future.add_done_callback(lambda _f: done.set())
    if not done.wait(timeout):
        raise TimeoutError(f"no answer within {timeout} s")
    return future.result()


def eventually(probe: Callable[[], T | None], timeout: float = DISCOVERY_TIMEOUT_S, what: str = "condition") -> T:
    """Poll until probe() returns something other than None/False."""
    deadline = time.monotonic() + timeout
    while True:
        value = probe()
        if value:
            return value
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what} not seen within {timeout} s")
        time.sleep(0.02)


class RosClient:
    """One node in a private context that subscribes to the cell and calls its servers."""

    def __init__(self, config: CellConfig) -> None:
        self.config = config
        self._lock = threading.Lock()
        self._latest: dict[str, Any] = {}
        self.joint_state_count = 0
        self.feedback: list[FollowJointTrajectory.Feedback] = []

    def start(self) -> RosClient:
        cfg = self.config
        self._context = Context()
        rclpy.init(context=self._context, domain_id=int(os.environ["ROS_DOMAIN_ID"]), signal_handler_options=SignalHandlerOptions.NO)
        node = rclpy.create_node("cell_test_client", context=self._context)
        self.node = node
        node.create_subscription(JointState, cfg.joint_states_topic, self._keep("joint_states"), 10)
        best_effort = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
        node.create_subscription(WrenchStamped, cfg.wrench_topic, self._keep("wrench"), best_effort)
        node.create_subscription(Image, cfg.camera_topic, self._keep("image"), 10)
        static_qos = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE)
        node.create_subscription(TFMessage, "/tf_static", self._keep("tf_static"), static_qos)
        self.trajectory = ActionClient(node, FollowJointTrajectory, cfg.trajectory_action)
        self.gripper = ActionClient(node, GripperCommand, cfg.gripper_action)
        self.list_client = node.create_client(ListControllers, cfg.list_controllers_service)
        self.switch_client = node.create_client(SwitchController, cfg.switch_controller_service)
        self._executor = MultiThreadedExecutor(num_threads=4, context=self._context)
        self._executor.add_node(node)
        self._thread = threading.Thread(target=self._executor.spin, name="cell-client-executor", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        self._executor.shutdown(timeout_sec=5.0)
        self._thread.join(timeout=5.0)
        self.trajectory.destroy()
        self.gripper.destroy()
        self.node.destroy_node()
        try_shutdown(context=self._context)

    def __enter__(self) -> RosClient:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _keep(self, key: str) -> Callable[[Any], None]:
        def store(msg: Any) -> None:
            with self._lock:
                self._latest[key] = msg
                if key == "joint_states":
                    self.joint_state_count += 1

        return store

    def latest(self, key: str) -> Any:
        with self._lock:
            return self._latest.get(key)

    def wait_latest(self, key: str, timeout: float = DISCOVERY_TIMEOUT_S) -> Any:
        return eventually(lambda: self.latest(key), timeout, f"a message on {key}")

    def positions(self) -> list[float]:
        msg = self.wait_latest("joint_states")
        return list(msg.position)

    # ------------------------------------------------------------------ trajectory action

    def trajectory_goal(
        self, names: Sequence[str], waypoints: Sequence[Sequence[float]], times: Sequence[float]
    ) -> FollowJointTrajectory.Goal:
        goal = FollowJointTrajectory.Goal()
        goal.trajectory.joint_names = list(names)
        points = []
        for positions, t in zip(waypoints, times, strict=True):
            point = JointTrajectoryPoint(positions=list(positions))
            point.time_from_start.sec = int(t)
            point.time_from_start.nanosec = round((t - int(t)) * 1e9)
            points.append(point)
        goal.trajectory.points = points
        return goal

    def send_goal(self, goal: FollowJointTrajectory.Goal, timeout: float = DISCOVERY_TIMEOUT_S) -> ClientGoalHandle:
        if not self.trajectory.wait_for_server(timeout_sec=timeout):
            raise TimeoutError("trajectory action server not discovered")
        future = self.trajectory.send_goal_async(goal, feedback_callback=self._on_feedback)
        return wait_for(future, timeout)

    def _on_feedback(self, message: Any) -> None:
        with self._lock:
            self.feedback.append(message.feedback)

    def result(self, handle: ClientGoalHandle, timeout: float = 30.0) -> Any:
        return wait_for(handle.get_result_async(), timeout)

    def cancel(self, handle: ClientGoalHandle, timeout: float = 10.0) -> Any:
        return wait_for(handle.cancel_goal_async(), timeout)

    # ------------------------------------------------------------------ gripper and controllers

    def grip(self, width: float, effort: float = 20.0, timeout: float = DISCOVERY_TIMEOUT_S) -> Any:
        if not self.gripper.wait_for_server(timeout_sec=timeout):
            raise TimeoutError("gripper action server not discovered")
        goal = GripperCommand.Goal()
        goal.command.position = width
        goal.command.max_effort = effort
        handle = wait_for(self.gripper.send_goal_async(goal), timeout)
        return handle, wait_for(handle.get_result_async(), 30.0)

    def call(self, client: Any, request: Any, timeout: float = DISCOVERY_TIMEOUT_S) -> Any:
        if not client.wait_for_service(timeout_sec=timeout):
            raise TimeoutError(f"service {client.srv_name} not discovered")
        return wait_for(client.call_async(request), timeout)
