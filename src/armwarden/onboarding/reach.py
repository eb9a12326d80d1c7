"""The workspace a generated policy starts with: the table plane and a box around all the arm reaches.

The box holds every point any moving body can reach within the joint limits (sampled, with a
margin), so the only bound it adds is the table: no link below the plane the arm stands on. A
user narrows it to their cell and adds keep-out zones; `init` cannot know where the monitor is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from armwarden.robot import RobotModel

#: [m] added around the sampled reach on every side but the table's
REACH_MARGIN_M = 0.05
#: configurations sampled uniformly within the joint limits
REACH_SAMPLES = 4096


@dataclass(frozen=True)
class Workspace:
    """The box [m] in the base frame; `table_z_m` is its floor (the table plane)."""

    box_min: tuple[float, float, float]
    box_max: tuple[float, float, float]
    reach_m: float  # the farthest the TCP gets from the base origin
    table_lowered: bool  # the table plane had to go below the base (a moving link reaches under z = 0)

    @property
    def table_z_m(self) -> float:
        return self.box_min[2]


def _down(value: float) -> float:
    return math.floor(value * 100.0 - 1e-9) / 100.0


def _up(value: float) -> float:
    return math.ceil(value * 100.0 + 1e-9) / 100.0


def derive_workspace(robot: RobotModel, padding_m: float, *, samples: int = REACH_SAMPLES, seed: int = 0) -> Workspace:
    """The table at the base (z = 0) unless a body on the first moving joint reaches below it (then
    just under that body, padding included), and a box around the sampled reach of every body."""
    rng = np.random.default_rng(seed)
    qs = robot.lower + rng.random((samples, robot.nq)) * (robot.upper - robot.lower)
    p0, p1 = robot.body_points(robot.joint_frames(qs))
    radii = np.append(robot.capsule_radii, 0.0) + padding_m  # the TCP last, a point
    moving = np.array([c.joint_index > 0 for c in robot.capsules] + [True])
    lows = np.minimum(p0, p1)[:, moving] - radii[moving][:, None]
    highs = np.maximum(p0, p1)[:, moving] + radii[moving][:, None]
    low, high = lows.reshape(-1, 3).min(axis=0), highs.reshape(-1, 3).max(axis=0)
    first = min((c.joint_index for c in robot.capsules if c.joint_index > 0), default=None)
    near_base = np.array([c.joint_index == first for c in robot.capsules] + [False])
    floor = 0.0
    if near_base.any():
        lowest = float((np.minimum(p0, p1)[:, near_base][..., 2] - radii[near_base]).min())
        floor = min(0.0, _down(lowest - 0.005))
    reach = float(np.linalg.norm(p0[:, -1], axis=1).max())
    box_min = (_down(low[0] - REACH_MARGIN_M), _down(low[1] - REACH_MARGIN_M), floor)
    box_max = (_up(high[0] + REACH_MARGIN_M), _up(high[1] + REACH_MARGIN_M), _up(high[2] + REACH_MARGIN_M))
    return Workspace(box_min, box_max, reach, floor < 0.0)


__all__ = ["REACH_MARGIN_M", "REACH_SAMPLES", "Workspace", "derive_workspace"]
