"""A fake FR3 cell made of real rclpy endpoints: the ROS 2 backend's tests and `armwarden eval`'s arm.

One node in a private rclpy Context offers what a ros2_control FR3 with a Franka Hand and a
scene camera offers: joint states (100 Hz), a force/torque wrench (best-effort QoS) with an
optional virtual table, a FollowJointTrajectory action server that interpolates goals in real
time, a GripperCommand action server, the controller_manager list/switch services, a camera image
that changes with the joint state and a static transform base → camera.

Tests steer it (reject, abort or hang goals, stop a topic, freeze a stamp, die mid-motion, push on
the arm) and read its counters (goals received and accepted: refused scenarios must show zero).
It lives in the package, not under tests_ros/, because `armwarden eval --backend ros2` starts it
as a process of its own (``python -m armwarden.backends.ros2.fake_cell --journal FILE``) and counts
what it accepted in that journal: the actuation a scenario caused, as the cell received it
(`CellJournal`, the format of `armwarden.backends.journal`).

Its joint states carry the joint torques a torque-sensing arm measures in `effort` [N·m]: the FR3
model's inverse dynamics of the published motion, `rnea(q, q̇, q̈)` (so at rest g(q)), minus Jᵀ F
for a contact force F: the virtual table's at the TCP, and a test's `push(link, force, point)`
until `release_push()` (`armwarden.backends.ros2.fake_cell_dynamics`); plus seeded Gaussian noise
(`torque_noise_nm`). The cell follows a trajectory piecewise linearly (its published velocity is
the segment's), so q̈ is `_acceleration`'s: each velocity step spread between the middles of the
segments beside it, as the fake backend's servo does, rather than an impulse no motor delivers
and a sampled reading would see as a spike or miss; a cancel stops the cell at once, with no
deceleration torque.
`CellConfig(efforts=False)` sends an empty `effort`, as an arm without torque sensing does. It also offers what
the backend's optional parts use: the finger joint states of the gripper, a JointTrajectory topic
(the controller's topic interface, the backend's fallback), the same camera picture as a PNG
CompressedImage, and a std_srvs/Trigger error-recovery service.

Standalone: ``bash scripts/ros_cell.sh [--table-height 0.1]`` (sets up .venv-ros, then runs
``python -m tests_ros.cell``, the same as ``python -m armwarden.backends.ros2.fake_cell``). DDS
stays on this host: the cell refuses to start unless discovery is limited to localhost (or a
Fast DDS profile is given). The standalone entry point uses the daemon's defaults where the
environment sets nothing (``armwarden.backends.ros2.dds``: domain 0,
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) and names both on stderr.
"""

from __future__ import annotations

import argparse
import enum
import itertools
import os
import signal
import struct
import sys
import threading
import time
import zlib
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import rclpy
from builtin_interfaces.msg import Time as TimeMsg
from control_msgs.action import FollowJointTrajectory, GripperCommand
from controller_manager_msgs.msg import ControllerState
from controller_manager_msgs.srv import ListControllers, SwitchController
from geometry_msgs.msg import TransformStamped, WrenchStamped
from rclpy.action.server import ActionServer, CancelResponse, GoalResponse, ServerGoalHandle
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.context import Context
from rclpy.executors import MultiThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import try_shutdown
from sensor_msgs.msg import CompressedImage, Image, JointState
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from armwarden.backends.ros2.dds import dds_settings
from armwarden.backends.ros2.fake_cell_dynamics import ArmDynamics, Contact, Vector3
from armwarden.backends.ros2.fake_cell_journal import GRIPPER_GOAL, READY, CellJournal
from armwarden.policy import bundled_policy, load_policy
from armwarden.robot import RobotModel, build_robot

STATE_PERIOD_S = 0.01  # joint states and the trajectory interpolation run at 100 Hz
CAMERA_PERIOD_S = 0.1
GRIPPER_SPEED_MPS = 0.1

Result = FollowJointTrajectory.Result


class GoalMode(enum.Enum):
    """What the trajectory action server does with the next goals."""

    ACCEPT = "accept"  # execute them
    REJECT = "reject"  # refuse them in the goal callback (counted as received, not accepted)
    ABORT = "abort"  # accept, move for `abort_after_s`, then abort with PATH_TOLERANCE_VIOLATED
    DIE = "die"  # accept, move for `die_after_s`, then the whole cell goes silent
    HANG = "hang"  # accept, never move, never finish (until cancelled): a stuck controller


