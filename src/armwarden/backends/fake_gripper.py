"""The fake backend's gripper: finger width as a function of time, frozen by a stop from any thread."""

from __future__ import annotations

from dataclasses import dataclass, field

import anyio

from armwarden.backends.ramp import Ramp

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


__all__ = ["GRIPPER_HOMING_SPEED_MPS", "FingerMotion"]
