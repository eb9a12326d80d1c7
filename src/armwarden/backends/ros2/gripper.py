"""The ROS 2 backend's gripper: one `control_msgs/GripperCommand` goal at a time, the width read
from the finger joint states.

GripperCommand carries no speed, so the gripper's own speed applies (the requested speed is only
checked). The goal is sent under the backend's motion lock, after a last look at the stop epoch:
either a stop came first and nothing is sent, or the goal was sent and the stop cancels it by goal
id (again once it is accepted, if the cancel went out before the server answered). A stop may
come from any thread (`Ros2Gripper.stop_now` never awaits). After a result the action waits for a
finger state received after it, so the state read next is where the action left the fingers.
"""

from __future__ import annotations

import asyncio
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from action_msgs.msg import GoalStatus
from control_msgs.action import GripperCommand

from armwarden.backends.gripper_checks import check_grasp_margins, check_gripper_width_speed, grasp_outcome
from armwarden.backends.parts import Gripper
from armwarden.backends.ros2.action_client import STATUS_NAMES, cancel_goal, wait_for_server
from armwarden.backends.ros2.bridge import RosBridge
from armwarden.backends.ros2.config import GripperConfig, resolved
from armwarden.backends.ros2.endpoints import Endpoints
from armwarden.backends.ros2.runs import GripperRun, StopRecord, new_goal_id
from armwarden.backends.ros2.state import JointStateCache
from armwarden.backends.values import GripperResult
from armwarden.core.errors import BackendError
from armwarden.core.state import GripperState

#: the homing motion's speed [m/s] (checked only: GripperCommand has no speed)
HOMING_SPEED_MPS = 0.05


@dataclass(eq=False)
class Ros2Gripper(Gripper):
    """The gripper part. `motion_lock` and `stop_records` are the backend's (shared with the arm's
    stops); `stop_landed` and `epoch` are the backend's gripper stop epoch (see `Backend`). A move
    may need the full opening (`travel_m` is `max_width_m`)."""

    bridge: RosBridge
    endpoints: Endpoints
    config: GripperConfig
    fingers: JointStateCache
    motion_lock: threading.Lock
    stop_records: deque[StopRecord]
    stop_landed: Callable[[], bool]
    epoch: Callable[[], int]
    run: GripperRun | None = None
    grasped: bool = False

    def __post_init__(self) -> None:
        self.travel_m = self.config.max_width_m

    def stop_now(self) -> None:
        """Any thread, never awaiting: cancel the gripper's goal in progress."""
        with self.motion_lock:
            run = self.run
        if run is not None:
            self._cancel(run)

    def _cancel(self, run: GripperRun) -> None:
        """Any thread: cancel `run`'s goal, once (a cancel before its acceptance is sent again then)."""
        action = self.endpoints.gripper_action
        if action is None or run.cancel_sent:
            return
        run.cancel_sent = True
        cancel_goal(action, run.handle, run.goal_id, GripperCommand.Impl.SendGoalService.Response)
        self.stop_records.append(StopRecord("gripper cancel", time.monotonic()))

    def state(self) -> GripperState:
        """The fresh finger state (a stale one refuses, `JointStateCache.fresh`)."""
        state = self.fingers.fresh()
        moving = self.run is not None or bool(np.max(np.abs(state.velocities)) > 1e-3)
        return GripperState(float(np.sum(state.positions)), self.grasped, moving, state.stamp)

    async def move(self, width_m: float, speed_mps: float) -> GripperResult:
        check_gripper_width_speed(width_m, speed_mps, self.config.max_width_m)
        result, stopped = await self._goal(width_m, self.config.move_effort_n)
        self.grasped = False
        if stopped:
            return GripperResult(False, result, False, "stopped")
        return GripperResult(True, result, False, "")

    async def grasp(self, width_m: float, force_n: float, speed_mps: float, epsilon_inner_m: float,
                    epsilon_outer_m: float) -> GripperResult:
        check_gripper_width_speed(width_m, speed_mps, self.config.max_width_m)
        check_grasp_margins(epsilon_inner_m, epsilon_outer_m)
        if not (math.isfinite(force_n) and 0 < force_n <= self.config.max_effort_n):
            raise BackendError(f"gripper grasp force {force_n} N outside (0, {self.config.max_effort_n}] N")
        self.grasped = False
        width, stopped = await self._goal(width_m, force_n)
        result = grasp_outcome(width_m, width, stopped, epsilon_inner_m, epsilon_outer_m)
        self.grasped = result.is_grasped
        return result

    async def home(self) -> GripperResult:
        return await self.move(self.config.max_width_m, HOMING_SPEED_MPS)

    async def _goal(self, width_m: float, effort_n: float) -> tuple[float, bool]:
        """Send one GripperCommand goal and wait for its result: (final gap [m], whether a stop ended it)."""
        action, gripper = self.endpoints.gripper_action, self.config
        assert action is not None
        if self.run is not None:
            raise BackendError("the gripper is already moving; one gripper action at a time")
        await wait_for_server(action, resolved(gripper.action, "gripper.action"), gripper.server_timeout_s)
        goal = GripperCommand.Goal()
        goal.command.position, goal.command.max_effort = float(width_m), float(effort_n)
        with self.motion_lock:
            if self.stop_landed():
                return self._measured_width(), True
            run = GripperRun(new_goal_id(), self.epoch())
            self.run = run
            sending = action.send_goal_async(goal, goal_uuid=run.goal_id)
        finished = False
        try:
            handle = await self.bridge.result(sending, gripper.server_timeout_s)
            with self.motion_lock:
                run.handle = handle
                late = run.cancel_sent
            if not handle.accepted:
                finished = True
                raise BackendError(f"the gripper goal was rejected by {gripper.action}")
            if late:
                run.cancel_sent = False
                self._cancel(run)
            response = await self.bridge.result(handle.get_result_async(), None)
            finished = True
            await self._finger_state_after(time.monotonic(), gripper.max_age_s)
            if self.stop_landed() or response.status == GoalStatus.STATUS_CANCELED:
                return float(response.result.position), True
            if response.status != GoalStatus.STATUS_SUCCEEDED:
                raise BackendError(f"the gripper goal ended {STATUS_NAMES.get(response.status, response.status)} "
                                   f"at {gripper.action}")
            return float(response.result.position), False
        finally:
            if not finished:
                self._cancel(run)
            with self.motion_lock:
                if self.run is run:
                    self.run = None

    async def _finger_state_after(self, instant: float, timeout_s: float) -> None:
        """Wait (at most `timeout_s`) for a finger state received after `instant`, so the gripper
        state read after an action reflects where the action left the fingers, not a sample
        from just before its last step."""
        deadline = instant + timeout_s
        while time.monotonic() < deadline:
            state = self.fingers.latest()
            if state is not None and state.stamp > instant:
                return
            await asyncio.sleep(0.002)

    def _measured_width(self) -> float:
        state = self.fingers.latest()
        return float(np.sum(state.positions)) if state is not None else float("nan")


__all__ = ["Ros2Gripper"]
