"""Collision bodies as capsules: the one shape every safety check in ArmWarden reasons about.

A capsule is a segment `p0–p1` in a joint frame swept by a sphere of `radius_m`. Every URDF
collision primitive is replaced by a capsule that *contains* it, so checks on capsules are
conservative for the real geometry:

- cylinder (radius r, length L)  → the same axis segment, radius r (adds hemispherical caps);
- sphere (radius r)              → a zero-length capsule;
- box (half extents hx ≥ hy ≥ hz, any order) → segment along the longest axis, radius √(hy² + hz²);
- capsule                        → itself;
- mesh / anything else           → the capsule around its local axis-aligned bounding box.

Capsules are cheap to test exactly against axis-aligned boxes (containment) and against each
other (segment–segment distance), which is what makes a full-link, every-sample check affordable.
"""

from __future__ import annotations

from dataclasses import dataclass

import coal  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.core.errors import RobotModelError


@dataclass(frozen=True)
class Capsule:
    """A capsule rigidly attached to a joint of the (reduced) Pinocchio model.

    `p0_m` and `p1_m` are the segment end points in the frame of joint `joint_index`
    (the joint that moves the link), in metres.
    """

    name: str
    link: str
    joint_index: int
    p0_m: tuple[float, float, float]
    p1_m: tuple[float, float, float]
    radius_m: float


def _box_capsule(center: np.ndarray, rotation: np.ndarray, half_extents: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    axis = int(np.argmax(half_extents))
    others = [i for i in range(3) if i != axis]
    radius = float(np.hypot(half_extents[others[0]], half_extents[others[1]]))
    direction = rotation[:, axis] * half_extents[axis]
    return center - direction, center + direction, radius


def capsule_from_geometry(obj: pin.GeometryObject) -> tuple[np.ndarray, np.ndarray, float]:
    """The end points (in the parent joint frame) and radius of a capsule containing `obj`."""
    placement: pin.SE3 = obj.placement
    rotation = placement.rotation
    center = placement.translation
    geometry = obj.geometry
    if isinstance(geometry, (coal.Capsule, coal.Cylinder)):
        half = rotation[:, 2] * geometry.halfLength
        return center - half, center + half, float(geometry.radius)
    if isinstance(geometry, coal.Sphere):
        return center.copy(), center.copy(), float(geometry.radius)
    if isinstance(geometry, coal.Box):
        return _box_capsule(center, rotation, np.asarray(geometry.halfSide, dtype=float))
    try:
        geometry.computeLocalAABB()
        aabb = geometry.aabb_local
        local_center = (np.asarray(aabb.min_) + np.asarray(aabb.max_)) / 2.0
        half_extents = (np.asarray(aabb.max_) - np.asarray(aabb.min_)) / 2.0
    except Exception as exc:  # pragma: no cover - depends on exotic geometry types
        raise RobotModelError(
            f"collision geometry {obj.name!r} ({type(geometry).__name__}) has no bounding box"
        ) from exc
    return _box_capsule(center + rotation @ local_center, rotation, half_extents)
