"""Collision bodies as capsules: the one shape every safety check in ArmWarden reasons about.

A capsule is a segment `p0–p1` in a joint frame swept by a sphere of `radius_m`. Every URDF
collision primitive is replaced by a capsule that *contains* it, so checks on capsules are
conservative for the real geometry:

- cylinder (radius r, length L)  → the same axis segment, radius r (adds hemispherical caps);
- sphere (radius r)              → a zero-length capsule;
- box (half extents hx ≥ hy ≥ hz, any order) → segment along the longest axis, radius √(hy² + hz²);
- capsule                        → itself;
- mesh / anything else           → the capsule around its local axis-aligned bounding box.

The capsules a model checks: one per URDF primitive (`urdf_capsules`) or the fitted ones, cut down
to the policy's `check_links` (`checked_capsules`), which must leave no moving body out.

Capsules are cheap to test exactly against axis-aligned boxes (containment) and against each
other (segment–segment distance), which is what makes a full-link, every-sample check affordable.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
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


def urdf_capsules(model: pin.Model, geometry: pin.GeometryModel) -> tuple[Capsule, ...]:
    """One capsule around each collision primitive of the description (`capsule_from_geometry`)."""
    capsules = []
    for obj in geometry.geometryObjects:
        p0, p1, radius = capsule_from_geometry(obj)
        capsules.append(
            Capsule(
                name=obj.name,
                link=model.frames[obj.parentFrame].name,
                joint_index=int(obj.parentJoint),
                p0_m=(float(p0[0]), float(p0[1]), float(p0[2])),
                p1_m=(float(p1[0]), float(p1[1]), float(p1[2])),
                radius_m=radius,
            )
        )
    return tuple(capsules)


def checked_capsules(candidates: Sequence[Capsule], check_links: Sequence[str] | None,
                     link_names: Iterable[str]) -> tuple[Capsule, ...]:
    """The capsules of `check_links` (every one when None), after refusing a list that names a link
    not in `link_names` or leaves a moving body out. Bodies fixed to the world (joint 0) stay:
    nothing moves them into a zone, so only the self-collision check looks at them — the arm must
    not fold into its own base."""
    if check_links is None:
        return tuple(candidates)
    known = set(link_names)
    unknown = [name for name in check_links if name not in known]
    if unknown:
        raise RobotModelError(f"unknown link(s) in check_links {unknown}; valid links: {sorted(known)}")
    moving = moving_links(candidates)
    unchecked = [link for link in moving if link not in check_links]
    if unchecked:
        raise RobotModelError(
            f"check_links leaves {len(unchecked)} moving link(s) with collision geometry unchecked: {unchecked}; "
            f"the workspace, keep-out and self-collision checks would not see them. Name every one of {moving} "
            "(links fixed to the base may be added), or use null for every moving link"
        )
    wanted = set(check_links)
    return tuple(c for c in candidates if c.link in wanted)


def moving_links(capsules: Sequence[Capsule]) -> list[str]:
    """Links of `capsules` that a driven joint moves (not fixed to the world), first-seen order."""
    links: list[str] = []
    for capsule in capsules:
        if capsule.joint_index != 0 and capsule.link not in links:
            links.append(capsule.link)
    return links


def neighbour_rule_pairs(capsules: Sequence[Capsule]) -> np.ndarray:
    """Self-collision pairs for capsules taken from the URDF (no pair analysis): every pair
    whose joints are at least two apart (neighbours touch at their joint by design)."""
    pairs = [
        (a, b)
        for a in range(len(capsules))
        for b in range(a + 1, len(capsules))
        if abs(capsules[a].joint_index - capsules[b].joint_index) >= 2
    ]
    return np.array(pairs, dtype=np.intp).reshape(-1, 2)