@dataclass(frozen=True)
class CellConfig:
    """Names and rates of the cell's endpoints. The defaults mirror a ros2_control FR3."""

    node_name: str = "fake_fr3_cell"
    joint_states_topic: str = "/joint_states"
    wrench_topic: str = "/force_torque_sensor_broadcaster/wrench"
    trajectory_action: str = "/fr3_arm_controller/follow_joint_trajectory"
    gripper_action: str = "/franka_gripper/gripper_action"
    list_controllers_service: str = "/controller_manager/list_controllers"
    switch_controller_service: str = "/controller_manager/switch_controller"
    camera_topic: str = "/scene_camera/color/image_raw"
    camera_frame: str = "scene_camera_color_optical_frame"
    compressed_camera_topic: str = "/scene_camera/color/image_raw/compressed"  # the same picture as PNG
    trajectory_topic: str = "/fr3_arm_controller/joint_trajectory"  # JointTrajectory (the controller's topic interface)
    gripper_joint_states_topic: str = "/franka_gripper/joint_states"  # finger joints, each half the width
    finger_joints: tuple[str, str] = ("fr3_finger_joint1", "fr3_finger_joint2")
    error_recovery_service: str = "/error_recovery"  # std_srvs/Trigger
    error_recovery_succeeds: bool = True
    image_width: int = 64
    image_height: int = 48
    # Virtual table: a plane z = table_height_m in the base frame; a TCP below it feels an upward
    # force of stiffness × depth (in the base frame). None: no table, the wrench stays zero.
    table_height_m: float | None = None
    table_stiffness_n_per_m: float = 2000.0
    initial_positions: tuple[float, ...] | None = None  # default: the policy's home pose
    initial_gripper_width_m: float = 0.08
    # Joint torques in the joint states' `effort` (see the module docstring); False: an empty `effort`.
    efforts: bool = True
    torque_noise_nm: float = 0.0  # standard deviation of Gaussian noise on every effort [N·m]
    torque_noise_seed: int = 0
    controllers: tuple[tuple[str, str], ...] = (
        ("joint_state_broadcaster", "active"),
        ("fr3_arm_controller", "active"),
        ("joint_impedance_controller", "inactive"),
    )
    abort_after_s: float = 0.2
    die_after_s: float = 0.2
    goal_mode: GoalMode = GoalMode.ACCEPT


@dataclass
class Counters:
    """What the cell saw; tests assert on these (e.g. zero goals in a refused scenario)."""

    goals_received: int = 0
    goals_accepted: int = 0
    goals_succeeded: int = 0
    goals_aborted: int = 0
    goals_canceled: int = 0
    cancels_received: int = 0
    gripper_goals: int = 0
    switch_calls: int = 0
    last_goal: FollowJointTrajectory.Goal | None = None
    error_recoveries: int = 0
    topic_trajectories: int = 0  # JointTrajectory messages received on the topic interface
    last_topic_trajectory: JointTrajectory | None = None


@dataclass
class _Switches:
    """Faults a test can switch on while the cell runs."""

    joint_states_paused: bool = False
    wrench_stopped: bool = False
    wrench_stamp_frozen: bool = False
    push: Contact | None = None  # a test's contact force on the arm, until released
    dead: bool = False
    frozen_stamp: TimeMsg = field(default_factory=TimeMsg)


def _require_local_discovery() -> None:
    """DDS must not leave this host: localhost-only discovery or an explicit Fast DDS profile."""
    if os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE") == "LOCALHOST" or os.environ.get("FASTRTPS_DEFAULT_PROFILES_FILE"):
        return
    raise RuntimeError(
        "refusing to start DDS with LAN discovery: set ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST "
        "(or FASTRTPS_DEFAULT_PROFILES_FILE to a loopback-only profile) and a random ROS_DOMAIN_ID"
    )


def _sample(points: Sequence[tuple[float, np.ndarray]], t: float) -> tuple[np.ndarray, np.ndarray]:
    """Position and velocity at time t along piecewise-linear (time, positions) points."""
    if t <= points[0][0]:
        return points[0][1].copy(), np.zeros_like(points[0][1])
    for (t0, q0), (t1, q1) in itertools.pairwise(points):
        if t <= t1:
            span = t1 - t0
            if span <= 0.0:
                return q1.copy(), np.zeros_like(q1)
            return q0 + (q1 - q0) * ((t - t0) / span), (q1 - q0) / span
    return points[-1][1].copy(), np.zeros_like(points[-1][1])


