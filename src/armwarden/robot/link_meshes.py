"""Each link's collision surface as one `LinkMesh` in the link's own frame, ready for fitting.

Mesh files are taken as Pinocchio loaded them (coal's triangle model: the mesh scale applied), so
the surface fitted is the one Pinocchio and coal would check. Primitives become closed polytopes
that enclose them (never inscribed: a capsule holding every vertex of an inscribed polygon could
still cut through the true cylinder between its vertices): a box exactly, a sphere, an ellipsoid, a
cylinder and a capsule through latitude/longitude rings pushed out until every face lies on or
outside the true surface. A link with several shapes keeps them as separate parts (`components`),
which the fit covers part by part.
"""

from __future__ import annotations

import math
from typing import Any

import coal  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.core.errors import RobotModelError
from armwarden.robot.description_files import Description
from armwarden.robot.fitting_mesh import LinkMesh, box_mesh, merge_meshes, transform_mesh

#: segments around a round primitive's axis, and latitude bands from pole to pole (even: an equator)
AROUND, BANDS = 24, 12


def _rings(radius: float, half_length: float) -> tuple[np.ndarray, np.ndarray]:
    """A closed polytope enclosing the capsule of `radius` around the z segment ±`half_length`
    (a sphere when it is 0): latitude rings of a sphere, the northern half lifted by the half
    length, the equator doubled into a band; scaled so every face is at least `radius` from the
    segment (checked below)."""
    polar = np.arange(1, BANDS) * math.pi / BANDS
    azimuth = np.arange(AROUND) * 2.0 * math.pi / AROUND
    rings = []
    for k, theta in enumerate(polar):
        ring = np.column_stack([np.sin(theta) * np.cos(azimuth), np.sin(theta) * np.sin(azimuth),
                                np.full(AROUND, np.cos(theta))])
        north = k < BANDS // 2 - 1 or (k == BANDS // 2 - 1 and half_length > 0.0)
        if k == BANDS // 2 - 1 and half_length > 0.0:  # the equator, once for each half
            rings.append((ring, 1.0))
            rings.append((ring, -1.0))
        else:
            rings.append((ring, 1.0 if north else -1.0))
    unit = np.vstack([[0.0, 0.0, 1.0], *(r for r, _ in rings), [0.0, 0.0, -1.0]])
    lift = np.concatenate([[1.0], *(np.full(AROUND, s) for _, s in rings), [-1.0]]) * half_length
    n_rings = len(rings)
    triangles = [[0, 1 + i, 1 + (i + 1) % AROUND] for i in range(AROUND)]
    for r in range(n_rings - 1):
        a, b = 1 + r * AROUND, 1 + (r + 1) * AROUND
        for i in range(AROUND):
            j = (i + 1) % AROUND
            triangles += [[a + i, b + i, b + j], [a + i, b + j, a + j]]
    south = len(unit) - 1
    last = 1 + (n_rings - 1) * AROUND
    triangles += [[south, last + (i + 1) % AROUND, last + i] for i in range(AROUND)]
    faces = np.array(triangles, dtype=np.int64)
    # every face's plane must clear the capsule: its distance from the origin along the face normal,
    # for the unit sphere, is at least 1/scale; the lift moves both the plane and the segment's
    # support together (northern faces up, southern down, band faces are vertical)
    corners = unit[faces]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    lengths = np.linalg.norm(normals, axis=1)
    solid = lengths > 1e-12  # the doubled equator's band is flat on the unit sphere: lifted, it is vertical
    inner = float(np.min(np.abs(np.einsum("ij,ij->i", normals[solid] / lengths[solid, None], corners[solid, 0]))))
    scale = radius / inner
    return unit * scale + np.column_stack([np.zeros((len(unit), 2)), lift]), faces


