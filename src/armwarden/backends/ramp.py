"""A straight move at constant speed: the finger motion law every backend's gripper follows.

One record, one clock: `start` to `target` at `speed` (units per second), begun at `began` on
whichever clock the caller reads (monotonic, perf_counter or simulated time). It ends exactly at
`target`, and a ramp of no length has ended from its start.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Ramp:
    start: float
    target: float
    speed: float  # > 0
    began: float

    @property
    def duration_s(self) -> float:
        return abs(self.target - self.start) / self.speed

    def travelled(self, now: float) -> float:
        """How far the ramp has gone at `now` (before it began: nowhere), ignoring its end."""
        return self.speed * max(0.0, now - self.began)

    def done(self, now: float) -> bool:
        return self.travelled(now) >= abs(self.target - self.start)

    def position(self, now: float) -> float:
        if self.done(now):
            return self.target
        return self.start + math.copysign(self.travelled(now), self.target - self.start)

    def velocity(self, now: float) -> float:
        return 0.0 if self.done(now) else math.copysign(self.speed, self.target - self.start)


__all__ = ["Ramp"]
