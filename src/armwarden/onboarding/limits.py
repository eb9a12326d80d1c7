"""The arm joints' limits as a generated policy states them, and where each value came from.

A URDF gives position, velocity and effort limits; neither URDF nor MJCF has an acceleration
limit, and an MJCF often has no velocity limit: those get the documented defaults below, which a
user with the manufacturer's datasheet should replace.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.core.errors import RobotModelError
from armwarden.policy.robot import MAX_JOINT_ACCELERATION, MAX_JOINT_VELOCITY

#: [rad/s²] every joint's acceleration limit where the description has none (it never has): half
#: of what most collaborative arms' datasheets allow, so a first motion is gentle
DEFAULT_MAX_ACCELERATION = 5.0
#: [rad/s] a joint's speed limit where the description gives none (absent, zero or infinite)
DEFAULT_MAX_VELOCITY = 1.0


@dataclass(frozen=True)
class DraftJoint:
    """One arm joint's limits for the policy [rad, rad/s, rad/s²] and their origins."""

    name: str
    min: float
    max: float
    max_velocity: float
    max_acceleration: float
    velocity_from: str  # "description" | "default"
    effort_nm: float | None  # the description's, for the summary (None: not given)


def joint_limits(model: pin.Model, joint_names: Sequence[str]) -> tuple[DraftJoint, ...]:
    """The limits of `joint_names` in `model`; a joint without finite position limits is refused
    (a continuous joint: the envelope cannot bound what it sweeps)."""
    out = []
    for name in joint_names:
        jid = model.getJointId(name)
        joint = model.joints[jid]
        if joint.nq != 1:
            raise RobotModelError(f"joint {name!r} is continuous or multi-DoF ({joint.shortname()}); give it position "
                                  "limits in the description (a revolute joint with lower/upper)")
        lo, hi = float(model.lowerPositionLimit[joint.idx_q]), float(model.upperPositionLimit[joint.idx_q])
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise RobotModelError(f"joint {name!r} has no finite position limits ({lo}, {hi}); give it lower/upper "
                                  "limits in the description")
        velocity = float(model.velocityLimit[joint.idx_v])
        given = math.isfinite(velocity) and velocity > 0
        effort = float(model.effortLimit[joint.idx_v])
        out.append(DraftJoint(
            name=name, min=lo, max=hi,
            max_velocity=min(velocity, MAX_JOINT_VELOCITY) if given else DEFAULT_MAX_VELOCITY,
            max_acceleration=min(DEFAULT_MAX_ACCELERATION, MAX_JOINT_ACCELERATION),
            velocity_from="description" if given else "default",
            effort_nm=effort if math.isfinite(effort) and effort > 0 else None,
        ))
    return tuple(out)


__all__ = ["DEFAULT_MAX_ACCELERATION", "DEFAULT_MAX_VELOCITY", "DraftJoint", "joint_limits"]
