"""The simulated Franka-style fingers of the MuJoCo cell: a position actuator on the fingers'
tendon, its target a width ramp on simulated time, its force capped at the grasp's force.

The physics thread reads `SimulatedFingers.target` before every step; gripper actions and stops
replace it whole. A stop (`stop_now`, any thread) freezes the target, not the measured width:
fingers closed on an object keep squeezing it with the grasp's force, so a stop never drops what
the hand holds; free fingers stop within the servo's lag of their measured width.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from armwarden.backends.gripper_checks import check_grasp_margins, check_gripper_width_speed, grasp_outcome
from armwarden.backends.mujoco.measurement import Measured
from armwarden.backends.parts import Gripper
from armwarden.backends.ramp import Ramp
from armwarden.backends.values import GripperResult
from armwarden.core.errors import BackendError
from armwarden.core.state import GripperState

#: how often a gripper action looks at the published sample [s]
POLL_S = 0.002
#: finger speed [m/s] of `gripper_home`
GRIPPER_HOMING_SPEED_MPS = 0.05
#: the fingers count as still below this opening speed [m/s]
GRIPPER_STILL_MPS = 1e-3
#: a finger move has arrived within this width [m]
GRIPPER_ARRIVED_M = 1e-3


@dataclass(frozen=True)
class FingerTarget:
    """What the finger actuator tracks: a ramp of the width [m] on simulated time, pressing with
    at most `force_n` [N]."""

    ramp: Ramp
    force_n: float


class SimulatedFingers(Gripper):
    """The gripper part of the MuJoCo cell."""

    def __init__(self, max_width_m: float, force_limit_n: float, sample: Callable[[], Measured],
                 stop_landed: Callable[[], bool], require_running: Callable[[], None]) -> None:
        self.max_width_m = max_width_m
        self.travel_m = max_width_m
        self.force_limit_n = force_limit_n
        self._sample = sample  # the latest published sample
        self._stop_landed = stop_landed  # a stop came after the running gripper action was decided
        self._require_running = require_running  # the physics thread is alive (raises otherwise)
        #: what the fingers track; replaced whole (gripper actions, stops), read before every physics step
        self.target = FingerTarget(Ramp(max_width_m, max_width_m, 1.0, 0.0), force_limit_n)
        self._lock = threading.Lock()  # starting the fingers vs a stop from any thread
        self.busy = False  # a gripper action runs (event loop only)
        self.grasped = False

    def stop_now(self) -> None:
        """Any thread: the finger ramp stops where it is from the next physics step on."""
        with self._lock:
            target, sim_s = self.target, self._sample().sim_s
            width = target.ramp.position(sim_s)
            self.target = FingerTarget(Ramp(width, width, 1.0, sim_s), target.force_n)

    def state(self) -> GripperState:
        sample = self._sample()
        moving = self.busy or abs(sample.gripper_speed_mps) > GRIPPER_STILL_MPS
        return GripperState(sample.gripper_width_m, self.grasped, moving, sample.stamp)

    async def move(self, width_m: float, speed_mps: float) -> GripperResult:
        check_gripper_width_speed(width_m, speed_mps, self.max_width_m)
        width, stopped = await self._run(width_m, speed_mps, self.force_limit_n, arrive=True)
        if stopped:
            return GripperResult(False, width, False, "stopped")
        if abs(width - width_m) > GRIPPER_ARRIVED_M:
            return GripperResult(False, width, False, f"blocked at {width:.4f} m")
        return GripperResult(True, width, False, "")

    async def grasp(self, width_m: float, force_n: float, speed_mps: float, epsilon_inner_m: float,
                    epsilon_outer_m: float) -> GripperResult:
        check_gripper_width_speed(width_m, speed_mps, self.max_width_m)
        check_grasp_margins(epsilon_inner_m, epsilon_outer_m)
        if not (np.isfinite(force_n) and 0 < force_n <= self.force_limit_n):
            raise BackendError(f"gripper grasp force {force_n} N outside (0, {self.force_limit_n}] N")
        # close fully with the force capped: the fingers stop where the object stops them
        width, stopped = await self._run(0.0, speed_mps, float(force_n), arrive=False)
        result = grasp_outcome(width_m, width, stopped, epsilon_inner_m, epsilon_outer_m)
        self.grasped = result.is_grasped
        return result

    async def home(self) -> GripperResult:
        return await self.move(self.max_width_m, GRIPPER_HOMING_SPEED_MPS)

    async def _run(self, goal_m: float, speed_mps: float, force_n: float, *, arrive: bool) -> tuple[float, bool]:
        """Ramp the fingers to `goal_m`; wait until they arrived (`arrive`) or, the ramp done, stand
        still (against an object or at the goal). Returns (measured width, whether a stop ended it)."""
        if self.busy:
            raise BackendError("the gripper is already moving; one gripper action at a time")
        self._require_running()
        with self._lock:  # started atomically with the check: a stop from any thread that came first wins
            if self._stop_landed():
                return self._sample().gripper_width_m, True
            sample = self._sample()
            target = FingerTarget(Ramp(sample.gripper_width_m, goal_m, speed_mps, sample.sim_s), force_n)
            self.target = target
        self.busy = True
        self.grasped = False  # any motion releases what was held
        try:
            while True:
                await asyncio.sleep(POLL_S)
                self._require_running()
                sample = self._sample()
                if self._stop_landed():
                    return sample.gripper_width_m, True
                still = abs(sample.gripper_speed_mps) <= GRIPPER_STILL_MPS
                if arrive and abs(sample.gripper_width_m - goal_m) <= GRIPPER_ARRIVED_M and still:
                    return sample.gripper_width_m, False
                if target.ramp.done(sample.sim_s - 0.05) and still:  # 50 ms simulated past the ramp, still
                    return sample.gripper_width_m, False
        finally:
            self.busy = False
