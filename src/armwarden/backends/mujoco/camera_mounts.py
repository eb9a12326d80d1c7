"""The MuJoCo cell's camera mounts: where each camera sits and looks, from the robot profile
(`cameras`) of a built-in robot, from the backend config, or — for an arm without a profile — one
`scene` camera in front of its workspace; and the orientation MuJoCo needs.
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


#: the name of the camera an arm without a profile gets
SCENE_CAMERA = "scene"


def workspace_camera(box_min: tuple[float, float, float], box_max: tuple[float, float, float]) -> CameraSpec:
    """A world camera in front of the workspace box (+x of the base) and above the table, looking at
    the box's centre a quarter of the way up: the whole arm in view, whatever its size. Its bodies
    are not ours to guess, so an arm without a profile gets no body camera."""
    lo, hi = np.asarray(box_min, dtype=float), np.asarray(box_max, dtype=float)
    centre = (lo + hi) / 2.0
    target = (float(centre[0]), float(centre[1]), float(lo[2] + 0.25 * (hi[2] - lo[2])))
    distance = 1.2 * float(max(hi[0] - lo[0], hi[1] - lo[1]))
    position = (float(hi[0] + 0.5 * distance), float(centre[1]), float(lo[2] + 0.6 * distance))
    return CameraSpec(SCENE_CAMERA, position, target, fovy_deg=50.0)


def profile_cameras(description: str, box_min: tuple[float, float, float] | None = None,
                    box_max: tuple[float, float, float] | None = None) -> tuple[CameraSpec, ...]:
    """The camera mounts of the robot `description` names (`builtin:<name>`: its profile's, none if
    it lists none). A user's description has no profile: with the policy's workspace box given, one
    `workspace_camera`; without it, refused (the backend config names its cameras: `cameras`, an
    empty list for none)."""
    profile = builtin_profile(description)
    if profile is None:
        if box_min is not None and box_max is not None:
            return (workspace_camera(box_min, box_max),)
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


__all__ = ["SCENE_CAMERA", "CameraSpec", "look_at_quat", "profile_cameras", "workspace_camera"]
