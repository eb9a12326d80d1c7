"""The smallest backend that keeps the contract: a kinematic arm stepped on the event loop.

Written from `armwarden.backends.base` alone (no thread, and a cell with no parts: no gripper,
no camera, no wrench), as the proof that a backend author need not read the fake.
`BackendContract` runs against it.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import anyio
import numpy as np

from armwarden.backends.base import Backend
from armwarden.backends.values import PREEMPTED, ExecutionResult
from armwarden.core.errors import BackendError
from armwarden.core.state import JointState

if TYPE_CHECKING:
    from armwarden.policy import Policy
    from armwarden.robot.model import RobotModel

STEP_S = 0.002  # how often the arm moves to the next sample [s]


class MinimalBackend(Backend):
    name = "minimal"

    def __init__(self, joint_names, home, *, start_tolerance_rad: float, speedup: float = 1.0) -> None:
        super().__init__(joint_names, start_tolerance_rad=start_tolerance_rad)
        self.speedup = speedup
        self._lock = threading.Lock()  # stop_now may come from any thread
        self._stops = 0  # bumped by every stop: a step computed before it is not published
        self._state = JointState(self.joint_names, np.array(home, dtype=float), np.zeros(len(home)), time.monotonic())
        self._busy = False

    async def _open(self) -> None:
        pass

    async def _close(self) -> None:
        pass

    async def _read_joint_state(self) -> JointState:
        with self._lock:  # a resting arm is re-sampled now
            state = self._state
            self._state = JointState(self.joint_names, state.positions, state.velocities, time.monotonic())
            return self._state

    async def _execute(self, trajectory, progress) -> ExecutionResult:
        if self._busy:
            raise BackendError("one execution at a time")
        with self._lock:  # handed over atomically with the check: a stop that came first wins
            if self._stop_landed():
                return ExecutionResult(False, PREEMPTED, self._state.positions.copy())
            stops = self._stops
        self._busy, start = True, time.monotonic()
        try:
            while True:
                t = (time.monotonic() - start) * self.speedup
                done = t >= trajectory.duration_s
                q = trajectory.goal.copy() if done else trajectory.sample(t)
                with self._lock:
                    if self._stops != stops:
                        return ExecutionResult(False, "stopped", self._state.positions.copy())
                    velocity = np.zeros_like(q) if done else (q - self._state.positions) / STEP_S
                    self._state = JointState(self.joint_names, q, velocity, time.monotonic())
                progress(1.0 if done else t / trajectory.duration_s)
                if done:
                    return ExecutionResult(True, "completed", q.copy())
                await anyio.sleep(STEP_S)
        finally:
            self._busy = False

    async def _stop(self) -> None:
        self._stop_now()

    def _stop_now(self) -> None:
        with self._lock:
            self._stops += 1
            state = self._state
            self._state = JointState(self.joint_names, state.positions, np.zeros_like(state.positions), time.monotonic())
            self._record_stop_stamp(self._state.stamp)


def build_for_tests(policy: Policy, robot: RobotModel, *, speedup: float, options: Mapping[str, Any]) -> MinimalBackend:
    """How the test harness builds this backend: the `testing.py` convention (docs/add-a-backend.md),
    here beside the backend, which no registry names. It has no options to take."""
    if options:
        raise TypeError(f"the minimal backend takes no options, got {sorted(options)}")
    return MinimalBackend(robot.joint_names, policy.robot.home_joint_positions,
                          start_tolerance_rad=policy.motion.start_tolerance_rad, speedup=speedup)
