"""Time parameterisation of a joint-space polyline under per-joint velocity/acceleration limits.

Written for ArmWarden rather than taken from a library (toppra would be the well-kept choice for
time-optimal profiles) because what we need is small and must agree exactly with the envelope's
own estimator: a trapezoidal profile in the path parameter, sampled at a fixed period, then
verified with `estimate_velocities/accelerations` — the same functions the envelope uses — and
stretched uniformly in time until it passes. A plan our planner makes therefore never fails the
envelope's dynamics check.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from armwarden.core.trajectory import DEFAULT_DT_S, JointTrajectory
from armwarden.safety.waypoints import estimate_accelerations, estimate_velocities

_MAX_STRETCHES = 30
#: the most waypoints a timed plan may have (about 20 minutes at the default 10 ms spacing): a
#: longer one is refused, not built, so no request can make the planning thread exhaust memory
MAX_WAYPOINTS = 120_000
_MIN_STEP_RAD = 1e-9  # smaller joint steps are numerical noise, not motion
_NEGLIGIBLE_SLOPE = 1e-12  # |dq_i/ds| below this: joint i does not limit the path acceleration


@dataclass(frozen=True)
class _Trapezoid:
    """Rest-to-rest profile of the path parameter: accelerate, cruise, decelerate."""

    length: float
    v_peak: float
    a_max: float
    t_acc: float
    t_flat: float

    @classmethod
    def fit(cls, length: float, v_max: float, a_max: float) -> _Trapezoid:
        t_acc = v_max / a_max
        if a_max * t_acc * t_acc >= length:  # never reaches v_max: triangular profile
            t_acc = float(np.sqrt(length / a_max))
            return cls(length, a_max * t_acc, a_max, t_acc, 0.0)
        return cls(length, v_max, a_max, t_acc, (length - a_max * t_acc * t_acc) / v_max)

    @property
    def duration(self) -> float:
        return 2.0 * self.t_acc + self.t_flat

    def time_at(self, s: np.ndarray) -> np.ndarray:
        """Inverse of the profile: the time at which the path parameter reaches `s`."""
        s_acc = 0.5 * self.a_max * self.t_acc**2
        s_cruise_end = s_acc + self.v_peak * self.t_flat
        accelerating = np.sqrt(2.0 * np.clip(s, 0.0, None) / self.a_max)
        cruising = self.t_acc + (s - s_acc) / self.v_peak
        decelerating = self.duration - np.sqrt(2.0 * np.clip(self.length - s, 0.0, None) / self.a_max)
        return np.where(s <= s_acc, accelerating, np.where(s <= s_cruise_end, cruising, decelerating))


def time_parameterize(
    joint_names: tuple[str, ...],
    path: np.ndarray,
    max_velocity: np.ndarray,
    max_acceleration: np.ndarray,
    dt_s: float = DEFAULT_DT_S,
    stops: tuple[int, ...] = (),
) -> JointTrajectory:
    """Like `time_leg`, coming to rest at each vertex index in `stops` (corners of Cartesian paths)."""
    path = np.asarray(path, dtype=float)
    bounds = sorted({0, len(path) - 1, *[i for i in stops if 0 < i < len(path) - 1]})
    times: list[np.ndarray] = []
    positions: list[np.ndarray] = []
    offset = 0.0
    for start, end in itertools.pairwise(bounds):
        leg = time_leg(joint_names, path[start : end + 1], max_velocity, max_acceleration, dt_s)
        skip = 1 if times else 0  # the junction waypoint is shared by both legs
        times.append(leg.times[skip:] + offset)
        positions.append(leg.positions[skip:])
        offset += leg.duration_s
    return JointTrajectory(joint_names, np.concatenate(times), np.vstack(positions))


def time_leg(
    joint_names: tuple[str, ...],
    path: np.ndarray,
    max_velocity: np.ndarray,
    max_acceleration: np.ndarray,
    dt_s: float = DEFAULT_DT_S,
) -> JointTrajectory:
    """A rest-to-rest trajectory through the vertices of the polyline `path` (M, n).

    `max_velocity`/`max_acceleration` are the already-scaled per-joint limits (rad/s, rad/s²).
    The vertices are kept (they are IK solutions on Cartesian paths) and long segments are
    subdivided so that waypoints are about `dt_s` apart at full speed; each waypoint gets the
    time at which a trapezoidal profile of the path parameter reaches it.
    """
    path = _drop_repeated_vertices(np.asarray(path, dtype=float))
    if len(path) < 2:
        return JointTrajectory(joint_names, np.array([0.0, dt_s]), np.vstack([path[0], path[0]]))
    # path parameter: time each segment takes at full speed on its limiting joint
    seg = np.max(np.abs(np.diff(path, axis=0)) / max_velocity, axis=1)
    with np.errstate(over="ignore", invalid="ignore"):
        steps = np.maximum(1.0, np.ceil(seg / dt_s))  # waypoints per segment, as floats: no overflow yet
    needed = float(np.sum(steps))
    if not needed <= MAX_WAYPOINTS:  # also NaN
        raise TimingError(f"the motion would need about {needed:.3g} waypoints, more than {MAX_WAYPOINTS}: "
                          "it is far too slow (raise the velocity scaling) or too long")
    pieces = steps.astype(int)
    dense = [path[:1]]
    for k, n in enumerate(pieces):
        alpha = (np.arange(1, n + 1) / n)[:, None]
        dense.append(path[k] + alpha * (path[k + 1] - path[k]))
    positions = np.vstack(dense)
    s = np.concatenate([[0.0], np.cumsum(np.repeat(seg / pieces, pieces))])
    # with ds/dt ≤ 1 every joint is within its velocity limit; the tangential acceleration
    # |dq_i/ds| s̈ stays within a_i for s̈ ≤ min_i a_i / max|dq_i/ds|; curvature at vertices is
    # caught by the verification below
    slope = np.max(np.abs(np.diff(path, axis=0)) / seg[:, None], axis=0)
    moving = slope > _NEGLIGIBLE_SLOPE  # a joint that moves ~1e-300 rad would overflow a_i / slope
    a_path = float(np.min(max_acceleration[moving] / slope[moving])) if moving.any() else float(np.min(max_acceleration))
    profile = _Trapezoid.fit(float(s[-1]), 1.0, a_path)
    base_times = profile.time_at(s)
    base_times[0], base_times[-1] = 0.0, profile.duration
    stretch = 1.0
    acc = float("nan")  # the last acceleration ratio tried, for the error
    for _ in range(_MAX_STRETCHES):
        times = base_times * stretch
        vel = np.max(np.abs(estimate_velocities(times, positions)) / max_velocity)
        acc = np.max(np.abs(estimate_accelerations(times, positions)) / max_acceleration)
        if vel <= 1.0 + 1e-9 and acc <= 1.0 + 1e-9:
            return JointTrajectory(joint_names, times, positions)
        stretch *= max(1.01, float(np.sqrt(max(acc, 1.0))) * 1.001, float(vel) * 1.001)
    raise TimingError(f"no timing within the limits after {_MAX_STRETCHES} stretches (acceleration ratio {acc:.2f})")


def _drop_repeated_vertices(path: np.ndarray) -> np.ndarray:
    """Vertices closer than `_MIN_STEP_RAD` to the previous kept one carry no motion: drop them.

    The first vertex always stays; the last one replaces a near-duplicate before it, so a path
    that moves ends exactly at its goal (one that does not move holds its start).
    """
    kept = [path[0]]
    for vertex in path[1:]:
        if np.max(np.abs(vertex - kept[-1])) > _MIN_STEP_RAD:
            kept.append(vertex)
    if len(kept) > 1:
        kept[-1] = path[-1]
    return np.array(kept)


class TimingError(RuntimeError):
    """The path cannot be timed within the limits (e.g. a sharp corner); the planner reports it."""
