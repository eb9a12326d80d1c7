"""From the observer's residuals with nothing touching the arm to recommended contact limits.

With no contact, what the observer reads is friction and model error. Friction has a shape the
observer can be told about (Coulomb, smoothed through tanh as the observer does, plus viscous):
it is fitted per joint by non-negative least squares on r ≈ −(c·tanh(v/ε) + b·v), so that an
observer that allows for it reads only what is left. The limit is then the largest residual left
times a margin, never below a floor (a limit at the noise level would stop on noise) and never
above the policy format's cap. The margin the limit gives over the largest residual seen is the
false-alarm margin reported beside it.

Written here rather than taken from a library: it is a two-parameter non-negative least-squares
problem per joint, solved exactly by trying the four active sets (scipy is not a dependency).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from armwarden.calibration.arguments import DEFAULT_MARGIN
from armwarden.policy.joint_torques import MAX_EXTERNAL_TORQUE_NM, MAX_FRICTION_NM
from armwarden.safety.contact_observer import COULOMB_SMOOTHING_RAD_S

__all__ = ["DEFAULT_MARGIN", "MIN_FORCE_ROOM_N", "MIN_LIMIT_NM", "JointRecommendation", "fit_friction",
           "force_limit_for", "limit_for", "recommend"]

#: no limit below this [N·m]. Calibration sees only the poses and speeds it ran: friction that rises
#: as a cold drive warms up, cable drag, a pose its motions missed would stop a limit at the noise
#: level (a wrist joint reads ~0.1-0.3 N·m in MuJoCo). 1 N·m stays under the smallest provisional
#: limit (2 N·m) and far under Franka's own lowest defaults (10-20 N·m).
MIN_LIMIT_NM = 1.0
#: the least room [N] a recommended TCP force limit leaves over the estimate's free-motion peak
#: (the margin alone would put it within a newton or two of a peak of a few newtons)
MIN_FORCE_ROOM_N = 5.0
#: joint speed [rad/s] above which a sample says something about friction
MOVING_RAD_S = 0.05


@dataclass(frozen=True)
class JointRecommendation:
    """What calibration found for one joint and what it recommends."""

    name: str
    samples: int
    peak_residual_nm: float  # largest |residual| with no friction allowed for
    coulomb_nm: float
    viscous_nms: float
    peak_after_friction_nm: float  # largest |residual| once the fitted friction is allowed for
    limit_nm: float
    margin: float  # limit / peak_after_friction (inf: no residual at all)


def fit_friction(velocities: np.ndarray, residuals: np.ndarray) -> tuple[float, float]:
    """(Coulomb [N·m], viscous [N·m·s/rad]) ≥ 0 that best explain `residuals` as −friction(v)."""
    v = np.asarray(velocities, dtype=float)
    r = np.asarray(residuals, dtype=float)
    moving = np.abs(v) > MOVING_RAD_S
    if np.count_nonzero(moving) < 2:
        return 0.0, 0.0
    design = -np.column_stack([np.tanh(v[moving] / COULOMB_SMOOTHING_RAD_S), v[moving]])
    target = r[moving]
    best, best_cost = (0.0, 0.0), float(np.sum(target ** 2))
    candidates = []
    for column in (0, 1):  # one parameter free, the other zero
        a = design[:, column]
        denominator = float(a @ a)
        if denominator > 0:
            x = float(a @ target) / denominator
            candidates.append((x, 0.0) if column == 0 else (0.0, x))
    solution, *_ = np.linalg.lstsq(design, target, rcond=None)  # both free
    candidates.append((float(solution[0]), float(solution[1])))
    for coulomb, viscous in candidates:
        if coulomb < 0 or viscous < 0 or not (math.isfinite(coulomb) and math.isfinite(viscous)):
            continue
        cost = float(np.sum((target - design @ np.array([coulomb, viscous])) ** 2))
        if cost < best_cost:
            best, best_cost = (coulomb, viscous), cost
    return min(best[0], MAX_FRICTION_NM), min(best[1], MAX_FRICTION_NM)


def limit_for(peak_nm: float, margin: float) -> float:
    """The limit [N·m] for a joint whose residual peaked at `peak_nm`: margin × the peak, rounded up
    to 0.01 N·m (rounding must never take it below margin × the peak), within the floor and the cap."""
    return min(MAX_EXTERNAL_TORQUE_NM, max(MIN_LIMIT_NM, math.ceil(round(margin * peak_nm * 100, 6)) / 100))


def recommend(joint_names: Sequence[str], velocities: np.ndarray, residuals: np.ndarray,
              margin: float = DEFAULT_MARGIN, peaks_after_friction_nm: Sequence[float] | None = None,
              ) -> list[JointRecommendation]:
    """Per joint: fitted friction and the recommended limit, from samples (rows) of joint
    velocities and residuals [N·m] recorded with nothing touching the arm and no friction allowed
    for. What is left once the fitted friction is allowed for is estimated from the samples
    (r + friction(v)); `peaks_after_friction_nm`, what an observer with that friction really read
    on the same states (its low-pass included), raises it where it is larger."""
    if not (math.isfinite(margin) and margin >= 1.0):
        raise ValueError(f"the margin must be at least 1, got {margin}")
    v = np.asarray(velocities, dtype=float)
    r = np.asarray(residuals, dtype=float)
    if v.shape != r.shape or v.ndim != 2 or v.shape[1] != len(joint_names) or v.shape[0] == 0:
        raise ValueError("expected one row of velocities and residuals per sample, one column per joint")
    found = []
    for j, name in enumerate(joint_names):
        coulomb, viscous = fit_friction(v[:, j], r[:, j])
        left = r[:, j] + coulomb * np.tanh(v[:, j] / COULOMB_SMOOTHING_RAD_S) + viscous * v[:, j]
        peak_before, peak_after = float(np.max(np.abs(r[:, j]))), float(np.max(np.abs(left)))
        if peaks_after_friction_nm is not None:
            peak_after = max(peak_after, float(peaks_after_friction_nm[j]))
        limit = limit_for(peak_after, margin)
        found.append(JointRecommendation(name, int(v.shape[0]), peak_before, round(coulomb, 3), round(viscous, 3),
                                         peak_after, limit, limit / peak_after if peak_after > 0 else math.inf))
    return found


def force_limit_for(peak_force_n: float, margin: float, max_contact_force_n: float) -> float | None:
    """The recommended `max_tcp_force_n` [N]: `margin` times the largest trusted TCP force the
    observer estimated with nothing touching the arm, at least `MIN_FORCE_ROOM_N` over it, rounded
    up to 1 N; None when that is above `max_contact_force_n` (the estimate keeps the policy's limit,
    and the summary warns)."""
    if not (math.isfinite(peak_force_n) and peak_force_n >= 0):
        raise ValueError(f"the peak force must be a finite number >= 0, got {peak_force_n}")
    limit = float(math.ceil(max(margin * peak_force_n, peak_force_n + MIN_FORCE_ROOM_N)))
    return limit if limit <= max_contact_force_n else None
