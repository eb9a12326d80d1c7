"""rclpy's action client, safe to use from one thread while an executor spins on others.

rclpy's `ActionClient` (7.1, Jazzy) sends a goal, cancel or result request and only then records
the future that waits for its answer. With the executor on other threads, the answer can be taken
and handled in between: it is dropped ("Ignoring unexpected goal response", ros2/rclpy#1123) and
the future never completes — a goal that "did not answer", a result that never comes. It happened
here on a loaded machine. This client sends under a lock and handles an answer only once that lock
is free, so the request an answer belongs to is always recorded first. The lock is never held
while futures complete (their callbacks take the backend's motion lock and may send a cancel).
"""

from __future__ import annotations

import threading
import time
from typing import Any

import anyio
import rclpy.action.client
from action_msgs.msg import GoalStatus

from armwarden.core.errors import BackendError

#: how often a wait for an action server looks again [s]
SERVER_POLL_S = 0.01
#: action goal statuses by value, for messages
STATUS_NAMES = {getattr(GoalStatus, name): name[len("STATUS_"):].lower() for name in dir(GoalStatus)
                if name.startswith("STATUS_")}


class ActionClient(rclpy.action.client.ActionClient):
    """`rclpy.action.client.ActionClient` without the lost-answer race (see the module docstring)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._sending = threading.Lock()  # held from sending a request until its future is recorded

    def send_goal_async(self, goal: Any, feedback_callback: Any = None, goal_uuid: Any = None) -> Any:
        with self._sending:
            return super().send_goal_async(goal, feedback_callback, goal_uuid)

    def _cancel_goal_async(self, goal_handle: Any) -> Any:
        with self._sending:
            return super()._cancel_goal_async(goal_handle)

    def _get_result_async(self, goal_handle: Any) -> Any:
        with self._sending:
            return super()._get_result_async(goal_handle)

    async def execute(self, taken_data: Any) -> None:
        with self._sending:  # a request being sent right now is recorded once this is free
            pass
        await super().execute(taken_data)


def cancel_goal(action: rclpy.action.client.ActionClient, handle: rclpy.action.client.ClientGoalHandle | None,
                goal_id: Any, response_type: type) -> None:
    """Any thread, without waiting: ask `action`'s server to cancel the goal `goal_id`, through
    its `handle` once accepted, by id before (so a cancel works before the goal was answered)."""
    goal = handle or rclpy.action.client.ClientGoalHandle(action, goal_id, response_type())
    goal.cancel_goal_async()


async def wait_for_server(action: rclpy.action.client.ActionClient, name: str, timeout_s: float) -> None:
    """Wait (at most `timeout_s`) for `action`'s server, or `BackendError`: no goal is sent to nobody."""
    deadline = time.monotonic() + timeout_s
    while not action.server_is_ready():
        if time.monotonic() > deadline:
            raise BackendError(f"the action server {name} is not available (waited {timeout_s:g} s); nothing was sent")
        await anyio.sleep(SERVER_POLL_S)


__all__ = ["STATUS_NAMES", "ActionClient", "cancel_goal", "wait_for_server"]
