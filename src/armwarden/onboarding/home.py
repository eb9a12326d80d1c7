"""A home configuration for a generated policy: collision-free, clear of the limits, tool raised.

Home is where the fake backend starts and what an agent returns to, so it should be a pose from
which small motions in every direction stay inside the envelope and a top-down grasp is a short
move: every joint well inside its limits, the TCP in front of the base (+x) at a middle height and its
z axis (the approach axis of most tool frames) pointing down. Candidates are the middle of the
limits and seeded random configurations; the best by that score that the envelope passes without a
finding (hard or soft) is home. Same model, same home.
"""

from __future__ import annotations

import numpy as np

from armwarden.core.errors import RobotModelError
from armwarden.core.trajectory import JointTrajectory
from armwarden.safety.envelope import Envelope

#: random candidates besides the middle of the limits
HOME_CANDIDATES = 4096
#: where a home puts the TCP [fractions of the reach]: height above the table, distance from the base axis
TARGET_HEIGHT = 0.35
TARGET_RADIUS = 0.3
#: weight of the tool's z axis pointing down (cosine of its angle to -z) against the other terms
DOWN_WEIGHT = 0.25
#: weight of the TCP's bearing from the base's +x axis (0 in front, 1 behind)
FRONT_WEIGHT = 0.2
#: links beyond the second joint held at least this high above the table earn the most [fraction of the reach]
RAISED_LINKS = 0.2
#: decimals of a home joint value in the policy file (1 µrad)
HOME_DECIMALS = 6


def stationary(envelope: Envelope, q: np.ndarray) -> JointTrajectory:
    """A one-second stay at `q`: how the start-up check judges a home (`preflight`)."""
    return JointTrajectory(envelope.robot.joint_names, np.array([0.0, 1.0]), np.vstack([q, q]))


def _raised(envelope: Envelope, qs: np.ndarray, table_z_m: float, reach: float) -> np.ndarray:
    """How high the lowest body beyond the second joint stays above the table, capped at
    `RAISED_LINKS` of the reach: an elbow up, not a forearm lying on the table."""
    robot = envelope.robot
    outer = np.array([c.joint_index > 2 for c in robot.capsules])
    if not outer.any():
        return np.zeros(len(qs))
    p0, p1 = robot.body_points(robot.joint_frames(qs))
    lowest = (np.minimum(p0[:, :-1, 2], p1[:, :-1, 2]) - robot.capsule_radii)[:, outer].min(axis=1)
    return np.minimum((lowest - table_z_m) / reach, RAISED_LINKS)


def choose_home(envelope: Envelope, reach_m: float, table_z_m: float, *, seed: int = 0,
                candidates: int = HOME_CANDIDATES) -> np.ndarray:
    """The best-scoring candidate with no envelope finding; `RobotModelError` if none has."""
    robot = envelope.robot
    lower, upper = robot.lower, robot.upper
    middle = np.clip(np.zeros(robot.nq), lower, upper)
    middle = np.where((middle - lower < 0.25 * (upper - lower)) | (upper - middle < 0.25 * (upper - lower)),
                      (lower + upper) / 2.0, middle)  # zero when it is well inside, else the middle
    rng = np.random.default_rng(seed)
    qs = np.vstack([middle, lower + (0.15 + 0.7 * rng.random((candidates, robot.nq))) * (upper - lower)])
    qs = np.round(qs, HOME_DECIMALS)
    span = upper - lower
    clearance = np.min(np.minimum(qs - lower, upper - qs) / span, axis=1)  # 0 at a limit, 0.5 in the middle
    poses = [robot.tcp_pose(q) for q in qs]
    position = np.array([pose.position for pose in poses])
    down = -np.array([pose.rotation[2, 2] for pose in poses])  # the tool z axis's component along -z
    reach = max(reach_m, 1e-6)
    height = (position[:, 2] - table_z_m) / reach
    radius = np.hypot(position[:, 0], position[:, 1]) / reach
    behind = np.abs(np.arctan2(position[:, 1], position[:, 0])) / np.pi
    score = (clearance - np.abs(height - TARGET_HEIGHT) - np.abs(radius - TARGET_RADIUS) + DOWN_WEIGHT * down
             - FRONT_WEIGHT * behind + _raised(envelope, qs, table_z_m, reach))
    for index in np.argsort(-score, kind="stable"):
        report = envelope.check(stationary(envelope, qs[index]))
        if not report.violations:
            return qs[index].copy()
    raise RobotModelError(f"no collision-free home among {len(qs)} configurations within the joint limits: the "
                          "fitted bodies may collide in every pose (check the self-collision pairs) or the arm "
                          "cannot rise above the table")


__all__ = ["DOWN_WEIGHT", "FRONT_WEIGHT", "HOME_CANDIDATES", "HOME_DECIMALS", "RAISED_LINKS", "TARGET_HEIGHT", "TARGET_RADIUS",
           "choose_home", "stationary"]
