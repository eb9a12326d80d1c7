"""The ROS 2 backend: a ros2_control arm through standard interfaces, over real rclpy.

State: `sensor_msgs/JointState` name-matched to the policy's joints (config `joints` maps names
that differ), judged fresh by receipt time; older than `joint_states.max_age_s` and reads refuse,
naming the age (`get_robot_state` errors rather than lying). The wrench (`WrenchStamped`,
best-effort QoS) is stamped with the receipt time of its last *new* header stamp, so a frozen
driver ages like a silent one and the Guard's force monitor aborts.

Execution (`control_msgs/FollowJointTrajectory`): the goal is exactly the validated waypoints and
their times (positions only: the controller interpolates linearly between them, as the envelope
sampled them). The goal is sent under the motion lock the stops take, after a last look at the
stop epoch: either a stop came first and nothing is sent, or the goal was sent and the stop
cancels it (by goal id, before the server has even answered if need be; a goal accepted after a
stop is cancelled again when its acceptance arrives). Rejection, an error code, no answer, no
result within the trajectory's duration + `result_margin_s` (cancel, "controller timeout"), joint
states that stop or an action server that vanishes mid-motion (cancel, fault) all end in
`BackendError` naming the cause. Progress comes from the feedback's trajectory time.

Fallback (`trajectory.topic`): the trajectory is published as `trajectory_msgs/JointTrajectory`;
it has completed when its time is up and the joint states are at the goal; a stop publishes a
one-point hold at the measured positions (Jazzy's controller rejects an empty trajectory).

Stops (`_stop_now`, any thread, never awaiting): cancel the running goal (or publish the hold),
cancel the gripper's goal, and record when the cancel request was sent (`stop_records`). Faults
(joint states stop for longer than `max_age_s`, the action server vanishes), found by the idle
watchdog or by a running execution's own look, whichever comes first, stop the same way, are
recorded and are reported once through the fault listener (the Guard latches its e-stop); a
running execution then ends in `BackendError` naming the recorded fault, so the message does not
depend on which thread looked first (on a loaded machine either may). Closing ends a running
execution as "stopped", whatever answer the cell sends to the close's cancel.

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

import asyncio
import contextlib
import logging
import threading
import time
from collections import deque
from typing import TYPE_CHECKING, Any

import anyio
import numpy as np
import rclpy.action.client
import rclpy.action.graph
import rclpy.client
import rclpy.publisher
import rclpy.qos
import rclpy.subscription
import rclpy.timer
from action_msgs.msg import GoalStatus
from control_msgs.action import FollowJointTrajectory, GripperCommand
from controller_manager_msgs.srv import ListControllers, SwitchController
from geometry_msgs.msg import WrenchStamped
from sensor_msgs.msg import CompressedImage, Image
from sensor_msgs.msg import JointState as JointStateMsg
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage
from trajectory_msgs.msg import JointTrajectory as JointTrajectoryMsg

from armwarden.backends.base import Backend, Capabilities
from armwarden.backends.ros2.action_client import STATUS_NAMES, ActionClient, wait_for_server
from armwarden.backends.ros2.bridge import HEARTBEAT_PERIOD_S, RosBridge
from armwarden.backends.ros2.cameras import CameraFeed
from armwarden.backends.ros2.config import Config, check_against_policy, resolve_robot_names, resolved
from armwarden.backends.ros2.controllers import Ros2Controllers
from armwarden.backends.ros2.gripper import Ros2Gripper
from armwarden.backends.ros2.images import png_from_compressed, png_from_image
from armwarden.backends.ros2.runs import (
    Endpoints,
    Fault,
    GoalRun,
    StopRecord,
    TopicRun,
    hold_message,
    new_goal_id,
    trajectory_message,
)
from armwarden.backends.ros2.state import JointStateCache, WrenchCache, nothing_heard
from armwarden.backends.ros2.tf import TransformBuffer
from armwarden.backends.values import PREEMPTED, CameraImage, ControllerInfo, ExecutionResult, GripperResult, ProgressCallback
from armwarden.backends.watchdog import Heartbeat, stall_deadline_s
from armwarden.core.errors import BackendError
from armwarden.core.state import GripperState, JointState, Transform, Wrench
from armwarden.core.trajectory import JointTrajectory
from armwarden.robot.model import RobotModel

if TYPE_CHECKING:
    from armwarden.policy import Policy

logger = logging.getLogger(__name__)

#: how often a waiting execution looks at the stop epoch, progress, health and deadlines [s]
POLL_S = 0.01
#: how often the idle watchdog looks at the joint states and the action server [s]
WATCH_PERIOD_S = 0.05
#: how long a stopped execution waits for the arm to come to rest [s]
REST_TIMEOUT_S = 2.0
#: an executor quiet this long [s] may hang: silence on its topics is not then blamed on the cell
EXECUTOR_QUIET_S = 5 * HEARTBEAT_PERIOD_S
#: what stopped the arm when a fault aborts an execution, for messages
CANCELLED, ENDED, HELD = "the goal was cancelled", "the goal had ended", "a hold was sent"
#: FollowJointTrajectory.Result error codes by value, for messages
ERROR_CODES = {getattr(FollowJointTrajectory.Result, name): name for name in (
    "SUCCESSFUL", "INVALID_GOAL", "INVALID_JOINTS", "OLD_HEADER_TIMESTAMP", "PATH_TOLERANCE_VIOLATED",
    "GOAL_TOLERANCE_VIOLATED")}


class Ros2Backend(Backend):
    """A ros2_control arm over rclpy (see the module docstring)."""

    name = "ros2"
    worker_threads = ("executor",)  # rclpy's executor: every subscription, action and service callback
    goal_accuracy_rad = 1e-3
    hold_accuracy_rad = 2e-3
    rest_speed_rad_s = 1e-3

    def __init__(self, robot: RobotModel, config: Config, ros_names: tuple[str, ...], *,
                 start_tolerance_rad: float) -> None:
        super().__init__(robot.joint_names, start_tolerance_rad=start_tolerance_rad)
        self.config = config
        self.ros_names = ros_names
        self.bridge = RosBridge(config.node_name, config.domain_id)
        self.joint_states = JointStateCache(config.joint_states.topic, robot.joint_names, ros_names,
                                            config.joint_states.max_age_s)
        self.wrench = None if config.wrench is None else WrenchCache(
            config.wrench.topic, config.wrench.max_age_s, config.wrench.frame_id)
        gripper = config.gripper
        self.fingers = None if gripper is None else JointStateCache(
            resolved(gripper.joint_states_topic, "gripper.joint_states_topic"),
            resolved(gripper.finger_joints, "gripper.finger_joints"),
            resolved(gripper.finger_joints, "gripper.finger_joints"), gripper.max_age_s)
        self.transforms = TransformBuffer(config.tf.max_age_s) if config.tf.enabled else None
        self._endpoints = Endpoints()
        self.controllers = Ros2Controllers(self.bridge, self._endpoints, config.controller_manager)
        self._motion_lock = threading.Lock()  # sending a goal vs any stop, from any thread
        self._run: GoalRun | TopicRun | None = None
        #: the stops carried out, newest last (the benchmark reads e-stop -> cancel sent)
        self.stop_records: deque[StopRecord] = deque(maxlen=1000)
        self.gripper = None if gripper is None or self.fingers is None else Ros2Gripper(
            self.bridge, self._endpoints, gripper, self.fingers, self._motion_lock, self.stop_records,
            self._gripper_stop_landed, lambda: self._gripper_epoch)
        self._server_seen = False  # the trajectory action server was seen at least once
        self._fault_lock = threading.Lock()
        self._fault_active = False  # a fault was reported and the cell has not been healthy since
        self._last_fault: Fault | None = None  # the latest fault found (executions name it)
        if gripper is not None:
            self.gripper_travel_m = gripper.max_width_m
        if config.cameras:
            self.camera_timeout_s = max(c.timeout_s for c in config.cameras.values()) + 0.5
        self._cameras: dict[str, CameraFeed] = {}  # made at open, on the bridge that opens
        self._capabilities = Capabilities(
            wrench=config.wrench is not None,
            gripper=gripper is not None,
            cameras=tuple(config.cameras),
            controllers=config.controller_manager is not None,
            error_recovery=config.error_recovery is not None,
            graph=True,
            transforms=self.transforms is not None,
        )

    @property
    def capabilities(self) -> Capabilities:
        return self._capabilities

    @property
    def trajectory_interface(self) -> str:
        """The action or topic trajectories go to, for messages."""
        trajectory = self.config.trajectory
        return trajectory.action if trajectory.action is not None else f"topic {trajectory.topic}"

    # ================================================================ lifecycle
    async def _open(self) -> None:
        image_qos = rclpy.qos.QoSProfile(depth=1, reliability=rclpy.qos.ReliabilityPolicy.BEST_EFFORT)
        self._cameras = {name: CameraFeed(self.bridge, spec.topic, CompressedImage if spec.kind == "compressed" else Image,
                                          image_qos) for name, spec in self.config.cameras.items()}
        self.bridge.on_death = lambda error: self._worker_died("executor", error)
        await anyio.to_thread.run_sync(self.bridge.start, self._create_endpoints)  # made before it spins
        for cache in (self.joint_states, self.fingers, self.wrench):
            if cache is not None:
                cache.network = self.bridge.dds  # named when nothing arrives: most often another domain
        try:
            await self._wait_for_first_state()
        except BaseException:
            with anyio.CancelScope(shield=True):
                await anyio.to_thread.run_sync(self.bridge.close)
            raise

    def _create_endpoints(self) -> None:
        """The endpoints that live as long as the node, made before the executor spins (see
        `armwarden.backends.ros2.bridge`: the executor thread owns the entities)."""
        node, group, cfg, e = self.bridge.node, self.bridge.group, self.config, self._endpoints
        subscribe = e.subscriptions.append
        subscribe(node.create_subscription(JointStateMsg, cfg.joint_states.topic, self.joint_states.accept, 10,
                                           callback_group=group))
        if self.wrench is not None:
            best_effort = rclpy.qos.QoSProfile(depth=10, reliability=rclpy.qos.ReliabilityPolicy.BEST_EFFORT)
            subscribe(node.create_subscription(WrenchStamped, self.wrench.topic, self.wrench.accept, best_effort,
                                               callback_group=group))
        if self.fingers is not None:
            subscribe(node.create_subscription(JointStateMsg, self.fingers.topic, self.fingers.accept, 10,
                                               callback_group=group))
        if self.transforms is not None:
            transforms = self.transforms
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
        e.watchdog = node.create_timer(WATCH_PERIOD_S, self._watch, callback_group=group)

    async def _wait_for_first_state(self) -> None:
        """Open ends once the arm's joint states (and the fingers' and the wrench, when configured)
        have arrived: reads right after open must not find a stream not yet discovered."""
        timeout_s = self.config.joint_states.startup_timeout_s
        deadline = time.monotonic() + timeout_s
        for cache in (self.joint_states, self.fingers):
            while cache is not None and cache.latest() is None:
                self._require_spinning()
                if time.monotonic() > deadline:
                    why = f" ({cache.last_drop})" if cache.dropped else ""
                    raise BackendError(f"no joint state naming {', '.join(cache.ros_names)} arrived on "
                                       f"{cache.topic} within {timeout_s:g} s{why}{nothing_heard(self.bridge.dds)}")
                await anyio.sleep(POLL_S)
        while self.wrench is not None and not self.wrench.received:
            if time.monotonic() > deadline:
                raise BackendError(f"no wrench arrived on {self.wrench.topic} within {timeout_s:g} s"
                                   f"{nothing_heard(self.bridge.dds)}")
            await anyio.sleep(POLL_S)

    async def _close(self) -> None:
        await anyio.to_thread.run_sync(self.bridge.close)

    def _worker_heartbeats(self) -> tuple[Heartbeat, ...]:
        return (Heartbeat("executor", lambda: self.bridge.heartbeats, stall_deadline_s(HEARTBEAT_PERIOD_S)),)

    # ================================================================ state
    def _latest_joint_state(self) -> JointState:
        return self.joint_states.fresh()

    async def _read_joint_state(self) -> JointState:
        return self.joint_states.fresh()

    def _latest_wrench(self) -> Wrench | None:
        return None if self.wrench is None else self.wrench.fresh()

    async def _read_wrench(self) -> Wrench | None:
        return self._latest_wrench()

    # ================================================================ watchdog (executor thread)
    def _health_problem(self) -> str | None:
        """What is wrong with the cell right now (joint states stopped, action server gone), or None
        (also while the executor is quiet: then it may be the cause, see the module docstring)."""
        if self._worker_quiet_s("executor") > EXECUTOR_QUIET_S:
            return None
        age = self.joint_states.age_s()
        limit = self.config.joint_states.max_age_s
        if age is None or age > limit:
            shown = "never received" if age is None else f"{age:.2f} s old"
            return f"joint states on {self.joint_states.topic} stopped arriving ({shown}, limit {limit:g} s)"
        action = self._endpoints.trajectory_action
        if action is not None:
            ready = action.server_is_ready()
            if ready:
                self._server_seen = True
            elif self._server_seen:
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

    # ================================================================ motion
    async def _execute(self, trajectory: JointTrajectory, progress: ProgressCallback) -> ExecutionResult:
        if self._endpoints.trajectory_action is not None:
            return await self._execute_action(self._endpoints.trajectory_action, trajectory, progress)
        return await self._execute_topic(trajectory, progress)


    async def _execute_action(self, action: rclpy.action.client.ActionClient, trajectory: JointTrajectory,
                              progress: ProgressCallback) -> ExecutionResult:
        cfg = self.config.trajectory
        name = self.trajectory_interface
        await wait_for_server(action, name, cfg.server_timeout_s)
        self._server_seen = True
        goal = FollowJointTrajectory.Goal(trajectory=trajectory_message(trajectory, self.ros_names))
        with self._motion_lock:  # the stops take it: a stop is either before the send or cancels it
            if self._stop_landed():
                return ExecutionResult(False, PREEMPTED, self.joint_states.fresh().positions.copy())
            run = GoalRun(new_goal_id(), self._execution_epoch, trajectory.duration_s, time.monotonic())
            self._run = run
            sending = action.send_goal_async(goal, feedback_callback=run.on_feedback, goal_uuid=run.goal_id)
        sending.add_done_callback(lambda future: self._on_goal_response(run, future))
        try:
            try:
                handle = await self.bridge.result(sending, cfg.goal_response_timeout_s)
            except TimeoutError:
                raise BackendError(f"{name} did not answer the trajectory goal within "
                                   f"{cfg.goal_response_timeout_s:g} s; a cancel was sent") from None
            if not handle.accepted:
                run.terminal = True
                raise BackendError(f"the trajectory goal was rejected by {name} (nothing moved)")
            return await self._follow_goal(run, handle, trajectory, progress)
        finally:
            if not run.terminal:  # error, timeout or cancellation of this task: the goal must not run on
                self._cancel_goal(run)
            with self._motion_lock:
                if self._run is run:
                    self._run = None

    def _on_goal_response(self, run: GoalRun, future: Any) -> None:
        """Executor thread: note the handle; a goal accepted after a stop is cancelled now."""
        if future.exception() is not None:
            return
        handle = future.result()
        with self._motion_lock:
            run.handle = handle
            stopped_meanwhile = run.cancel_sent or self._stop_epoch != run.epoch
        if handle.accepted and stopped_meanwhile:
            self._cancel_goal(run, again=True)

    def _cancel_goal(self, run: GoalRun, *, again: bool = False) -> None:
        """Any thread, without waiting: ask the server to cancel `run`'s goal (by id, so it works
        before the goal was even answered). Sent once, plus once more on a late acceptance."""
        action = self._endpoints.trajectory_action
        if action is None or run.terminal or (run.cancel_sent and not again):
            return
        run.cancel_sent = True
        handle = run.handle or rclpy.action.client.ClientGoalHandle(
            action, run.goal_id, FollowJointTrajectory.Impl.SendGoalService.Response())
        handle.cancel_goal_async()
        self.stop_records.append(StopRecord("cancel", time.monotonic()))

    async def _follow_goal(self, run: GoalRun, handle: rclpy.action.client.ClientGoalHandle,
                           trajectory: JointTrajectory, progress: ProgressCallback) -> ExecutionResult:
        """The goal was accepted: report progress until its result, a stop, a fault or the deadline."""
        cfg = self.config.trajectory
        name = self.trajectory_interface
        deadline = time.monotonic() + trajectory.duration_s + cfg.result_margin_s
        waiting = asyncio.ensure_future(self.bridge.result(handle.get_result_async(), None))
        reported = 0.0
        try:
            while not waiting.done():
                await asyncio.wait({waiting}, timeout=POLL_S)
                if waiting.done():
                    break
                if self._stopped(run.epoch, CANCELLED):
                    return await self._stopped_goal(run, waiting)
                fraction = min(run.fraction(), 0.99)  # 1.0 only once completed
                if fraction > reported:
                    reported = fraction
                    progress(fraction)
                if time.monotonic() > deadline:
                    self._cancel_goal(run)
                    raise BackendError(f"controller timeout: no result from {name} within "
                                       f"{trajectory.duration_s + cfg.result_margin_s:g} s (trajectory "
                                       f"{trajectory.duration_s:g} s + margin {cfg.result_margin_s:g} s); the goal was cancelled")
            if self._stopped(run.epoch, CANCELLED):  # the stop's cancel ended the goal
                run.terminal = True
                return await self._rest(run.epoch, CANCELLED)
            response = waiting.result()
        finally:
            if not waiting.done():
                waiting.cancel()
        run.terminal = True
        status, result = response.status, response.result
        if status == GoalStatus.STATUS_SUCCEEDED and result.error_code == FollowJointTrajectory.Result.SUCCESSFUL:
            settled = await self._settle(run.epoch, trajectory)
            if settled.completed:
                progress(1.0)
            return settled
        code = f"{ERROR_CODES.get(result.error_code, 'UNKNOWN')} ({result.error_code})"
        if status == GoalStatus.STATUS_ABORTED:
            raise BackendError(f"the trajectory was aborted by the controller ({name}): {code}: {result.error_string}")
        raise BackendError(f"the trajectory goal ended {STATUS_NAMES.get(status, status)} at {name} without a stop "
                           f"from here: {code}: {result.error_string}")

    def _state_during(self, epoch: int, sent: str) -> JointState:
        """Event loop: the fresh joint state during the execution decided under `epoch`; stale
        joint states there are a fault, named as the watchdog names it (`_abort_on_fault`)."""
        return self._measured_state_during(epoch, sent)[0]

    def _measured_state_during(self, epoch: int, sent: str) -> tuple[JointState, float]:
        """`_state_during`, with the sample's header stamp [s, the cell's clock]."""
        try:
            return self.joint_states.fresh_measured()
        except BackendError:
            self._abort_on_fault(epoch, sent)
            raise

    def _stopped(self, epoch: int, sent: str) -> bool:
        """Event loop: whether the execution decided under `epoch` must end as stopped — a stop
        landed, or the backend is closing (its stop does not bump the epoch). A fault found by
        then, by the watchdog or by this look, raises instead (`_abort_on_fault`)."""
        if not self.is_open:
            return True
        self._abort_on_fault(epoch, sent)
        return self._stop_landed()

    async def _stopped_goal(self, run: GoalRun, waiting: asyncio.Future[Any]) -> ExecutionResult:
        """A stop cancelled the goal: wait (bounded) for its result, then for the arm to rest."""
        self._cancel_goal(run)  # the stop sent it already; this only covers a stop that found no run
        if self.is_open:
            with contextlib.suppress(Exception):  # the result or its absence; a closing node fails it
                await asyncio.wait_for(asyncio.shield(waiting), self.config.trajectory.goal_response_timeout_s)
            run.terminal = run.terminal or waiting.done()
        return await self._rest(run.epoch, CANCELLED)

    async def _settle(self, epoch: int, trajectory: JointTrajectory) -> ExecutionResult:
        """The controller reports success: the joint states must show the goal (within
        `goal_accuracy_rad`) and rest, within `result_margin_s`."""
        goal = trajectory.goal
        deadline = time.monotonic() + self.config.trajectory.result_margin_s
        while True:
            if self._stopped(epoch, ENDED):
                return await self._rest(epoch, ENDED)
            state = self._state_during(epoch, ENDED)
            error = float(np.max(np.abs(state.positions - goal)))
            if error <= self.goal_accuracy_rad and np.max(np.abs(state.velocities)) <= self.rest_speed_rad_s:
                return ExecutionResult(True, "completed", state.positions.copy())
            if time.monotonic() > deadline:
                return ExecutionResult(False, f"the controller reported success but the arm is {error:.4f} rad from the "
                                       f"goal after {self.config.trajectory.result_margin_s:g} s", state.positions.copy())
            await anyio.sleep(POLL_S)

    async def _rest(self, epoch: int, sent: str, after: float | None = None, reason: str = "stopped",
                    measured_after: float | None = None) -> ExecutionResult:
        """Wait (bounded) until a joint state received after `after` (monotonic [s]; by default
        now, when the stop has been sent: a sample from before it may show the arm still at its
        start) and measured after `measured_after` (its header stamp [s, the cell's clock]; by
        default after the latest sample now: a backlog our executor reads late arrives "now" but
        was measured before the stop) shows the joints at rest; where they rest is the result. A
        fault meanwhile aborts the execution decided under `epoch` (`sent`: what stopped the arm)."""
        after = time.monotonic() if after is None else after
        if measured_after is None:
            measured_after = self.joint_states.latest_header_s()
        deadline = time.monotonic() + REST_TIMEOUT_S
        while True:
            if not self.is_open:  # closed under the execution: the stop was sent; report where it was
                latest = self.joint_states.latest()
                if latest is not None:
                    return ExecutionResult(False, reason, latest.positions.copy())
            else:
                self._abort_on_fault(epoch, sent)
            state, measured = self._measured_state_during(epoch, sent)
            resting = (state.stamp >= after and (measured_after is None or measured > measured_after)
                       and np.max(np.abs(state.velocities)) <= self.rest_speed_rad_s)
            if resting or time.monotonic() > deadline:
                return ExecutionResult(False, reason, state.positions.copy())
            await anyio.sleep(POLL_S)

    # ---------------------------------------------------------------- topic fallback
    async def _execute_topic(self, trajectory: JointTrajectory, progress: ProgressCallback) -> ExecutionResult:
        publisher = self._endpoints.trajectory_topic
        assert publisher is not None
        cfg = self.config.trajectory
        name = self.trajectory_interface
        if publisher.get_subscription_count() == 0:
            await self._wait_for_subscriber(publisher, name, cfg.server_timeout_s)
        message = trajectory_message(trajectory, self.ros_names)
        with self._motion_lock:
            if self._stop_landed():
                return ExecutionResult(False, PREEMPTED, self.joint_states.fresh().positions.copy())
            run = TopicRun(self._execution_epoch, trajectory.duration_s, time.monotonic(), trajectory)
            self._run = run
            publisher.publish(message)
        try:
            deadline = run.sent_at + trajectory.duration_s + cfg.result_margin_s
            reported = 0.0
            while True:
                await anyio.sleep(POLL_S)
                if self._stopped(run.epoch, HELD):
                    self._hold(run)  # the stop sent it already; this covers a close, which does not bump the epoch
                    hold_s = self.config.trajectory.hold_time_s
                    held_at = run.held_at if run.held_at is not None else time.monotonic()
                    measured = None if run.held_measured is None else run.held_measured + hold_s
                    return await self._rest(run.epoch, HELD, held_at + hold_s, measured_after=measured)
                elapsed = time.monotonic() - run.sent_at
                if elapsed >= trajectory.duration_s:
                    state = self._state_during(run.epoch, HELD)
                    at_goal = float(np.max(np.abs(state.positions - trajectory.goal))) <= self.goal_accuracy_rad
                    if at_goal and np.max(np.abs(state.velocities)) <= self.rest_speed_rad_s:
                        progress(1.0)
                        return ExecutionResult(True, "completed", state.positions.copy())
                elif trajectory.duration_s > 0 and (fraction := min(0.99, elapsed / trajectory.duration_s)) > reported:
                    reported = fraction
                    progress(fraction)
                if time.monotonic() > deadline:
                    self._hold(run)
                    raise BackendError(f"controller timeout: the joint states did not reach the goal within "
                                       f"{trajectory.duration_s + cfg.result_margin_s:g} s of publishing on {name}; a hold was sent")
        except BaseException:
            self._hold(run)
            raise
        finally:
            with self._motion_lock:
                if self._run is run:
                    self._run = None

    async def _wait_for_subscriber(self, publisher: rclpy.publisher.Publisher, name: str, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while publisher.get_subscription_count() == 0:
            if time.monotonic() > deadline:
                raise BackendError(f"nothing subscribes to {name} (waited {timeout_s:g} s); nothing was sent")
            await anyio.sleep(POLL_S)

    def _hold(self, run: TopicRun) -> None:
        """Any thread: publish a one-point hold (once per run) at the measured positions — or, when
        the latest joint state is older than the hold's own time (the states stopped or lag), at
        the published trajectory's setpoint for now, where the controller is driving the arm: a
        hold at a stale measurement would drive a moving arm back to where it was, fast."""
        publisher = self._endpoints.trajectory_topic
        if publisher is None or run.held_at is not None:
            return
        hold_s = self.config.trajectory.hold_time_s
        state, age = self.joint_states.latest_with_age()
        if state is not None and age is not None and age <= hold_s:
            positions = state.positions
        elif run.trajectory is not None:
            positions = run.trajectory.sample(time.monotonic() - run.sent_at)
        elif state is not None:
            positions = state.positions
        else:
            raise BackendError("cannot hold: no joint state to hold at")
        publisher.publish(hold_message(positions, self.ros_names, hold_s))
        run.held_at = time.monotonic()
        run.held_measured = self.joint_states.latest_header_s()
        self.stop_records.append(StopRecord("hold", run.held_at))

    # ================================================================ stops
    async def _stop(self) -> None:
        self._stop_now()

    def _stop_now(self) -> None:
        """Any thread, never awaiting: cancel the running goal (or hold), cancel the gripper's goal."""
        with self._motion_lock:
            run = self._run
        if isinstance(run, GoalRun):
            self._cancel_goal(run)
        elif isinstance(run, TopicRun):
            self._hold(run)
        self._stop_fingers()

    # ================================================================ gripper
    def _stop_fingers(self) -> None:
        if self.gripper is not None:
            self.gripper.stop()

    def _latest_gripper_state(self) -> GripperState:
        assert self.gripper is not None
        return self.gripper.state()

    async def _gripper_move(self, width_m: float, speed_mps: float) -> GripperResult:
        assert self.gripper is not None
        return await self.gripper.move(width_m, speed_mps)

    async def _gripper_grasp(self, width_m: float, force_n: float, speed_mps: float, epsilon_inner_m: float,
                             epsilon_outer_m: float) -> GripperResult:
        assert self.gripper is not None
        return await self.gripper.grasp(width_m, force_n, speed_mps, epsilon_inner_m, epsilon_outer_m)

    async def _gripper_home(self) -> GripperResult:
        assert self.gripper is not None
        return await self.gripper.home()

    # ================================================================ cameras
    async def _camera_snapshot(self, camera: str) -> CameraImage:
        """The next image on the camera's topic (subscribed only while snapshots wait, by the
        executor thread: `armwarden.backends.ros2.cameras`)."""
        spec = self.config.cameras[camera]
        try:
            msg = await self._cameras[camera].next_message(spec.timeout_s)
        except TimeoutError:
            self._require_spinning()  # a dead executor is why, not the camera
            raise BackendError(f"camera {camera!r}: no image on {spec.topic} within {spec.timeout_s:g} s") from None
        width, height, png = png_from_compressed(msg) if spec.kind == "compressed" else png_from_image(msg)
        return CameraImage(camera, width, height, png, time.monotonic())

    # ================================================================ controllers and recovery
    async def _list_controllers(self) -> list[ControllerInfo]:
        return await self.controllers.list(self.controllers_timeout_s)

    async def _switch_controllers(self, activate: tuple[str, ...], deactivate: tuple[str, ...]) -> None:
        await self.controllers.switch(activate, deactivate, self.controllers_timeout_s)

    async def _error_recovery(self) -> None:
        await self.controllers.recover(self.error_recovery_timeout_s)

    # ================================================================ graph and frames
    async def _graph(self) -> dict[str, list[str]]:
        node = self.bridge.node

        def typed(pairs: list[tuple[str, list[str]]]) -> list[str]:
            return [f"{name} [{', '.join(types)}]" for name, types in pairs if "/_action/" not in name]

        nodes = [f"{ns.rstrip('/')}/{name}" for name, ns in node.get_node_names_and_namespaces()]
        return {
            "nodes": nodes,
            "topics": typed(node.get_topic_names_and_types()),
            "services": typed(node.get_service_names_and_types()),
            "actions": typed(rclpy.action.graph.get_action_names_and_types(node)),
        }

    async def _lookup_transform(self, target_frame: str, source_frame: str) -> Transform:
        assert self.transforms is not None
        reading = self.transforms.lookup(target_frame, source_frame)
        return Transform(reading.translation, reading.rotation_xyzw, time.monotonic())

    def tf_frames(self) -> tuple[str, ...]:
        """Frames seen on /tf and /tf_static so far."""
        return () if self.transforms is None else self.transforms.frames()

    # ================================================================ diagnostics
    @property
    def last_cancel_stamp(self) -> float | None:
        """Monotonic time [s] the latest cancel request (or topic hold) was sent; None: none yet."""
        return self.stop_records[-1].stamp if self.stop_records else None


def create_backend(robot: RobotModel, policy: Policy, config: Config) -> Ros2Backend:
    """Registry factory: the ROS 2 backend for `policy`'s joints, named as `config` says."""
    config = resolve_robot_names(config, policy.robot.description)
    ros_names = check_against_policy(config, tuple(policy.robot.joint_names))
    return Ros2Backend(robot, config, ros_names, start_tolerance_rad=policy.motion.start_tolerance_rad)


__all__ = ["ERROR_CODES", "Ros2Backend", "StopRecord", "create_backend", "hold_message", "trajectory_message"]
