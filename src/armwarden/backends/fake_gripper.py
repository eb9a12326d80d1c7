"""The fake backend's gripper: finger width as a function of time, frozen by a stop from any thread."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import anyio

#: speed of the homing motion (fully open) [m/s]
GRIPPER_HOMING_SPEED_MPS = 0.1


@dataclass(eq=False)
class GripperMotion:
    """A gripper motion in progress: the width is a function of time until it ends or is halted."""

    start_width_m: float
    target_width_m: float
    speed_mps: float  # already time-scaled
    start_time: float
    halted: anyio.Event = field(default_factory=anyio.Event)  # set on the event loop once halted
    halted_at: float | None = None  # perf_counter of the stop that froze it (set from any thread)

    @property
    def duration_s(self) -> float:
        return abs(self.target_width_m - self.start_width_m) / self.speed_mps

    def width_at(self, now: float) -> float:
        """Finger opening [m] at perf_counter time `now` (frozen from `halted_at` on)."""
        halted_at = self.halted_at
        until = now if halted_at is None else min(now, halted_at)
        travel = min(abs(self.target_width_m - self.start_width_m), self.speed_mps * max(0.0, until - self.start_time))
        return self.start_width_m + math.copysign(travel, self.target_width_m - self.start_width_m)


__all__ = ["GRIPPER_HOMING_SPEED_MPS", "GripperMotion"]
