"""The fake arm: which joints, frames and home it has, and the kinematics its servo thread computes.

The robot is the policy's (`robot.description`). A `builtin:<name>` robot's profile gives the
defaults a bare `FakeBackend()` needs (joints, ready pose, frames); a user's URDF has no profile,
so its joints, frames and home must be given: a missing one is refused, never guessed.

The servo thread has a `RobotModel` of its own (`ArmKinematics`): Pinocchio data is not thread
safe, so the event loop's model is never shared with it. Contact with the virtual table is a force
of `stiffness × penetration` along +z, penetration = max(0, table height − TCP z).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from armwarden.backends.servo import frozen
from armwarden.robot.model import RobotModel
from armwarden.robots import RobotProfile

_T = TypeVar("_T")


@dataclass(frozen=True)
class ArmSetup:
    """The arm a fake is built for: joint names, frames, home [rad], and the servo thread's model."""

    joint_names: tuple[str, ...]
    base_frame: str
    tcp_frame: str
    home: np.ndarray
    model: RobotModel


def arm_setup(
    profile: RobotProfile | None,
    description: str,
    robot: RobotModel | None,
    joint_names: Sequence[str] | None,
    base_frame: str | None,
    tcp_frame: str | None,
    home: Sequence[float] | None,
) -> ArmSetup:
    """What was given, else the loop-side `robot`'s, else the profile's; refused when none names it
    and when the home pose is not finite or outside the joint limits."""
    ready = profile.ready_joint_positions if profile is not None else None
    if joint_names is None:
        joint_names = robot.joint_names if robot else _from_profile(tuple(ready) if ready else None, "joint_names", description)
    joint_names = tuple(joint_names)
    base_frame = base_frame or (robot.base_frame if robot else _from_profile(
        profile and profile.base_frame, "base_frame", description))
    tcp_frame = tcp_frame or (robot.tcp_frame if robot else _from_profile(
        profile and profile.tcp_frame, "tcp_frame", description))
    model = RobotModel.from_description(description, joint_names, base_frame, tcp_frame)
    if home is None:
        home = _from_profile(tuple(ready.values()) if ready else None, "home", description)
        require(tuple(ready or ()) == joint_names, f"home: the ready pose of {description} is for the joints "
                f"{list(ready or ())}, not {list(joint_names)}; give home")
    q_home = np.array(home, dtype=float)
    require(q_home.shape == (len(joint_names),), f"home needs {len(joint_names)} positions, got {q_home.shape}")
    require(bool(np.all(np.isfinite(q_home))), f"home must be finite, got {q_home.tolist()}")
    require(
        model.within_limits(q_home),
        f"home {q_home.tolist()} is outside the joint limits {model.lower.tolist()} .. {model.upper.tolist()}",
    )
    return ArmSetup(joint_names, base_frame, tcp_frame, q_home, model)


class ArmKinematics:
    """The servo thread's forward kinematics, cached: a held arm costs no Pinocchio call per tick."""

    def __init__(self, model: RobotModel) -> None:
        self.model = model
        self._q: np.ndarray | None = None
        self._tcp_position = np.zeros(3)

    def tcp_position(self, q: np.ndarray) -> np.ndarray:
        """TCP position in the base frame (read-only); forward kinematics only when q changed."""
        if self._q is None or not np.array_equal(q, self._q):
            self._q = np.array(q, dtype=float)
            self._tcp_position = frozen(self.model.tcp_pose(q).position)
        return self._tcp_position


def table_contact_force_n(tcp_position: np.ndarray, table_height_m: float | None, stiffness_n_per_m: float) -> float:
    """The +z force [N] of the virtual table on a TCP at `tcp_position` (0 without a table)."""
    if table_height_m is None:
        return 0.0
    penetration_m = max(0.0, table_height_m - float(tcp_position[2]))
    return stiffness_n_per_m * penetration_m


def require(condition: bool, message: str) -> None:
    """Refuse a construction argument (`ValueError` with `message`) unless `condition` holds."""
    if not condition:
        raise ValueError(message)


def require_positive(value: float, what: str) -> None:
    """Refuse `value` unless it is a finite number > 0."""
    require(math.isfinite(value) and value > 0, f"{what} must be positive, got {value}")


def _from_profile(value: _T | None, what: str, description: str) -> _T:
    """A default the robot's profile gives; refused (never guessed) when it gives none."""
    if value is None:
        raise ValueError(f"{what} must be given: the robot {description!r} has no profile that names it")
    return value


__all__ = ["ArmKinematics", "ArmSetup", "arm_setup", "require", "require_positive", "table_contact_force_n"]
