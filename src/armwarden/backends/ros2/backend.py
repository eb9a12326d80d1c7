"""The ROS 2 backend: a ros2_control arm through standard interfaces, over real rclpy.

State: `sensor_msgs/JointState` name-matched to the policy's joints (config `joints` maps names
that differ), judged fresh by receipt time; older than `joint_states.max_age_s` and reads refuse,
naming the age (`get_robot_state` errors rather than lying). With `joint_states.efforts` the
message's `effort` is the measured joint torque, carried in the same `JointState` (one sample,
one stamp, so it ages exactly as the positions do) and declared as the cell's `joint_torques`.
The wrench (`WrenchStamped`, best-effort QoS) is stamped with the receipt time of its last *new*
header stamp, so a frozen driver ages like a silent one and the Guard's force monitor aborts.

Parts it composes: the arm's motion, trajectory goals or the topic fallback and their stops
(`arm.py`), and the cell's parts (`self.cell`, `armwarden.backends.parts`): the gripper
(`gripper.py`), the cameras (`cameras.py`), the wrench topic's fresh sample, the controller
manager and error recovery (`controllers.py`), the graph (`graph.py`) and the tf frame tree
(`tf.py`); it keeps the state caches, the endpoints and the fault watch they share.

Stops (`_stop_now`, any thread, never awaiting): cancel the running goal (or publish the hold),
cancel the gripper's goal, and record when the cancel request was sent (`stop_records`). Faults
(joint states stop for longer than `max_age_s`, the action server vanishes), found by the idle
watchdog or by a running execution's own look, whichever comes first, stop the same way, are
recorded and are reported once through the fault listener (the Guard latches its e-stop); a
running execution then ends in `BackendError` naming the recorded fault, so the message does not
depend on which thread looked first (on a loaded machine either may). Closing ends a running
execution as "stopped", whatever answer the cell sends to the close's cancel.

The guardian (`guardian.py`, `guardian_link.py`; config `guardian`, action mode only): a process
of its own, started by open, told each goal before it is sent, that cancels it if the daemon dies
or stops beating; its exit is a fault for good (`_health_problem`) and no goal is sent without it.

Open waits (`joint_states.startup_timeout_s`) for the first arm joint state, and for the first
finger state and wrench when those are configured, so reads right after open find them.

Threads: every callback runs on the bridge's executor thread, which owns the rclpy entities
(`armwarden.backends.ros2.bridge`): the endpoints are made before it spins, a camera's
subscription is made and destroyed on it (`armwarden.backends.ros2.cameras`). Its death is a fault
for good: the goal cancelled, the fault reported once (the Guard latches and records it), every
later call but stop and close refused naming it. So is its hang (a callback that never returns):
the backend's watchdog, on a thread of its own, finds the bridge's heartbeat stopped, and the goal
is cancelled from there (a cancel request needs no executor). While the executor is quiet, joint
states that stop arriving say nothing about the cell (nobody takes them in), so no cell fault is
found then: the watchdog names the cause. When the force monitor finds the wrench stale,
`fault_behind_stale_data` tells a dead cell (its joint states stop too) from a wrench topic alone.

Declared accuracies: `goal_accuracy_rad` 1e-3 rad, `hold_accuracy_rad` 2e-3 rad, `rest_speed_rad_s`
1e-3 rad/s. A ros2_control position controller ends within its goal tolerance and a cancelled one
holds where the cancel reached it. The test cell ends exactly at the goal and publishes exact zero
velocities at rest; a cancel reaches its 10 ms loop at most one period late, and the joint state a
stop reads is at most one 10 ms period old, so at the contract's 0.05 rad/s the arm rests within
0.05 × (10 + 10 + DDS latency) ms ≈ 1–2e-3 rad of where the stop read it. A real arm with looser
goal tolerances, or faster motions, needs larger values (see docs/backends/ros2.md).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from typing import TYPE_CHECKING

import anyio

from armwarden.backends.base import Backend
from armwarden.backends.parts import Cell, PublishedWrench
from armwarden.backends.ros2.action_client import wait_for_server
from armwarden.backends.ros2.arm import POLL_S, Ros2Arm
from armwarden.backends.ros2.bridge import HEARTBEAT_PERIOD_S, ExecutorFactory, RosBridge
from armwarden.backends.ros2.cameras import Ros2Cameras
from armwarden.backends.ros2.config import Config, check_against_policy, resolve_robot_names, resolved
from armwarden.backends.ros2.controllers import Ros2Controllers, Ros2ErrorRecovery, ServiceCalls
from armwarden.backends.ros2.endpoints import Endpoints, Streams, create_endpoints
from armwarden.backends.ros2.graph import Ros2Graph
from armwarden.backends.ros2.gripper import Ros2Gripper
from armwarden.backends.ros2.guardian_link import GuardianLink
from armwarden.backends.ros2.runs import Fault, StopRecord
from armwarden.backends.ros2.state import JointStateCache, WrenchCache, wait_for_first_samples
from armwarden.backends.ros2.tf import TfFrames, TransformBuffer
from armwarden.backends.values import ExecutionResult, ProgressCallback
from armwarden.backends.watchdog import Heartbeat, stall_deadline_s
from armwarden.core.errors import BackendError
from armwarden.core.state import JointState
from armwarden.core.trajectory import JointTrajectory
from armwarden.robot.model import RobotModel

if TYPE_CHECKING:
    from armwarden.policy import Policy

logger = logging.getLogger(__name__)

#: how often the idle watchdog looks at the joint states and the action server [s]
WATCH_PERIOD_S = 0.05
#: an executor quiet this long [s] may hang: silence on its topics is not then blamed on the cell
EXECUTOR_QUIET_S = 5 * HEARTBEAT_PERIOD_S


class Ros2Backend(Backend):
    """A ros2_control arm over rclpy (see the module docstring)."""

    name = "ros2"
    worker_threads = ("executor",)  # rclpy's executor: every subscription, action and service callback
    reports_motion_events = True  # the arm reports them under its motion lock (arm.py)
    goal_accuracy_rad = 1e-3
    hold_accuracy_rad = 2e-3
    rest_speed_rad_s = 1e-3

    def __init__(self, robot: RobotModel, config: Config, ros_names: tuple[str, ...], *,
                 start_tolerance_rad: float, executor_factory: ExecutorFactory | None = None) -> None:
        super().__init__(robot.joint_names, start_tolerance_rad=start_tolerance_rad)
        self.config = config
        self.ros_names = ros_names
        # another executor only to measure it (scripts/bench.py ros2): every part is built on this bridge
        self.bridge = (RosBridge(config.node_name, config.domain_id) if executor_factory is None
                       else RosBridge(config.node_name, config.domain_id, executor_factory))
        self.joint_states = JointStateCache(config.joint_states.topic, robot.joint_names, ros_names,
                                            config.joint_states.max_age_s, efforts=config.joint_states.efforts)
        self.wrench = None if config.wrench is None else WrenchCache(
            config.wrench.topic, config.wrench.max_age_s, config.wrench.frame_id)
        gripper = config.gripper
        self.fingers = None if gripper is None else JointStateCache(
            resolved(gripper.joint_states_topic, "gripper.joint_states_topic"),
            resolved(gripper.finger_joints, "gripper.finger_joints"),
            resolved(gripper.finger_joints, "gripper.finger_joints"), gripper.max_age_s)
        self.transforms = TransformBuffer(config.tf.max_age_s) if config.tf.enabled else None
        self._endpoints = Endpoints()
        self._motion_lock = threading.Lock()  # sending a goal vs any stop, from any thread
        #: the stops carried out, newest last (the benchmark reads e-stop -> cancel sent)
        self.stop_records: deque[StopRecord] = deque(maxlen=1000)
        self.arm = Ros2Arm(self.bridge, self._endpoints, config.trajectory, self.joint_states, ros_names,
                           self._motion_lock, self.stop_records, lambda: self.is_open, self._stop_landed,
                           lambda: self._stop_epoch, self._abort_on_fault, self.goal_accuracy_rad,
                           self.rest_speed_rad_s, lambda: self.arm_state, self._arm_event)
        self.guardian: GuardianLink | None = None  # while open, in action mode with `config.guardian`
        self._fault_lock = threading.Lock()
        self._fault_active = False  # a fault was reported and the cell has not been healthy since
        self._last_fault: Fault | None = None  # the latest fault found (executions name it)
        #: the camera part, typed (its feeds are made at open, on the bridge that opens)
        self.cameras = Ros2Cameras(config.cameras, self._require_spinning) if config.cameras else None
        services = ServiceCalls(self.bridge, self._endpoints)
        wrench = self.wrench
        self.cell = Cell(
            gripper=None if gripper is None or self.fingers is None else Ros2Gripper(
                self.bridge, self._endpoints, gripper, self.fingers, self._motion_lock, self.stop_records,
                self._gripper_stop_landed, lambda: self._gripper_epoch),
            cameras=self.cameras,
            wrench=None if wrench is None else PublishedWrench(wrench.fresh),
            controllers=None if config.controller_manager is None else Ros2Controllers(services,
                                                                                        config.controller_manager),
            error_recovery=None if config.error_recovery is None else Ros2ErrorRecovery(services),
            graph=Ros2Graph(self.bridge),
            transforms=None if self.transforms is None else TfFrames(self.transforms),
            joint_torques=config.joint_states.efforts,
        )

    # ================================================================ lifecycle
    async def _open(self) -> None:
        if self.cameras is not None:
            self.cameras.open(self.bridge)
        self.bridge.on_death = lambda error: self._worker_died("executor", error)
        await anyio.to_thread.run_sync(self.bridge.start, self._create_endpoints)  # made before it spins
        for cache in (self.joint_states, self.fingers, self.wrench):
            if cache is not None:
                cache.network = self.bridge.dds  # named when nothing arrives: most often another domain
        try:
            await wait_for_first_samples(self.joint_states, self.fingers, self.wrench,
                                         self.config.joint_states.startup_timeout_s, self.bridge.dds,
                                         self._require_spinning)
            await self._start_guardian()
        except BaseException:
            with anyio.CancelScope(shield=True):
                await anyio.to_thread.run_sync(self.bridge.close)
            raise

    async def _start_guardian(self) -> None:
        """The guardian process, when the config has one and goals go through the action."""
        config, action = self.config.guardian, self.arm.config.action
        if config is None or action is None or self._endpoints.trajectory_action is None:
            return
        guardian = GuardianLink(action, config.deadline_s, self.bridge.dds.domain_id if self.bridge.dds else None,
                                self._fault)
        await anyio.to_thread.run_sync(guardian.start, config.start_timeout_s)
        self.guardian = guardian
        self.arm.on_goal = lambda goal: guardian.idle() if goal is None else guardian.goal(goal)

    def _create_endpoints(self) -> None:
        """The endpoints that live as long as the node, made before the executor spins (see
        `armwarden.backends.ros2.bridge`: the executor thread owns the entities)."""
        create_endpoints(self._endpoints, self.bridge, self.config, Streams(self.joint_states, self.wrench, self.fingers,
                         self.transforms), self._watch, WATCH_PERIOD_S)

    async def _close(self) -> None:
        if self.guardian is not None:
            self.guardian.expect_exit()
        try:
            await anyio.to_thread.run_sync(self.bridge.close)
        finally:  # after the bridge's own cancel of a running goal: the guardian then leaves quietly
            if self.guardian is not None:
                self.guardian.close()  # one non-blocking write: no thread needed

    def _worker_heartbeats(self) -> tuple[Heartbeat, ...]:
        return (Heartbeat("executor", lambda: self.bridge.heartbeats, stall_deadline_s(HEARTBEAT_PERIOD_S)),)

    # ================================================================ state
    def _latest_joint_state(self) -> JointState:
        return self.joint_states.fresh()

    async def _read_joint_state(self) -> JointState:
        return self.joint_states.fresh()

    # ================================================================ watchdog (executor thread)
    def _health_problem(self) -> str | None:
        """What is wrong with the cell right now (joint states stopped, action server gone), or None
        (also while the executor is quiet: then it may be the cause, see the module docstring)."""
        if self._worker_quiet_s("executor") > EXECUTOR_QUIET_S:
            return None
        if self.guardian is not None and self.guardian.problem is not None:
            return self.guardian.problem
        age = self.joint_states.age_s()
        limit = self.config.joint_states.max_age_s
        if age is None or age > limit:
            shown = "never received" if age is None else f"{age:.2f} s old"
            return f"joint states on {self.joint_states.topic} stopped arriving ({shown}, limit {limit:g} s)"
        action = self._endpoints.trajectory_action
        if action is not None:
            ready = action.server_is_ready()
            if ready:
                self.arm.server_seen = True
            elif self.arm.server_seen:
                return f"the trajectory action server {self.config.trajectory.action} vanished"
        return None

    def _require_spinning(self) -> None:
        """`BackendError` naming a dead executor thread (nothing arrives without it)."""
        if not self.bridge.spinning:
            raise BackendError(self.worker_failure or "ros2 backend: the ROS executor thread is not running")

    def _watch(self) -> None:
        """Executor thread: a fault found while open is stopped and reported once (until healthy)."""
        self._worker_checkpoint("executor")  # the test seam: an injected failure ends the executor here
        if not self.is_open:
            return
        try:
            problem = self._health_problem()
        except Exception:  # the node is going away under a closing backend
            logger.debug("ros2 watchdog: health check failed", exc_info=True)
            return
        if problem is None:
            with self._fault_lock:
                self._fault_active = False
            return
        self._fault(problem)

    def _fault(self, problem: str) -> None:
        """Any thread: stop for `problem` and report it, once until the cell is healthy again.
        The watchdog and a running execution both call it, whichever looks first; the execution
        then ends naming the recorded fault (`_abort_on_fault`), so the message does not depend on
        which check fired first."""
        with self._fault_lock:
            if self._fault_active:
                return
            self._fault_active = True
            self._last_fault = Fault(problem, self.stop_epoch)
        self._bump_stop_epoch()
        try:
            self._stop_now()
        except Exception:
            logger.exception("ros2 backend: stop after a fault failed")
        self._report_fault(f"ros2 backend fault: {problem}")

    async def _fault_behind_stale_data(self) -> str | None:
        """Whether the cell is why the data stopped (the Guard asks once the force monitor found no
        usable wrench and stopped the arm): a fault already found, one found now, or else the joint
        states are watched until they either move on (the cell lives: None, the wrench alone is
        stale) or age past `joint_states.max_age_s` (the cell is gone: its fault, reported like the
        watchdog's). A dead cell stops both streams at once, so this takes at most that age."""
        deadline = time.monotonic() + self.config.joint_states.max_age_s + WATCH_PERIOD_S
        seen = self.joint_states.latest_header_s()
        while True:
            if (failure := self.worker_failure) is not None:
                return failure
            with self._fault_lock:
                found = self._last_fault if self._fault_active else None
            if found is not None:
                return f"ros2 backend fault: {found.problem}"
            problem = self._health_problem()
            if problem is not None:
                self._fault(problem)
                return f"ros2 backend fault: {problem}"
            if self.joint_states.latest_header_s() != seen or time.monotonic() > deadline:
                return None
            await anyio.sleep(POLL_S)

    def _abort_on_fault(self, epoch: int, sent: str) -> None:
        """Event loop, during an execution decided under stop epoch `epoch`: look at the cell's
        health; if a fault was found since (now, or already by the watchdog), raise `BackendError`
        naming it (`sent`: what stopped the arm, for the message)."""
        if (failure := self.worker_failure) is not None:  # the executor died: no result or state will come
            raise BackendError(f"execution aborted: {failure}; {sent}")
        problem = self._health_problem()
        if problem is not None:
            self._fault(problem)
        fault = self._last_fault
        if fault is not None and fault.epoch >= epoch:
            raise BackendError(f"execution aborted: {fault.problem}; {sent}")

    # ================================================================ motion and stops
    async def _execute(self, trajectory: JointTrajectory, progress: ProgressCallback) -> ExecutionResult:
        guardian = self.guardian
        if guardian is not None:
            if guardian.problem is not None:
                raise BackendError(f"{guardian.problem}; nothing was sent")
            timeout_s = self.config.trajectory.server_timeout_s
            action = self._endpoints.trajectory_action
            if action is not None:  # the server first: an absent one is refused as such, nothing sent
                await wait_for_server(action, self.arm.interface, timeout_s)
            if not await anyio.to_thread.run_sync(guardian.wait_watching, timeout_s, abandon_on_cancel=True):
                raise BackendError(f"the ROS 2 guardian process has not found the cancel service of "
                                   f"{self.arm.interface} within {timeout_s:g} s: a goal it could not cancel is "
                                   "not sent; nothing was sent")
        return await self.arm.execute(trajectory, progress, self._execution_epoch)

    async def _stop(self) -> None:
        self._stop_now()

    def _stop_now(self) -> None:
        """Any thread, never awaiting: cancel the running goal (or hold), cancel the gripper's goal."""
        try:
            self.arm.stop()
        finally:  # the gripper's goal is cancelled even if the arm's cancel or hold failed
            self._stop_fingers()

    # ================================================================ frames
    def tf_frames(self) -> tuple[str, ...]:
        """Frames seen on /tf and /tf_static so far."""
        return () if self.transforms is None else self.transforms.frames()

    # ================================================================ diagnostics
    @property
    def last_cancel_stamp(self) -> float | None:
        """Monotonic time [s] the latest cancel request (or topic hold) was sent; None: none yet."""
        return self.stop_records[-1].stamp if self.stop_records else None


def create_backend(robot: RobotModel, policy: Policy, config: Config, *,
                   executor_factory: ExecutorFactory | None = None) -> Ros2Backend:
    """Registry factory: the ROS 2 backend for `policy`'s joints, named as `config` says
    (`executor_factory`: another rclpy executor, for the bench that compares them)."""
    config = resolve_robot_names(config, policy.robot.description)
    ros_names = check_against_policy(config, tuple(policy.robot.joint_names))
    return Ros2Backend(robot, config, ros_names, start_tolerance_rad=policy.motion.start_tolerance_rad,
                       executor_factory=executor_factory)


__all__ = ["Ros2Backend", "create_backend"]
