"""The MuJoCo cell's camera mounts: where each camera sits and looks, from the robot profile
(`cameras`) of a built-in robot or from the backend config, and the orientation MuJoCo needs.
"""

# mujoco ships compiled pybind11 modules without type stubs (see model.py)
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from armwarden.core.errors import RobotModelError
from armwarden.robots import builtin_profile


@dataclass(frozen=True)
class CameraSpec:
    """A named camera. World cameras (`body` None) are placed in the policy's base frame; body
    cameras in that body's frame. The camera looks from `position_m` at `target_m`."""

    name: str
    position_m: tuple[float, float, float]
    target_m: tuple[float, float, float]
    body: str | None = None
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    fovy_deg: float = 45.0


def profile_cameras(description: str) -> tuple[CameraSpec, ...]:
    """The camera mounts of the robot `description` names (`builtin:<name>`: its profile's, none if
    it lists none). A user's URDF has no profile and its bodies are not ours to guess: refused, the
    backend config names its cameras (`cameras`, an empty list for none)."""
    profile = builtin_profile(description)
    if profile is None:
        raise RobotModelError(f"the robot {description!r} has no profile naming its camera mounts: list them "
                              "in the MuJoCo backend config (`cameras`; [] for none)")
    return tuple(CameraSpec(mount.name, mount.position_m, mount.target_m, mount.body, mount.up, mount.fovy_deg)
                 for mount in profile.cameras or ())


def look_at_quat(position: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Quaternion (w, x, y, z) of a MuJoCo camera (looks along −z, y up) at `position` facing `target`."""
    forward = target - position
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    norm = np.linalg.norm(right)
    if norm < 1e-9:
        raise RobotModelError("camera 'up' must not be parallel to its viewing direction")
    right /= norm
    true_up = np.cross(right, forward)
    rotation = np.column_stack([right, true_up, -forward])
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, rotation.reshape(-1))
    return quat


__all__ = ["CameraSpec", "look_at_quat", "profile_cameras"]
