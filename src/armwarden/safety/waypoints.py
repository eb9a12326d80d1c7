"""The envelope's per-waypoint checks, without kinematics: malformed input, joint limits and the
near-limit margin, joint travel per plan, peak velocity and acceleration from the waypoint
timing. Each returns the violations it found; `Envelope.check` runs them before the geometry.

`estimate_velocities` and `estimate_accelerations` are also what the planner's time
parameterisation verifies against, so a plan our planner makes never fails these checks.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from armwarden.core.trajectory import JointTrajectory
from armwarden.safety.violations import Code, Violation

if TYPE_CHECKING:
    from armwarden.safety.limits import EnvelopeLimits

ACCELERATION_TOLERANCE = 1.10  # the 10 % tolerance on acceleration estimated from waypoint timing
_VELOCITY_TOLERANCE = 1.0 + 1e-9


def estimate_velocities(times: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Per-segment joint velocities (K-1, n) from the waypoint timing."""
    return np.diff(positions, axis=0) / np.diff(times)[:, None]


def estimate_accelerations(times: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Joint accelerations (K, n) from the waypoint timing, the trajectory at rest at both ends.

    Interior waypoints: change of segment velocity over the mean of the two segment durations.
    Ends: from rest to the first segment velocity over half its duration (and back to rest).
    """
    dt = np.diff(times)
    vel = np.diff(positions, axis=0) / dt[:, None]
    padded_v = np.vstack([np.zeros((1, positions.shape[1])), vel, np.zeros((1, positions.shape[1]))])
    padded_dt = np.concatenate([[0.0], dt, [0.0]])
    span = (padded_dt[:-1] + padded_dt[1:]) / 2.0
    return np.diff(padded_v, axis=0) / span[:, None]


def check_malformed(trajectory: JointTrajectory, joint_names: tuple[str, ...], nq: int) -> list[Violation]:
    """Shape, joint names, finiteness and time order: nothing else is checked on a malformed trajectory."""
    times, positions = trajectory.times, trajectory.positions
    problems = []
    if tuple(trajectory.joint_names) != joint_names:
        problems.append(f"joint names {list(trajectory.joint_names)} do not match the robot's {list(joint_names)}")
    if times.ndim != 1 or positions.ndim != 2 or positions.shape[0] != times.shape[0]:
        problems.append(f"shape mismatch: times {times.shape}, positions {positions.shape}")
    elif positions.shape[1] != nq:
        problems.append(f"{positions.shape[1]} joint values per waypoint, expected {nq}")
    elif len(times) < 2:
        problems.append("a trajectory needs at least two waypoints")
    if not problems:
        if not (np.all(np.isfinite(times)) and np.all(np.isfinite(positions))):
            problems.append("non-finite value (NaN or Inf) in the trajectory")
        elif times[0] != 0.0:
            problems.append(f"the first waypoint must be at t = 0 (got {times[0]})")
        elif np.any(np.diff(times) <= 0.0):
            problems.append("waypoint times must strictly increase")
    return [Violation(Code.MALFORMED, p) for p in problems]

def check_joint_limits(lim: EnvelopeLimits, names: tuple[str, ...], times: np.ndarray, positions: np.ndarray) -> list[Violation]:
    """Positions outside the limits (exact between waypoints: the path is linear in joint space),
    and, for joints that stay inside, positions within the near-limit margin."""
    out: list[Violation] = []
    below = positions < lim.lower_rad
    above = positions > lim.upper_rad
    for j in np.flatnonzero(np.any(below | above, axis=0)):
        k = int(np.flatnonzero(below[:, j] | above[:, j])[0])
        out.append(
            Violation(
                Code.JOINT_LIMIT,
                f"{names[j]} = {positions[k, j]:.4f} rad is outside [{lim.lower_rad[j]:.4f}, {lim.upper_rad[j]:.4f}]",
                float(times[k]),
                names[j],
            )
        )
    margin = lim.joint_limit_margin_rad
    if margin > 0:
        near = ((positions < lim.lower_rad + margin) | (positions > lim.upper_rad - margin)) & ~(below | above)
        for j in np.flatnonzero(np.any(near, axis=0)):
            if np.any(below[:, j] | above[:, j]):
                continue
            k = int(np.flatnonzero(near[:, j])[0])
            out.append(
                Violation(
                    Code.NEAR_JOINT_LIMIT,
                    f"{names[j]} = {positions[k, j]:.4f} rad is within {margin:.3f} rad of its limit "
                    f"[{lim.lower_rad[j]:.4f}, {lim.upper_rad[j]:.4f}]",
                    float(times[k]),
                    names[j],
                )
            )
    return out

def check_travel(lim: EnvelopeLimits, names: tuple[str, ...], travel: np.ndarray) -> list[Violation]:
    """The joint that travels furthest, against the hard and the soft per-plan caps."""
    j = int(np.argmax(travel))
    if travel[j] > lim.max_joint_step_rad:
        return [
            Violation(
                Code.STEP_TOO_LARGE,
                f"{names[j]} travels {travel[j]:.3f} rad, over max_joint_step_rad {lim.max_joint_step_rad:.3f}",
                None,
                names[j],
            )
        ]
    if lim.soft_joint_step_rad is not None and travel[j] > lim.soft_joint_step_rad:
        return [
            Violation(
                Code.LARGE_MOTION,
                f"{names[j]} travels {travel[j]:.3f} rad, over soft_joint_step_rad {lim.soft_joint_step_rad:.3f}",
                None,
                names[j],
            )
        ]
    return []

def check_dynamics(lim: EnvelopeLimits, names: tuple[str, ...], times: np.ndarray,
                   positions: np.ndarray) -> tuple[float, float, list[Violation]]:
    """Peak velocity and acceleration ratios (to the joint limits) from the waypoint timing, and
    the violations of the scaling caps."""
    out: list[Violation] = []
    vel = np.abs(estimate_velocities(times, positions)) / lim.max_velocity_rad_s
    acc = np.abs(estimate_accelerations(times, positions)) / lim.max_acceleration_rad_s2
    vel_ratio = float(np.max(vel)) if vel.size else 0.0
    acc_ratio = float(np.max(acc)) if acc.size else 0.0
    if vel_ratio > lim.max_velocity_scaling * _VELOCITY_TOLERANCE:
        k, j = np.unravel_index(int(np.argmax(vel)), vel.shape)
        out.append(
            Violation(
                Code.VELOCITY_LIMIT,
                f"{names[j]} peaks at {vel_ratio:.3f} × its velocity limit; the cap is {lim.max_velocity_scaling:.3f}",
                float(times[k]),
                names[j],
            )
        )
    if acc_ratio > lim.max_acceleration_scaling * ACCELERATION_TOLERANCE:
        k, j = np.unravel_index(int(np.argmax(acc)), acc.shape)
        out.append(
            Violation(
                Code.ACCELERATION_LIMIT,
                f"{names[j]} peaks at {acc_ratio:.3f} × its acceleration limit; the cap is "
                f"{lim.max_acceleration_scaling:.3f} (+10 % tolerance)",
                float(times[k]),
                names[j],
            )
        )
    return vel_ratio, acc_ratio, out
