"""The timed joint trajectory: the one object that is checked and then executed unchanged.

Between waypoints the path is the straight line in joint space (linear interpolation in
time). Backends execute exactly that: the fake and CAN backends interpolate linearly, the
ROS 2 backend sends the same waypoints. Waypoints are dense (one per `DEFAULT_DT_S`), so the
velocity steps at waypoints are small.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

DEFAULT_DT_S = 0.01


@dataclass(frozen=True, eq=False)
class JointTrajectory:
    """Waypoints `positions[k]` (rad) reached at `times[k]` (s from the start; `times[0] == 0`).

    Arrays are made read-only so that what the envelope checked cannot be altered before it runs.
    """

    joint_names: tuple[str, ...]
    times: np.ndarray
    positions: np.ndarray
    digest: str = field(init=False)

    def __post_init__(self) -> None:
        times = np.array(self.times, dtype=float, copy=True)
        positions = np.array(self.positions, dtype=float, copy=True)
        times.setflags(write=False)
        positions.setflags(write=False)
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "positions", positions)
        hasher = hashlib.sha256()
        hasher.update("\x1f".join(self.joint_names).encode())
        hasher.update(times.tobytes())
        hasher.update(positions.tobytes())
        object.__setattr__(self, "digest", hasher.hexdigest())

    @property
    def duration_s(self) -> float:
        return float(self.times[-1]) if len(self.times) else 0.0

    @property
    def start(self) -> np.ndarray:
        return self.positions[0]

    @property
    def goal(self) -> np.ndarray:
        return self.positions[-1]

    def sample(self, t: float) -> np.ndarray:
        """Joint positions at time `t` (clamped to the trajectory's span), linear between waypoints."""
        times = self.times
        if t <= 0.0 or len(times) == 1:
            return self.positions[0].copy()
        if t >= times[-1]:
            return self.positions[-1].copy()
        k = int(np.searchsorted(times, t, side="right")) - 1
        span = times[k + 1] - times[k]
        alpha = (t - times[k]) / span if span > 0 else 1.0
        return self.positions[k] + alpha * (self.positions[k + 1] - self.positions[k])

    def velocities(self) -> np.ndarray:
        """Per-waypoint velocity (rad/s): central differences, zero at both ends."""
        vel = np.zeros_like(self.positions)
        if len(self.times) > 2:
            vel[1:-1] = (self.positions[2:] - self.positions[:-2]) / (self.times[2:] - self.times[:-2])[:, None]
        return vel
