"""An elbow-through-zone case for any arm: a motion from home whose middle link sweeps through a
small box the TCP never comes near, with start and goal both clear of it.

Found from the arm's own model (no per-arm numbers): for each of the first joints and each step,
the midpoint of a body on the arm's middle links is followed along the straight joint path; the box
is put where that midpoint is halfway, and kept when the TCP stays `tcp_clearance_m` away and
neither end pose touches it (padding included). Motions that carry the midpoint farthest are tried
first."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from armwarden.preflight import RuntimeModel
from armwarden.safety.envelope import Envelope
from armwarden.safety.limits import Box

#: [m] half the zone's side
HALF_SIDE_M = 0.02


@dataclass(frozen=True)
class ElbowZoneCase:
    start: np.ndarray
    goal: np.ndarray
    zone: Box
    link: str  # the middle link whose body sweeps through the zone


def _box_distance(points: np.ndarray, box: Box) -> np.ndarray:
    return np.linalg.norm(np.maximum(np.maximum(box.lo - points, points - box.hi), 0.0), axis=-1)


def find_elbow_zone_case(runtime: RuntimeModel, tcp_clearance_m: float = 0.1) -> ElbowZoneCase | None:
    """The first case, trying the motions whose middle-link midpoints travel farthest first."""
    robot = runtime.robot
    home = np.array(runtime.policy.robot.home_joint_positions)
    last = max(c.joint_index for c in robot.capsules)
    bodies = [i for i, c in enumerate(robot.capsules) if c.joint_index in {last // 2, last // 2 + 1}]
    margin = runtime.policy.motion.joint_limit_margin_rad + 0.05
    floor = runtime.envelope.limits.workspace.lo[2]
    tried = []
    for joint in range(min(3, robot.nq - 1)):
        for delta in (0.6, -0.6, 1.0, -1.0, 1.4, -1.4):
            goal = home.copy()
            goal[joint] += delta
            if not robot.within_limits(goal, margin):
                continue
            path = home + np.linspace(0.0, 1.0, 41)[:, None] * (goal - home)
            p0, p1 = robot.body_points(robot.joint_frames(path))
            for body in bodies:
                middle = (p0[:, body] + p1[:, body]) / 2.0
                tried.append((float(np.linalg.norm(middle[-1] - middle[0])), body, goal, middle[20], p0[:, -1]))
    for _, body, goal, point, tcp in sorted(tried, key=lambda t: -t[0]):
        zone = Box.of("shelf", point - HALF_SIDE_M, point + HALF_SIDE_M)
        if _box_distance(tcp, zone).min() < tcp_clearance_m or zone.lo[2] < floor + 0.05:
            continue
        envelope = Envelope(robot, replace(runtime.envelope.limits, keep_out=(zone,)))
        if not envelope.check_path(home[None, :]) and not envelope.check_path(goal[None, :]):
            return ElbowZoneCase(home, goal, zone, robot.capsules[body].link)
    return None
