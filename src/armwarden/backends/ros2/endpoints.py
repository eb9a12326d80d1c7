"""The rclpy entities the ROS 2 backend keeps as long as its node: subscriptions to the state
streams, the trajectory and gripper action clients (or the trajectory publisher), the service
clients and the watchdog timer.

They are all made in one place, before the executor spins (`RosBridge.start`), because the
executor thread owns the entities once it runs (`armwarden.backends.ros2.bridge`); the parts that
use them (`arm.py`, `gripper.py`, `controllers.py`) only read `Endpoints`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import rclpy.action.client
import rclpy.client
import rclpy.publisher
import rclpy.qos
import rclpy.subscription
import rclpy.timer
from control_msgs.action import FollowJointTrajectory, GripperCommand
from controller_manager_msgs.srv import ListControllers, SwitchController
from geometry_msgs.msg import WrenchStamped
from sensor_msgs.msg import JointState as JointStateMsg
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage
from trajectory_msgs.msg import JointTrajectory as JointTrajectoryMsg

from armwarden.backends.ros2.action_client import ActionClient
from armwarden.backends.ros2.bridge import RosBridge
from armwarden.backends.ros2.config import Config, resolved
from armwarden.backends.ros2.state import JointStateCache, WrenchCache
from armwarden.backends.ros2.tf import TransformBuffer


@dataclass
class Endpoints:
    """The rclpy entities the backend created (built in `_open`)."""

    trajectory_action: rclpy.action.client.ActionClient | None = None
    trajectory_topic: rclpy.publisher.Publisher | None = None
    gripper_action: rclpy.action.client.ActionClient | None = None
    list_controllers: rclpy.client.Client | None = None
    switch_controller: rclpy.client.Client | None = None
    error_recovery: rclpy.client.Client | None = None
    watchdog: rclpy.timer.Timer | None = None
    subscriptions: list[rclpy.subscription.Subscription] = field(default_factory=list)


@dataclass(frozen=True)
class Streams:
    """The caches the subscriptions feed (None: that stream is not configured)."""

    joint_states: JointStateCache
    wrench: WrenchCache | None
    fingers: JointStateCache | None
    transforms: TransformBuffer | None


def create_endpoints(endpoints: Endpoints, bridge: RosBridge, config: Config, streams: Streams,
                     watch: Callable[[], None], watch_period_s: float) -> None:
    """Make every entity `config` asks for into `endpoints`, and the watchdog timer calling
    `watch` every `watch_period_s` [s]; call before the executor spins."""
    node, group, cfg, e = bridge.node, bridge.group, config, endpoints
    subscribe = e.subscriptions.append
    subscribe(node.create_subscription(JointStateMsg, cfg.joint_states.topic, streams.joint_states.accept, 10,
                                       callback_group=group))
    if streams.wrench is not None:
        best_effort = rclpy.qos.QoSProfile(depth=10, reliability=rclpy.qos.ReliabilityPolicy.BEST_EFFORT)
        subscribe(node.create_subscription(WrenchStamped, streams.wrench.topic, streams.wrench.accept, best_effort,
                                           callback_group=group))
    if streams.fingers is not None:
        subscribe(node.create_subscription(JointStateMsg, streams.fingers.topic, streams.fingers.accept, 10,
                                           callback_group=group))
    if streams.transforms is not None:
        transforms = streams.transforms
        static = rclpy.qos.QoSProfile(depth=100, durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL,
                                      reliability=rclpy.qos.ReliabilityPolicy.RELIABLE)
        subscribe(node.create_subscription(TFMessage, "/tf", lambda m: transforms.accept(m, static=False), 100,
                                           callback_group=group))
        subscribe(node.create_subscription(TFMessage, "/tf_static", lambda m: transforms.accept(m, static=True),
                                           static, callback_group=group))
    if cfg.trajectory.action is not None:
        e.trajectory_action = ActionClient(node, FollowJointTrajectory, cfg.trajectory.action, callback_group=group)
    else:
        assert cfg.trajectory.topic is not None
        e.trajectory_topic = node.create_publisher(JointTrajectoryMsg, cfg.trajectory.topic, 10)
    if cfg.gripper is not None:
        e.gripper_action = ActionClient(node, GripperCommand, resolved(cfg.gripper.action, "gripper.action"),
                                        callback_group=group)
    if cfg.controller_manager is not None:
        ns = cfg.controller_manager.namespace.rstrip("/")
        e.list_controllers = node.create_client(ListControllers, f"{ns}/list_controllers", callback_group=group)
        e.switch_controller = node.create_client(SwitchController, f"{ns}/switch_controller", callback_group=group)
    if cfg.error_recovery is not None:
        e.error_recovery = node.create_client(Trigger, cfg.error_recovery.service, callback_group=group)
    e.watchdog = node.create_timer(watch_period_s, watch, callback_group=group)


__all__ = ["Endpoints", "Streams", "create_endpoints"]
