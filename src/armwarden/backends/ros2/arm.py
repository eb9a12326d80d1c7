"""The ROS 2 backend's arm motion: trajectory goals, the topic fallback, and their stops.

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

Stops (`Ros2Arm.stop`, any thread, never awaiting) cancel the running goal (or publish the hold)
and record when the cancel request was sent (`stop_records`).

Arm state (`armwarden.backends.arm_state`): the hand-over of a goal (or the publish) is EXECUTE,
the end of a run no stop reached is FINISH, every stop is STOP, each reported under the motion
lock, so a stop and the end of the run it stops are ordered (a stopped run stays held, never
finished). A hand-over while faulted is that fault's recovery: the backend admitted the run. Faults are the backend's: a running
execution asks it (`abort_on_fault`) at every look and ends naming the fault it recorded. Closing
ends a running execution as "stopped", whatever answer the cell sends to the close's cancel.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import anyio
import numpy as np
import rclpy.action.client
import rclpy.publisher
from action_msgs.msg import GoalStatus
from control_msgs.action import FollowJointTrajectory

from armwarden.backends.arm_state import ArmEvent, ArmState
from armwarden.backends.ros2.action_client import STATUS_NAMES, cancel_goal, wait_for_server
from armwarden.backends.ros2.bridge import RosBridge
from armwarden.backends.ros2.config import TrajectoryConfig
from armwarden.backends.ros2.endpoints import Endpoints
from armwarden.backends.ros2.runs import (
    GoalRun,
    StopRecord,
    TopicRun,
    hold_message,
    new_goal_id,
    trajectory_message,
)
from armwarden.backends.ros2.state import JointStateCache
from armwarden.backends.values import PREEMPTED, ExecutionResult, ProgressCallback
from armwarden.core.errors import BackendError
from armwarden.core.state import JointState
from armwarden.core.trajectory import JointTrajectory

#: how often a waiting execution looks at the stop epoch, progress, health and deadlines [s]
POLL_S = 0.01
#: how long a stopped execution waits for the arm to come to rest [s]
REST_TIMEOUT_S = 2.0
#: what stopped the arm when a fault aborts an execution, for messages
CANCELLED, ENDED, HELD = "the goal was cancelled", "the goal had ended", "a hold was sent"
#: FollowJointTrajectory.Result error codes by value, for messages
ERROR_CODES = {getattr(FollowJointTrajectory.Result, name): name for name in (
    "SUCCESSFUL", "INVALID_GOAL", "INVALID_JOINTS", "OLD_HEADER_TIMESTAMP", "PATH_TOLERANCE_VIOLATED",
    "GOAL_TOLERANCE_VIOLATED")}


@dataclass(eq=False)
class Ros2Arm:
    """The arm part. `motion_lock` and `stop_records` are the backend's (shared with the gripper);
    `is_open`, `stop_landed`, `stop_epoch` and `abort_on_fault` are the backend's stop epoch and
    fault watch; the accuracies are the backend's declared ones; `arm_state` and `arm_event` are
    the backend's arm state."""

    bridge: RosBridge
    endpoints: Endpoints
    config: TrajectoryConfig
    joint_states: JointStateCache
    ros_names: tuple[str, ...]
    motion_lock: threading.Lock
    stop_records: deque[StopRecord]
    is_open: Callable[[], bool]
    stop_landed: Callable[[], bool]
    stop_epoch: Callable[[], int]
    abort_on_fault: Callable[[int, str], None]
    goal_accuracy_rad: float
    rest_speed_rad_s: float
    arm_state: Callable[[], ArmState]
    arm_event: Callable[[ArmEvent], ArmState]
    run: GoalRun | TopicRun | None = None
    server_seen: bool = False  # the trajectory action server was seen at least once
    #: told each goal's id before it is sent (raising: it is not sent), and None once the server
    #: has ended it (the guardian's watch)
    on_goal: Callable[[bytes | None], None] = lambda _goal: None

    @property
    def interface(self) -> str:
        """The action or topic trajectories go to, for messages."""
        return self.config.action if self.config.action is not None else f"topic {self.config.topic}"

    async def execute(self, trajectory: JointTrajectory, progress: ProgressCallback, epoch: int) -> ExecutionResult:
        """Run `trajectory`, decided under stop epoch `epoch`, through the action or the topic."""
        if self.endpoints.trajectory_action is not None:
            return await self._execute_action(self.endpoints.trajectory_action, trajectory, progress, epoch)
        return await self._execute_topic(trajectory, progress, epoch)

    def stop(self) -> None:
        """Any thread, never awaiting: cancel the running goal (or publish the hold). The arm is
        held from here (STOP, under the lock; a cancel that cannot be sent raises: a failed stop)."""
        with self.motion_lock:
            run = self.run
            if run is not None:
                run.stopped = True
            self.arm_event(ArmEvent.STOP)
        if isinstance(run, GoalRun):
            self._cancel_goal(run)
        elif isinstance(run, TopicRun):
            self._hold(run)

    async def _execute_action(self, action: rclpy.action.client.ActionClient, trajectory: JointTrajectory,
                              progress: ProgressCallback, epoch: int) -> ExecutionResult:
        cfg = self.config
        name = self.interface
        await wait_for_server(action, name, cfg.server_timeout_s)
        self.server_seen = True
        goal = FollowJointTrajectory.Goal(trajectory=trajectory_message(trajectory, self.ros_names))
        with self.motion_lock:  # the stops take it: a stop is either before the send or cancels it
            if self.stop_landed():
                return ExecutionResult(False, PREEMPTED, self.joint_states.fresh().positions.copy())
            run = GoalRun(new_goal_id(), epoch, trajectory.duration_s, time.monotonic())
            self.on_goal(bytes(run.goal_id.uuid))  # the guardian knows it first (raises: nothing was sent)
            self._handing_over()
            self.run = run
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
            self._ended(run)

    def _handing_over(self) -> None:
        """Under the motion lock, as a run is handed over: the arm moves (after recovering a
        fault the backend has admitted this run past)."""
        if self.arm_state() in (ArmState.DAMPED, ArmState.FAULTED):
            self.arm_event(ArmEvent.RECOVER)
        self.arm_event(ArmEvent.EXECUTE)

    def _ended(self, run: GoalRun | TopicRun) -> None:
        """`run` is over: forget it, and unless a stop reached it (the arm is held), it finished."""
        with self.motion_lock:
            if self.run is run:
                self.run = None
            if not run.stopped:
                self.arm_event(ArmEvent.FINISH)
        if isinstance(run, GoalRun) and run.terminal:  # else the guardian keeps it: it may still run
            self.on_goal(None)

    def _on_goal_response(self, run: GoalRun, future: Any) -> None:
        """Executor thread: note the handle; a goal accepted after a stop is cancelled now."""
        if future.exception() is not None:
            return
        handle = future.result()
        with self.motion_lock:
            run.handle = handle
            stopped_meanwhile = run.cancel_sent or self.stop_epoch() != run.epoch
        if handle.accepted and stopped_meanwhile:
            self._cancel_goal(run, again=True)

    def _cancel_goal(self, run: GoalRun, *, again: bool = False) -> None:
        """Any thread, without waiting: ask the server to cancel `run`'s goal (by id, so it works
        before the goal was even answered). Sent once, plus once more on a late acceptance."""
        action = self.endpoints.trajectory_action
        if action is None or run.terminal or (run.cancel_sent and not again):
            return
        run.cancel_sent = True
        cancel_goal(action, run.handle, run.goal_id, FollowJointTrajectory.Impl.SendGoalService.Response)
        self.stop_records.append(StopRecord("cancel", time.monotonic()))

    async def _follow_goal(self, run: GoalRun, handle: rclpy.action.client.ClientGoalHandle,
                           trajectory: JointTrajectory, progress: ProgressCallback) -> ExecutionResult:
        """The goal was accepted: report progress until its result, a stop, a fault or the deadline."""
        cfg = self.config
        name = self.interface
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
        joint states there are a fault, named as the watchdog names it (`abort_on_fault`)."""
        return self._measured_state_during(epoch, sent)[0]

    def _measured_state_during(self, epoch: int, sent: str) -> tuple[JointState, float]:
        """`_state_during`, with the sample's header stamp [s, the cell's clock]."""
        try:
            return self.joint_states.fresh_measured()
        except BackendError:
            self.abort_on_fault(epoch, sent)
            raise

    def _stopped(self, epoch: int, sent: str) -> bool:
        """Event loop: whether the execution decided under `epoch` must end as stopped — a stop
        landed, or the backend is closing (its stop does not bump the epoch). A fault found by
        then, by the watchdog or by this look, raises instead (`abort_on_fault`)."""
        if not self.is_open():
            return True
        self.abort_on_fault(epoch, sent)
        return self.stop_landed()

    async def _stopped_goal(self, run: GoalRun, waiting: asyncio.Future[Any]) -> ExecutionResult:
        """A stop cancelled the goal: wait (bounded) for its result, then for the arm to rest."""
        self._cancel_goal(run)  # the stop sent it already; this only covers a stop that found no run
        if self.is_open():
            with contextlib.suppress(Exception):  # the result or its absence; a closing node fails it
                await asyncio.wait_for(asyncio.shield(waiting), self.config.goal_response_timeout_s)
            run.terminal = run.terminal or waiting.done()
        return await self._rest(run.epoch, CANCELLED)

    async def _settle(self, epoch: int, trajectory: JointTrajectory) -> ExecutionResult:
        """The controller reports success: the joint states must show the goal (within
        `goal_accuracy_rad`) and rest, within `result_margin_s`."""
        goal = trajectory.goal
        deadline = time.monotonic() + self.config.result_margin_s
        while True:
            if self._stopped(epoch, ENDED):
                return await self._rest(epoch, ENDED)
            state = self._state_during(epoch, ENDED)
            error = float(np.max(np.abs(state.positions - goal)))
            if error <= self.goal_accuracy_rad and np.max(np.abs(state.velocities)) <= self.rest_speed_rad_s:
                return ExecutionResult(True, "completed", state.positions.copy())
            if time.monotonic() > deadline:
                return ExecutionResult(False, f"the controller reported success but the arm is {error:.4f} rad from the "
                                       f"goal after {self.config.result_margin_s:g} s", state.positions.copy())
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
            if not self.is_open():  # closed under the execution: the stop was sent; report where it was
                latest = self.joint_states.latest()
                if latest is not None:
                    return ExecutionResult(False, reason, latest.positions.copy())
            else:
                self.abort_on_fault(epoch, sent)
            state, measured = self._measured_state_during(epoch, sent)
            resting = (state.stamp >= after and (measured_after is None or measured > measured_after)
                       and np.max(np.abs(state.velocities)) <= self.rest_speed_rad_s)
            if resting or time.monotonic() > deadline:
                return ExecutionResult(False, reason, state.positions.copy())
            await anyio.sleep(POLL_S)

    # ---------------------------------------------------------------- topic fallback
    async def _execute_topic(self, trajectory: JointTrajectory, progress: ProgressCallback,
                             epoch: int) -> ExecutionResult:
        publisher = self.endpoints.trajectory_topic
        assert publisher is not None
        cfg = self.config
        name = self.interface
        if publisher.get_subscription_count() == 0:
            await self._wait_for_subscriber(publisher, name, cfg.server_timeout_s)
        message = trajectory_message(trajectory, self.ros_names)
        with self.motion_lock:
            if self.stop_landed():
                return ExecutionResult(False, PREEMPTED, self.joint_states.fresh().positions.copy())
            self._handing_over()
            run = TopicRun(epoch, trajectory.duration_s, time.monotonic(), trajectory)
            self.run = run
            publisher.publish(message)
        try:
            deadline = run.sent_at + trajectory.duration_s + cfg.result_margin_s
            reported = 0.0
            while True:
                await anyio.sleep(POLL_S)
                if self._stopped(run.epoch, HELD):
                    self._hold(run)  # the stop sent it already; this covers a close, which does not bump the epoch
                    hold_s = self.config.hold_time_s
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
            self._ended(run)

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
        publisher = self.endpoints.trajectory_topic
        if publisher is None or run.held_at is not None:
            return
        hold_s = self.config.hold_time_s
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


__all__ = ["ERROR_CODES", "Ros2Arm"]