def _acceleration(points: Sequence[tuple[float, np.ndarray]], t: float) -> np.ndarray:
    """q̈ [rad/s²] at time t along piecewise-linear points: each velocity step (from rest at the
    start, to rest at the end) spread linearly between the middles of the segments beside it, so
    the acceleration integrates to exactly the segment velocities `_sample` publishes."""
    zero = np.zeros_like(points[0][1])
    if t <= points[0][0] or t >= points[-1][0]:
        return zero

    def knot(j: int) -> tuple[float, np.ndarray]:
        """(time, velocity) where the spread velocity equals segment j's (rest beyond the ends)."""
        if j < 0:
            return points[0][0], zero
        if j >= len(points) - 1:
            return points[-1][0], zero
        (t0, q0), (t1, q1) = points[j], points[j + 1]
        return (t0 + t1) / 2, (q1 - q0) / (t1 - t0) if t1 > t0 else zero

    k = max(j for j, (tj, _) in enumerate(points[:-1]) if tj <= t)  # the segment t is on
    (t0, v0), (t1, v1) = (knot(k - 1), knot(k)) if t < knot(k)[0] else (knot(k), knot(k + 1))
    return (v1 - v0) / (t1 - t0) if t1 > t0 else zero


def _seconds(duration) -> float:
    return float(duration.sec) + float(duration.nanosec) * 1e-9


