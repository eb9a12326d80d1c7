"""The gripper's argument checks and grasp outcome, one rule for every backend's gripper.

A backend checks a move's or grasp's arguments itself before the fingers start (the Guard
checks them against the policy earlier; this is the backend's own fail-closed floor), and judges
a grasp that ended by the same window, so all backends report the same outcome for one motion.
"""

from __future__ import annotations

import math

from armwarden.backends.values import GripperResult
from armwarden.core.errors import BackendError


def check_gripper_width_speed(width_m: float, speed_mps: float, max_width_m: float) -> None:
    """`BackendError` unless `width_m` lies in [0, `max_width_m`] and `speed_mps` is finite and > 0."""
    if not (math.isfinite(width_m) and 0.0 <= width_m <= max_width_m):
        raise BackendError(f"gripper width {width_m} m outside [0, {max_width_m}] m")
    if not (math.isfinite(speed_mps) and speed_mps > 0):
        raise BackendError(f"gripper speed must be finite and > 0, got {speed_mps} m/s")


def check_grasp_margins(epsilon_inner_m: float, epsilon_outer_m: float, force_n: float | None = None) -> None:
    """`BackendError` unless the grasp tolerances (and `force_n`, when given) are finite and ≥ 0."""
    named = (("force_n", force_n),) if force_n is not None else ()
    for name, value in (*named, ("epsilon_inner_m", epsilon_inner_m), ("epsilon_outer_m", epsilon_outer_m)):
        if not (math.isfinite(value) and value >= 0):
            raise BackendError(f"gripper grasp: {name} must be finite and ≥ 0, got {value}")


def grasp_outcome(width_m: float, final_width_m: float, stopped: bool, epsilon_inner_m: float,
                  epsilon_outer_m: float) -> GripperResult:
    """A grasp that ended with the fingers at `final_width_m`: "stopped" when a stop ended it, else
    grasped if that width lies within [width_m − epsilon_inner_m, width_m + epsilon_outer_m]."""
    if stopped:
        return GripperResult(False, final_width_m, False, "stopped")
    low, high = width_m - epsilon_inner_m, width_m + epsilon_outer_m
    grasped = low <= final_width_m <= high
    detail = "" if grasped else f"final width {final_width_m:.4f} m outside [{low:.4f}, {high:.4f}] m"
    return GripperResult(grasped, final_width_m, grasped, detail)


__all__ = ["check_grasp_margins", "check_gripper_width_speed", "grasp_outcome"]
