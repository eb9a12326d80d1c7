"""Argument checks against the policy for the tools that do not plan: gripper, controllers,
collision thresholds, cameras.

Each check is a pure function of the policy and the arguments: it returns nothing (or the value
it resolved) and raises a `SafetyRefusal` for the first argument outside the policy. Out-of-range
values are refused, never clamped. The tool layer's input schemas publish the same bounds; these
checks are what holds when a schema is bypassed or the policy is stricter than a schema.
"""

from __future__ import annotations

from collections.abc import Sequence

from armwarden.core.errors import RefusalCode, SafetyRefusal
from armwarden.policy import Policy
from armwarden.policy.devices import MIN_FINGER_SPEED_MPS
from armwarden.safety.estop import flatten_reason

__all__ = ["check_camera", "check_controllers", "check_gripper", "check_thresholds"]


def check_gripper(policy: Policy, width_m: float | None, force_n: float | None, speed_mps: float | None,
                  epsilon_inner_m: float, epsilon_outer_m: float) -> float:
    """Refuse gripper arguments outside the policy's gripper section; returns the speed to use
    (the policy's maximum when none was given)."""
    cfg = policy.gripper
    if cfg is None:
        raise SafetyRefusal(RefusalCode.NOT_CONFIGURED, "the policy has no gripper section")
    speed = cfg.max_speed_mps if speed_mps is None else speed_mps
    if width_m is not None and not (cfg.min_width_m <= width_m <= cfg.max_width_m):
        raise _out_of_range(f"width_m {width_m:g} must be in [{cfg.min_width_m:g}, {cfg.max_width_m:g}] m")
    if not (MIN_FINGER_SPEED_MPS <= speed <= cfg.max_speed_mps):
        raise _out_of_range(f"speed_mps {speed:g} must be in [{MIN_FINGER_SPEED_MPS:g}, {cfg.max_speed_mps:g}] m/s")
    if force_n is not None and not (0.0 < force_n <= cfg.max_grasp_force_n):
        raise _out_of_range(f"force_n {force_n:g} must be in (0, {cfg.max_grasp_force_n:g}] N")
    for name, eps in (("epsilon_inner_m", epsilon_inner_m), ("epsilon_outer_m", epsilon_outer_m)):
        if not (0.0 <= eps <= cfg.max_width_m):
            raise _out_of_range(f"{name} {eps:g} must be in [0, {cfg.max_width_m:g}] m")
    return speed


def check_controllers(policy: Policy, activate: Sequence[str], deactivate: Sequence[str]) -> None:
    """Only allowlisted controllers may be switched, and a switch must name at least one."""
    allowed = set(policy.controllers.allowlist)
    outside = [c for c in [*activate, *deactivate] if c not in allowed]
    if outside:
        raise SafetyRefusal(RefusalCode.NOT_ALLOWED, f"controller(s) {[flatten_reason(c, 64) for c in outside]} are "
                            f"not in the policy's allowlist {sorted(allowed)}")
    if not activate and not deactivate:
        raise SafetyRefusal(RefusalCode.INVALID, "nothing to switch: give activate and/or deactivate")
    # a switch a human approves must mean one thing: what one controller ends up doing
    repeated = sorted({c for names in (activate, deactivate) for c in names if list(names).count(c) > 1})
    if repeated:
        raise SafetyRefusal(RefusalCode.INVALID, f"controller(s) {repeated} named twice in one list")
    both = sorted(set(activate) & set(deactivate))
    if both:
        raise SafetyRefusal(RefusalCode.INVALID, f"controller(s) {both} both activated and deactivated: say which")


def check_thresholds(policy: Policy, force_n: float, torque_nm: float) -> None:
    """Collision thresholds may be lowered, never raised above the policy's contact limits."""
    force = policy.force
    if not (0.0 < force_n <= force.max_contact_force_n):
        raise _out_of_range(f"force_n {force_n:g} N must be in (0, {force.max_contact_force_n:g}] N")
    if not (0.0 < torque_nm <= force.max_contact_torque_nm):
        raise _out_of_range(f"torque_nm {torque_nm:g} N·m must be in (0, {force.max_contact_torque_nm:g}] N·m")


def check_camera(policy: Policy, camera: str) -> None:
    """A camera may be read only when the policy serves `camera_snapshot` (the `perception` tool
    group) and allowlists it. The group is checked here, not only by the tool's registration, so
    a caller that reaches the Guard without the tool (the console) is refused the same way."""
    if "perception" not in policy.tools.enabled:
        raise SafetyRefusal(RefusalCode.NOT_ALLOWED, "cameras are not read: the policy does not enable the "
                            "perception tool group (tools.enabled), so camera_snapshot is not served")
    allowed = policy.perception.cameras
    if camera not in allowed:
        raise SafetyRefusal(RefusalCode.NOT_ALLOWED, f"camera {flatten_reason(camera, 64)!r} is not allowlisted by the "
                            f"policy (perception.cameras); allowed: {list(allowed)}")


def _out_of_range(message: str) -> SafetyRefusal:
    return SafetyRefusal(RefusalCode.OUT_OF_RANGE, message)