def _png(pixels: np.ndarray) -> bytes:
    """PNG bytes of an rgb8 picture (height × width × 3), written by hand: no Pillow needed."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    height, width = pixels.shape[:2]
    rows = b"".join(b"\x00" + pixels[y].tobytes() for y in range(height))
    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b"")


class Cell:
    """The fake FR3 cell: start(), steer and read it, close(). Thread-safe."""

    def __init__(self, config: CellConfig | None = None, robot: RobotModel | None = None, hard_death: bool = False,
                 journal: Path | None = None) -> None:
        self.config = config or CellConfig()
        self._journal = CellJournal(journal)  # what it accepted, for `armwarden eval` (None: not written)
        policy = load_policy(bundled_policy("fr3"))
        self.robot = robot or build_robot(policy)
        self.joint_names: tuple[str, ...] = tuple(policy.robot.joint_names)
        home = self.config.initial_positions or tuple(policy.robot.home_joint_positions)
        if len(home) != len(self.joint_names):
            raise ValueError(f"initial_positions has {len(home)} values for {len(self.joint_names)} joints")
        self._hard_death = hard_death  # standalone process: dying means os._exit
        self._lock = threading.Lock()
        # held while a joint state is published: once a pause has taken it, nothing more is sent
        self._joint_publish_lock = threading.Lock()
        self._last_joint_stamp: TimeMsg | None = None  # header stamp of the last joint state sent
        self._wrench_publish_lock = threading.Lock()  # likewise for the wrench's switches
        # the clock thread's own Pinocchio Data: the effort of every joint state and the table's contact
        self._dynamics = ArmDynamics(self.robot, self.config.torque_noise_nm, self.config.torque_noise_seed)
        self._positions = np.array(home, dtype=float)
        self._velocities = np.zeros(len(self.joint_names))
        self._accelerations = np.zeros(len(self.joint_names))  # of the measured torque (`_acceleration`)
        self._gripper_width = self.config.initial_gripper_width_m
        self._mode = self.config.goal_mode
        self._controllers = dict(self.config.controllers)
        self._active_goal: bytes | None = None
        self._topic_points: list[tuple[float, np.ndarray]] | None = None  # the topic trajectory being followed
        self._topic_started = 0.0
        self._counters = Counters()
        self._switches = _Switches()
        self._closing = threading.Event()
        self._context: Context | None = None
        self._executor: MultiThreadedExecutor | None = None
        self._thread: threading.Thread | None = None
        self._clock_thread: threading.Thread | None = None
        self._node = None

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> Cell:
        _require_local_discovery()
        context = Context()
        domain = int(os.environ.get("ROS_DOMAIN_ID", "0"))
        rclpy.init(context=context, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
        self._context = context
        node = rclpy.create_node(self.config.node_name, context=context)
        self._node = node
        cfg = self.config
        serving = ReentrantCallbackGroup()
        self._joint_pub = node.create_publisher(JointState, cfg.joint_states_topic, 10)
        wrench_qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
        self._wrench_pub = node.create_publisher(WrenchStamped, cfg.wrench_topic, wrench_qos)
        self._image_pub = node.create_publisher(Image, cfg.camera_topic, 10)
        self._compressed_pub = node.create_publisher(CompressedImage, cfg.compressed_camera_topic, 10)
        self._fingers_pub = node.create_publisher(JointState, cfg.gripper_joint_states_topic, 10)
        node.create_subscription(JointTrajectory, cfg.trajectory_topic, self._on_topic_trajectory, 10, callback_group=serving)
        node.create_service(Trigger, cfg.error_recovery_service, self._error_recovery, callback_group=serving)
        static_qos = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE)
        self._tf_static_pub = node.create_publisher(TFMessage, "/tf_static", static_qos)
        self._trajectory_server = ActionServer(
            node,
            FollowJointTrajectory,
            cfg.trajectory_action,
            execute_callback=self._execute_trajectory,
            goal_callback=self._on_trajectory_goal,
            handle_accepted_callback=self._on_trajectory_accepted,
            cancel_callback=self._on_cancel,
            callback_group=serving,
        )
        self._gripper_server = ActionServer(
            node,
            GripperCommand,
            cfg.gripper_action,
            execute_callback=self._execute_gripper,
            goal_callback=self._on_gripper_goal,
            cancel_callback=lambda _handle: CancelResponse.ACCEPT,
            callback_group=serving,
        )
        node.create_service(ListControllers, cfg.list_controllers_service, self._list_controllers, callback_group=serving)
        node.create_service(SwitchController, cfg.switch_controller_service, self._switch_controller, callback_group=serving)
        self._publish_static_tf()
        self._executor = MultiThreadedExecutor(num_threads=6, context=context)
        self._executor.add_node(node)
        self._thread = threading.Thread(target=self._spin, name="fake-cell-executor", daemon=True)
        self._thread.start()
        self._clock_thread = threading.Thread(target=self._tick, name="fake-cell-clock", daemon=True)
        self._clock_thread.start()
        return self

    def _tick(self) -> None:
        """The cell's periodic work on a plain thread, not as executor timers: the executor then
        wakes only for requests, which keeps rclpy's per-wake cost out of the 100 Hz streams."""
        next_state = next_camera = time.monotonic()
        while not self._closing.is_set():
            now = time.monotonic()
            if now >= next_state:
                self._follow_topic_trajectory()
                self._publish_joint_state()
                self._publish_wrench()
                next_state = max(next_state + STATE_PERIOD_S, now)
            if now >= next_camera:
                self._publish_image()
                next_camera = max(next_camera + CAMERA_PERIOD_S, now)
            self._closing.wait(max(0.0, min(next_state, next_camera) - time.monotonic()))

    def _spin(self) -> None:
        assert self._executor is not None
        try:
            self._executor.spin()
        except Exception:  # the context shut down under it: close() is in progress
            if not self._closing.is_set():
                raise

    def close(self) -> None:
        """Stop the executor, join its thread, destroy the node, shut the context down."""
        if self._closing.is_set():
            return
        self._closing.set()
        if self._clock_thread is not None:
            self._clock_thread.join(timeout=5.0)
        if self._executor is not None:
            self._executor.shutdown(timeout_sec=5.0)
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        if self._node is not None:
            self._trajectory_server.destroy()
            self._gripper_server.destroy()
            self._node.destroy_node()
        if self._context is not None:
            try_shutdown(context=self._context)
        self._journal.close()

    def __enter__(self) -> Cell:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ steering and reading

    def positions(self) -> np.ndarray:
        with self._lock:
            return self._positions.copy()

    def gripper_width(self) -> float:
        with self._lock:
            return self._gripper_width

    def counters(self) -> Counters:
        with self._lock:
            return replace(self._counters)

    def controller_states(self) -> dict[str, str]:
        with self._lock:
            return dict(self._controllers)

    def set_goal_mode(self, mode: GoalMode) -> None:
        with self._lock:
            self._mode = mode

    def pause_joint_states(self, paused: bool = True) -> None:
        """Stop (or resume) the arm's and fingers' joint states: when it returns, the last one
        has been sent (`last_joint_state_stamp`) and no other will be until resumed."""
        with self._joint_publish_lock, self._lock:
            self._switches.joint_states_paused = paused

    def last_joint_state_stamp(self) -> TimeMsg | None:
        """The header stamp of the last joint state published (None: none yet)."""
        with self._joint_publish_lock:
            return self._last_joint_stamp

    def stop_wrench(self, stopped: bool = True) -> None:
        with self._wrench_publish_lock, self._lock:
            self._switches.wrench_stopped = stopped

    def freeze_wrench_stamp(self, frozen: bool = True) -> TimeMsg:
        """Keep publishing the wrench, always with the same stamp (a stuck driver): every wrench
        sent after this returns carries the stamp it returns."""
        with self._wrench_publish_lock, self._lock:
            self._switches.wrench_stamp_frozen = frozen
            self._switches.frozen_stamp = self._now()
            return self._switches.frozen_stamp

    def push(self, link: str, force_base: Vector3, point_in_link: Vector3 = (0.0, 0.0, 0.0)) -> None:
        """Push on the arm from now until `release_push` (a newer push replaces it): a force
        [N, base frame] at a point [m, in `link`'s own frame; default its origin] of one of the
        robot model's frames (e.g. ``fr3_link5``, the forearm). The efforts change by −Jᵀ F (J: the
        point's linear Jacobian); positions, velocities and the wrench topic do not (a position-
        controlled arm holds its path; the F/T sensor sits beyond the forearm). When it returns,
        every joint state sent afterwards carries it (`last_joint_state_stamp`: the last one before)."""
        contact = self._dynamics.contact(link, force_base, point_in_link)
        with self._joint_publish_lock, self._lock:
            self._switches.push = contact

    def release_push(self) -> None:
        """End the push: every joint state sent after this returns is without it."""
        with self._joint_publish_lock, self._lock:
            self._switches.push = None

    @contextmanager
    def pushing(self, link: str, force_base: Vector3, point_in_link: Vector3 = (0.0, 0.0, 0.0)) -> Iterator[None]:
        """`push` for the duration of a with block."""
        self.push(link, force_base, point_in_link)
        try:
            yield
        finally:
            self.release_push()

    def die(self) -> None:
        """The cell goes silent: no topic, no feedback, no result, no service answer. When it
        returns, the last joint state has been sent (`last_joint_state_stamp`)."""
        if self._hard_death:
            os._exit(3)
        with self._joint_publish_lock, self._wrench_publish_lock, self._lock:
            self._switches.dead = True

    @property
    def dead(self) -> bool:
        with self._lock:
            return self._switches.dead

    # ------------------------------------------------------------------ publishers

    def _now(self) -> TimeMsg:
        assert self._node is not None
        return self._node.get_clock().now().to_msg()

    def _efforts(self, positions: np.ndarray, velocities: np.ndarray, accelerations: np.ndarray,
                 push: Contact | None) -> list[float]:
        """Clock thread: what the joints measure now (see the module docstring); [] without efforts."""
        if not self.config.efforts:
            return []
        contacts = [] if push is None else [push]
        table = self._contact_force(positions)
        if table > 0.0:
            contacts.append(self._dynamics.tcp_contact((0.0, 0.0, table)))
        return self._dynamics.efforts(positions, velocities, accelerations, contacts).tolist()

    def _publish_joint_state(self) -> None:
        with self._joint_publish_lock:
            with self._lock:
                if self._switches.dead or self._switches.joint_states_paused:
                    return
                positions, velocities = self._positions.copy(), self._velocities.copy()
                accelerations = self._accelerations.copy()
                push = self._switches.push
                half_width = self._gripper_width / 2
            efforts = self._efforts(positions, velocities, accelerations, push)
            stamp = self._now()
            msg = JointState()
            msg.header.stamp = stamp
            msg.name = list(self.joint_names)
            msg.position = positions.tolist()
            msg.velocity = velocities.tolist()
            msg.effort = efforts
            self._joint_pub.publish(msg)
            fingers = JointState()
            fingers.header.stamp = stamp
            fingers.name = list(self.config.finger_joints)
            fingers.position = [half_width, half_width]
            fingers.velocity = [0.0, 0.0]
            self._fingers_pub.publish(fingers)
            self._last_joint_stamp = stamp

    def _contact_force(self, positions: np.ndarray) -> float:
        """Upward force of the virtual table on the TCP [N] (zero above the table or without one)."""
        height = self.config.table_height_m
        if height is None:
            return 0.0
        depth = height - float(self._dynamics.tcp_position(positions)[2])  # the clock thread's own Data
        return self.config.table_stiffness_n_per_m * depth if depth > 0.0 else 0.0

    def _publish_wrench(self) -> None:
        with self._wrench_publish_lock:
            with self._lock:
                switches = replace(self._switches)
                positions = self._positions.copy()
            if switches.dead or switches.wrench_stopped:
                return
            msg = WrenchStamped()
            msg.header.stamp = switches.frozen_stamp if switches.wrench_stamp_frozen else self._now()
            msg.header.frame_id = self.robot.base_frame
            msg.wrench.force.z = self._contact_force(positions)
            self._wrench_pub.publish(msg)

    def render_image(self, positions: np.ndarray) -> np.ndarray:
        """A small rgb8 picture that is a function of the joint state (height × width × 3)."""
        h, w = self.config.image_height, self.config.image_width
        ys, xs = np.mgrid[0:h, 0:w]
        shift = (positions * 40.0).astype(int)
        red = (xs * 4 + shift[0]) % 256
        green = (ys * 5 + shift[1]) % 256
        blue = ((xs + ys) * 2 + int(np.sum(shift[2:]))) % 256
        return np.stack([red, green, blue], axis=-1).astype(np.uint8)

    def _publish_image(self) -> None:
        with self._lock:
            if self._switches.dead:
                return
            positions = self._positions.copy()
        pixels = self.render_image(positions)
        msg = Image()
        msg.header.stamp = self._now()
        msg.header.frame_id = self.config.camera_frame
        msg.height, msg.width = pixels.shape[0], pixels.shape[1]
        msg.encoding = "rgb8"
        msg.is_bigendian = 0
        msg.step = pixels.shape[1] * 3
        msg.data = pixels.tobytes()
        self._image_pub.publish(msg)
        compressed = CompressedImage()
        compressed.header = msg.header
        compressed.format = "rgb8; png compressed rgb8"
        compressed.data = _png(pixels)
        self._compressed_pub.publish(compressed)

    def _publish_static_tf(self) -> None:
        transform = TransformStamped()
        transform.header.stamp = self._now()
        transform.header.frame_id = self.robot.base_frame
        transform.child_frame_id = self.config.camera_frame
        transform.transform.translation.x = 1.2
        transform.transform.translation.z = 0.8
        # Looking back at the robot and down: optical z along -x of the base, tilted down.
        transform.transform.rotation.x = 0.5
        transform.transform.rotation.y = -0.5
        transform.transform.rotation.z = 0.5
        transform.transform.rotation.w = -0.5
        self._tf_static_pub.publish(TFMessage(transforms=[transform]))

    # ------------------------------------------------------------------ trajectory action

    def _on_trajectory_goal(self, goal: FollowJointTrajectory.Goal) -> GoalResponse:
        with self._lock:
            self._counters.goals_received += 1
            self._counters.last_goal = goal
            if self._switches.dead or self._mode is GoalMode.REJECT:
                return GoalResponse.REJECT
        names = list(goal.trajectory.joint_names)
        points = goal.trajectory.points
        if sorted(names) != sorted(self.joint_names) or not points:
            return GoalResponse.REJECT  # like Jazzy's controller: wrong joints or an empty trajectory
        if any(len(p.positions) != len(names) for p in points):
            return GoalResponse.REJECT
        with self._lock:
            self._counters.goals_accepted += 1
        self._journal.write("trajectory_goal")
        return GoalResponse.ACCEPT

    def _on_trajectory_accepted(self, goal_handle: ServerGoalHandle) -> None:
        with self._lock:
            self._active_goal = bytes(goal_handle.goal_id.uuid)  # a newer goal preempts the running one
            self._topic_points = None
        goal_handle.execute()

    def _on_cancel(self, _goal_handle: ServerGoalHandle) -> CancelResponse:
        with self._lock:
            self._counters.cancels_received += 1
        self._journal.write("cancel", "stop")
        return CancelResponse.ACCEPT

    def _goal_points(self, goal: FollowJointTrajectory.Goal, start: np.ndarray) -> list[tuple[float, np.ndarray]]:
        order = [list(goal.trajectory.joint_names).index(name) for name in self.joint_names]
        points = [(0.0, start)]
        for point in goal.trajectory.points:
            points.append((_seconds(point.time_from_start), np.array([point.positions[i] for i in order], dtype=float)))
        return points

    def _park_until_closed(self) -> None:
        """A dead cell never answers: hold the callback until the cell is closed."""
        self._closing.wait()

    def _finish(self, goal_handle: ServerGoalHandle, outcome: str, code: int, text: str) -> FollowJointTrajectory.Result:
        with self._lock:
            self._velocities[:] = 0.0
            self._accelerations[:] = 0.0
            if outcome == "succeed":
                self._counters.goals_succeeded += 1
            elif outcome == "abort":
                self._counters.goals_aborted += 1
            else:
                self._counters.goals_canceled += 1
        getattr(goal_handle, {"succeed": "succeed", "abort": "abort", "cancel": "canceled"}[outcome])()
        return Result(error_code=code, error_string=text)

    def _execute_trajectory(self, goal_handle: ServerGoalHandle) -> FollowJointTrajectory.Result:
        goal_id = bytes(goal_handle.goal_id.uuid)
        with self._lock:
            mode = self._mode
            points = self._goal_points(goal_handle.request, self._positions.copy())
        started = time.monotonic()
        end = points[-1][0]
        while True:
            if self._closing.is_set():
                return self._finish(goal_handle, "abort", Result.INVALID_GOAL, "fake cell: shutting down")
            if self.dead:
                self._park_until_closed()
                return Result()
            elapsed = time.monotonic() - started
            with self._lock:
                preempted = self._active_goal != goal_id
            if preempted:
                return self._finish(goal_handle, "abort", Result.INVALID_GOAL, "fake cell: preempted by a newer goal")
            if goal_handle.is_cancel_requested:
                return self._finish(goal_handle, "cancel", Result.SUCCESSFUL, "fake cell: canceled, holding position")
            if mode is GoalMode.ABORT and elapsed >= self.config.abort_after_s:
                return self._finish(goal_handle, "abort", Result.PATH_TOLERANCE_VIOLATED, "fake cell: aborted on request (path tolerance)")
            if mode is GoalMode.DIE and elapsed >= self.config.die_after_s:
                self.die()
                continue
            if mode is GoalMode.HANG:
                time.sleep(STATE_PERIOD_S)
                continue
            desired, velocity = _sample(points, min(elapsed, end))
            with self._lock:
                self._positions[:] = desired
                self._velocities[:] = velocity if elapsed < end else 0.0
                self._accelerations[:] = _acceleration(points, elapsed)
            self._publish_feedback(goal_handle, desired, velocity)
            if elapsed >= end:
                return self._finish(goal_handle, "succeed", Result.SUCCESSFUL, "")
            time.sleep(STATE_PERIOD_S)

    def _publish_feedback(self, goal_handle: ServerGoalHandle, desired: np.ndarray, velocity: np.ndarray) -> None:
        feedback = FollowJointTrajectory.Feedback()
        feedback.header.stamp = self._now()
        feedback.joint_names = list(self.joint_names)
        feedback.desired = JointTrajectoryPoint(positions=desired.tolist(), velocities=velocity.tolist())
        feedback.actual = JointTrajectoryPoint(positions=desired.tolist(), velocities=velocity.tolist())
        feedback.error = JointTrajectoryPoint(positions=[0.0] * len(desired), velocities=[0.0] * len(desired))
        goal_handle.publish_feedback(feedback)

    # ------------------------------------------------------------------ trajectory topic

    def _on_topic_trajectory(self, msg: JointTrajectory) -> None:
        """Like a controller's topic interface: a new trajectory replaces the one being followed
        (and preempts an action goal), starting from where the joints are now."""
        with self._lock:
            self._counters.topic_trajectories += 1
            self._counters.last_topic_trajectory = msg
            if self._switches.dead:
                return
        names = list(msg.joint_names)
        if sorted(names) != sorted(self.joint_names) or not msg.points:
            return  # ignored, like Jazzy's controller with wrong joints or an empty trajectory
        self._journal.write("trajectory_topic")
        order = [names.index(name) for name in self.joint_names]
        with self._lock:
            points = [(0.0, self._positions.copy())]
            points += [(_seconds(p.time_from_start), np.array([p.positions[i] for i in order], dtype=float)) for p in msg.points]
            self._topic_points = points
            self._topic_started = time.monotonic()
            self._active_goal = None

    def _follow_topic_trajectory(self) -> None:
        with self._lock:
            points = self._topic_points
            if points is None or self._switches.dead:
                return
            elapsed = time.monotonic() - self._topic_started
            end = points[-1][0]
            desired, velocity = _sample(points, min(elapsed, end))
            self._positions[:] = desired
            self._velocities[:] = velocity if elapsed < end else 0.0
            self._accelerations[:] = _acceleration(points, elapsed)
            if elapsed >= end:
                self._topic_points = None

    def _error_recovery(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        if self.dead:
            self._park_until_closed()
        with self._lock:
            self._counters.error_recoveries += 1
        self._journal.write("error_recovery")
        response.success = self.config.error_recovery_succeeds
        response.message = "recovered" if response.success else "fake cell: reflex still active"
        return response

    # ------------------------------------------------------------------ gripper and controllers

    def _on_gripper_goal(self, _goal: GripperCommand.Goal) -> GoalResponse:
        with self._lock:
            self._counters.gripper_goals += 1
            if self._switches.dead:
                return GoalResponse.REJECT
        self._journal.write(GRIPPER_GOAL)
        return GoalResponse.ACCEPT

    def _execute_gripper(self, goal_handle: ServerGoalHandle) -> GripperCommand.Result:
        target = min(max(goal_handle.request.command.position, 0.0), 0.08)
        while True:
            if self.dead:
                self._park_until_closed()
                return GripperCommand.Result()
            with self._lock:
                step = GRIPPER_SPEED_MPS * STATE_PERIOD_S
                delta = target - self._gripper_width
                self._gripper_width += max(-step, min(step, delta))
                width = self._gripper_width
            reached = abs(target - width) < 1e-6
            if goal_handle.is_cancel_requested:
                goal_handle.canceled()
                return GripperCommand.Result(position=width, reached_goal=reached)
            goal_handle.publish_feedback(GripperCommand.Feedback(position=width, reached_goal=reached))
            if reached or self._closing.is_set():
                goal_handle.succeed()
                return GripperCommand.Result(position=width, reached_goal=reached)
            time.sleep(STATE_PERIOD_S)

    def _list_controllers(self, _request: ListControllers.Request, response: ListControllers.Response) -> ListControllers.Response:
        if self.dead:
            self._park_until_closed()
        with self._lock:
            response.controller = [
                ControllerState(name=name, state=state, type="fake/Controller", update_rate=1000)
                for name, state in self._controllers.items()
            ]
        return response

    def _switch_controller(self, request: SwitchController.Request, response: SwitchController.Response) -> SwitchController.Response:
        if self.dead:
            self._park_until_closed()
        self._journal.write("switch_controller")
        with self._lock:
            self._counters.switch_calls += 1
            names = [*request.activate_controllers, *request.deactivate_controllers]
            unknown = [name for name in names if name not in self._controllers]
            if unknown:
                response.ok = False
                response.message = f"unknown controller(s): {', '.join(unknown)}"
                return response
            for name in request.deactivate_controllers:
                self._controllers[name] = "inactive"
            for name in request.activate_controllers:
                self._controllers[name] = "active"
        response.ok = True
        response.message = "switched"
        return response


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Run the fake FR3 cell (domain from ROS_DOMAIN_ID).")
    parser.add_argument("--table-height", type=float, default=None, help="virtual table plane z [m] in the base frame")
    parser.add_argument("--goal-mode", choices=[m.value for m in GoalMode], default=GoalMode.ACCEPT.value)
    parser.add_argument("--torque-noise", type=float, default=0.0,
                        help="standard deviation [N·m] of Gaussian noise on the joint states' efforts")
    parser.add_argument("--torque-noise-seed", type=int, default=0, help="seed of that noise")
    parser.add_argument("--journal", type=Path, default=None, metavar="FILE",
                        help="append one JSON line per goal, switch or recovery accepted (what `armwarden eval` counts)")
    args = parser.parse_args(argv)
    # the daemon's own defaults (domain 0, LOCALHOST), so that both meet with nothing set
    dds = dds_settings(None, os.environ)
    dds.apply(os.environ)
    os.environ["ROS_DOMAIN_ID"] = str(dds.domain_id)
    print(f"fake FR3 cell: {dds.describe()}; start the daemon with the same", file=sys.stderr, flush=True)
    config = CellConfig(table_height_m=args.table_height, goal_mode=GoalMode(args.goal_mode),
                        torque_noise_nm=args.torque_noise, torque_noise_seed=args.torque_noise_seed)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    with Cell(config, hard_death=True, journal=args.journal):
        print(f"{READY}: ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}", flush=True)
        # a timed wait: the kernel may deliver SIGTERM to one of rclpy's or DDS's threads, and then
        # Python runs the handler only when the main thread next executes bytecode; an untimed wait
        # would never wake for it
        while not stop.wait(0.1):
            pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