def _outward(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The triangles of a convex polytope around the origin, each wound to face outward (the
    winding numbers the fit computes need one orientation)."""
    corners = vertices[triangles]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    inward = np.einsum("ij,ij->i", normals, corners.mean(axis=1)) < 0.0
    flipped = triangles.copy()
    flipped[inward] = flipped[inward][:, ::-1]
    return flipped


def _cylinder(radius: float, half_length: float) -> tuple[np.ndarray, np.ndarray]:
    """A prism around the z axis whose side faces touch the cylinder, with flat caps."""
    azimuth = np.arange(AROUND) * 2.0 * math.pi / AROUND
    outer = radius / math.cos(math.pi / AROUND)
    ring = np.column_stack([outer * np.cos(azimuth), outer * np.sin(azimuth)])
    vertices = np.vstack([np.column_stack([ring, np.full(AROUND, half_length)]),
                          np.column_stack([ring, np.full(AROUND, -half_length)]),
                          [[0.0, 0.0, half_length], [0.0, 0.0, -half_length]]])
    top, bottom = 2 * AROUND, 2 * AROUND + 1
    triangles = []
    for i in range(AROUND):
        j = (i + 1) % AROUND
        triangles += [[i, AROUND + i, AROUND + j], [i, AROUND + j, j], [top, i, j], [bottom, AROUND + j, AROUND + i]]
    return vertices, np.array(triangles, dtype=np.int64)


def shape_mesh(link: str, shape: Any, source: str) -> LinkMesh:
    """One coal shape as a closed mesh in its own frame; `RobotModelError` for a shape it cannot enclose."""
    if isinstance(shape, coal.BVHModelBase):
        vertices = np.asarray(shape.vertices(), dtype=float).reshape(-1, 3)
        triangles = np.array([[t[0], t[1], t[2]] for t in (shape.tri_indices(i) for i in range(shape.num_tris))],
                             dtype=np.int64).reshape(-1, 3)
        return LinkMesh(link, vertices, triangles, source)
    if isinstance(shape, coal.Box):
        return box_mesh(link, [2.0 * float(h) for h in shape.halfSide], (0.0, 0.0, 0.0), np.eye(3), source)
    if isinstance(shape, coal.Sphere):
        vertices, triangles = _rings(float(shape.radius), 0.0)
    elif isinstance(shape, coal.Capsule):
        vertices, triangles = _rings(float(shape.radius), float(shape.halfLength))
    elif isinstance(shape, coal.Ellipsoid):
        vertices, triangles = _rings(1.0, 0.0)
        vertices = vertices * np.asarray(shape.radii, dtype=float)  # the image of an enclosing polytope encloses
    elif isinstance(shape, coal.Cylinder):
        vertices, triangles = _cylinder(float(shape.radius), float(shape.halfLength))
    else:
        raise RobotModelError(f"link {link!r}: collision shape {type(shape).__name__} is not supported (meshes, "
                              "boxes, spheres, ellipsoids, cylinders and capsules are)")
    return LinkMesh(link, vertices, _outward(vertices, triangles), source)


def _source(obj: pin.GeometryObject) -> str:
    shape = obj.geometry
    if isinstance(shape, coal.BVHModelBase) and obj.meshPath:
        return obj.meshPath.rsplit("/", 1)[-1]
    return type(shape).__name__.lower()


def link_meshes(description: Description) -> dict[str, LinkMesh]:
    """Every link with collision geometry → its surface in the link frame, parts in description order."""
    if description.collision is None:
        raise RobotModelError(f"{description.path} was loaded without its collision geometry")
    model = description.model
    parts: dict[str, list[LinkMesh]] = {}
    for obj in description.collision.geometryObjects:
        frame = model.frames[obj.parentFrame]
        if isinstance(obj.geometry, (coal.Halfspace, coal.Plane)) and obj.parentFrame == 0:
            continue  # an MJCF floor: the world's, not a link's
        if frame.type != pin.FrameType.BODY:
            raise RobotModelError(f"collision shape {obj.name!r} is not attached to a link (frame {frame.name!r})")
        in_link = frame.placement.inverse() * obj.placement  # both relative to the parent joint
        mesh = shape_mesh(frame.name, obj.geometry, _source(obj))
        parts.setdefault(frame.name, []).append(transform_mesh(mesh, in_link.rotation, in_link.translation))
    return {link: meshes[0] if len(meshes) == 1 else merge_meshes(link, meshes, " + ".join(m.source for m in meshes))
            for link, meshes in parts.items()}


__all__ = ["AROUND", "BANDS", "link_meshes", "shape_mesh"]
