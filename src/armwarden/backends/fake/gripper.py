"""The fake backend's gripper: finger width as a function of time, frozen by a stop from any thread.

The fingers move on the event loop (a gripper action awaits its ramp); a stop (`FakeFingers.stop_now`)
may come from any thread: it freezes the width at once, and the event loop ends the action's wait
and books where the fingers stopped (at once on the loop, else at its next turn).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import anyio

from armwarden.backends.fake.knobs import FakeKnobs
from armwarden.backends.gripper_checks import check_grasp_margins, check_gripper_width_speed, grasp_outcome
from armwarden.backends.parts import Gripper
from armwarden.backends.ramp import Ramp
from armwarden.backends.values import GripperResult
from armwarden.core.errors import BackendError
from armwarden.core.state import GripperState

#: speed of the homing motion (fully open) [m/s]
GRIPPER_HOMING_SPEED_MPS = 0.1


@dataclass(eq=False)
class FingerMotion:
    """A gripper motion in progress: the width [m] ramps (speed already time-scaled, perf_counter
    clock) until it ends or is halted."""

    ramp: Ramp
    halted: anyio.Event = field(default_factory=anyio.Event)  # set on the event loop once halted
    halted_at: float | None = None  # perf_counter of the stop that froze it (set from any thread)

    def width_at(self, now: float) -> float:
        """Finger opening [m] at perf_counter time `now` (frozen from `halted_at` on)."""
        halted_at = self.halted_at
        return self.ramp.position(now if halted_at is None else min(now, halted_at))


class FakeFingers(Gripper):
    """The gripper part of the fake cell: kinematic fingers opening 0..`max_width_m`, one motion at
    a time, frozen by a stop. Every action counts as an actuation (`FakeKnobs`) before its checks."""

    def __init__(self, max_width_m: float, speedup: Callable[[], float], stop_landed: Callable[[], bool],
                 loop: Callable[[], asyncio.AbstractEventLoop | None], knobs: FakeKnobs) -> None:
        self.max_width_m = max_width_m
        self.travel_m = max_width_m
        self._speedup = speedup  # the backend's time scaling
        self._stop_landed = stop_landed  # a stop came after the running gripper action was decided
        self._loop = loop  # the event loop the backend runs on (None before open)
        self._knobs = knobs  # the object between the fingers; counts and records the actions
        self.width_m = max_width_m  # where the fingers rest (event loop only)
        self.grasped = False
        self.motion: FingerMotion | None = None
        self._lock = threading.Lock()  # starting the fingers vs a stop from another thread

    def state(self) -> GripperState:
        motion = self.motion
        width = motion.width_at(time.perf_counter()) if motion is not None else self.width_m
        moving = motion is not None and motion.halted_at is None
        return GripperState(width, self.grasped, moving, time.monotonic())

    async def move(self, width_m: float, speed_mps: float) -> GripperResult:
        self._knobs.count_actuation()
        check_gripper_width_speed(width_m, speed_mps, self.max_width_m)
        return await self._move(width_m, speed_mps)

    async def grasp(self, width_m: float, force_n: float, speed_mps: float, epsilon_inner_m: float,
                    epsilon_outer_m: float) -> GripperResult:
        """Close on the object between the fingers (`FakeKnobs.object_width_m`; None: exactly the
        width asked for)."""
        self._knobs.count_actuation()
        check_gripper_width_speed(width_m, speed_mps, self.max_width_m)
        check_grasp_margins(epsilon_inner_m, epsilon_outer_m, force_n)
        self._knobs.last_grasp_force_n = float(force_n)
        object_width_m = self._knobs.object_width_m
        object_width = width_m if object_width_m is None else float(object_width_m)
        # the fingers close until they touch the object, or fully if it is not between them
        target = object_width if 0.0 <= object_width <= self.width_m else 0.0
        width, stopped = await self._run(target, speed_mps)
        result = grasp_outcome(width_m, width, stopped, epsilon_inner_m, epsilon_outer_m)
        self.grasped = result.is_grasped
        return result

    async def home(self) -> GripperResult:
        self._knobs.count_actuation()
        return await self._move(self.max_width_m, GRIPPER_HOMING_SPEED_MPS)

    async def _move(self, width_m: float, speed_mps: float) -> GripperResult:
        width, stopped = await self._run(width_m, speed_mps)
        return GripperResult(False, width, False, "stopped") if stopped else GripperResult(True, width, False, "")

    async def _run(self, target_m: float, speed_mps: float) -> tuple[float, bool]:
        """Move the fingers to `target_m`; returns (final width, whether a stop interrupted it)."""
        if self.motion is not None:
            raise BackendError("the gripper is already moving; one gripper action at a time")
        motion = FingerMotion(Ramp(self.width_m, target_m, speed_mps * self._speedup(), time.perf_counter()))
        with self._lock:  # started atomically with the check: a stop from any thread that came first wins
            if self._stop_landed():
                return self.width_m, True
            self.motion = motion
        self.grasped = False  # any motion releases what was held
        finished = False
        try:
            with anyio.move_on_after(motion.ramp.duration_s):
                await motion.halted.wait()
            finished = True
        finally:
            if self.motion is motion:  # not halted on the loop: it arrived, or our caller was cancelled
                self.motion = None
                arrived = finished and motion.halted_at is None
                self.width_m = target_m if arrived else motion.width_at(time.perf_counter())
        # a stop that lands after the fingers arrived (before this task resumed) did not interrupt it
        interrupted = motion.halted_at is not None and not math.isclose(self.width_m, target_m, abs_tol=1e-9)
        return self.width_m, interrupted

    def stop_now(self) -> None:
        """Any thread: the fingers freeze now (`halted_at`); the backend's event loop ends the
        motion's wait and books its width, at once when this runs on it, else at its next turn."""
        loop = self._loop()
        with self._lock:  # the fingers are either not started yet (and will not be) or frozen here
            motion = self.motion
            froze = motion is not None and motion.halted_at is None
            if froze and motion is not None:
                motion.halted_at = time.perf_counter()
        if loop is None:
            return
        try:
            on_loop = asyncio.get_running_loop() is loop
        except RuntimeError:  # no loop runs in this thread
            on_loop = False
        if on_loop:
            self._end_motion()
        elif froze:
            with contextlib.suppress(RuntimeError):  # the loop is closed
                loop.call_soon_threadsafe(self._end_motion)

    def _end_motion(self) -> None:
        """Event loop: freeze the fingers where they are and end the motion's wait."""
        motion = self.motion
        if motion is not None:
            if motion.halted_at is None:
                motion.halted_at = time.perf_counter()
            self.width_m = motion.width_at(time.perf_counter())
            self.motion = None
            motion.halted.set()


__all__ = ["GRIPPER_HOMING_SPEED_MPS", "FakeFingers", "FingerMotion"]
