"""Capsules fitted to a robot's collision meshes: the fitting tool and the data file it writes.

One capsule around a box per link is conservative and far too fat (the FR3's wrist capsules
"collide" for every joint-6 angle ≥ 2.7 rad). This module fits *several* capsules per link to the
manufacturer's collision mesh so that they

- **contain the mesh, with a stated margin, by construction.** The mesh is subdivided into small
  triangles and every triangle is assigned to one capsule whose radius exceeds the distance of
  the triangle's three corners from the capsule's segment by at least `margin_m`. A capsule
  shrunk by the margin is convex, so it holds the whole triangle, not only its corners: every
  point of the mesh surface lies at least `margin_m` inside the union. The solid behind the
  surface is checked on a grid of interior points (winding number) and the fit is refused if any
  lies outside (`FittingError`).
- **hug the surface.** For 1, 2, … `max_bodies` capsules (started from the last set plus one
  where it reaches farthest beyond the mesh, and afresh from a k-means split; the better kept),
  a Lloyd-style loop alternates giving each surface piece to
  the capsule that overshoots the mesh least while holding it, and moving each capsule's segment
  (Nelder–Mead on its six end-point coordinates) to overshoot least while holding its pieces. A
  capsule's overshoot is estimated as its radius less the depth of its shallower end in the
  solid (exact when the farthest point lies over a face). The fewest capsules whose *measured*
  worst over-approximation — the largest distance from a point of the fitted surface to the
  mesh, on points at most `surface_spacing_m` apart (coal's exact point–mesh distance) — is
  within `body_tolerance_m` of the best are kept.

Capsules, not spheres: the envelope's predicates are exact for capsules already
(`armwarden.core.geometry`), a sphere is a zero-length capsule, and the FR3's links are
cylinders and rounded elbows that a few capsules hold without the scalloping a chain of spheres
leaves (docs/envelope.md, "Collision geometry fitted to the meshes").

The output is deterministic: fixed seeds, no data-dependent iteration order, every coordinate
rounded to `decimals` *before* the radius is computed from it (radii rounded up), so the same
meshes give the same bytes. Only `load_mesh` needs `trimesh` (the `fit` extra); it is imported
there, so the data model and `load_fitted` stay on the runtime's dependencies.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Literal

import coal  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, field_validator

from armwarden.core.errors import ArmWardenError

__all__ = [
    "ExcludedPair",
    "FitOptions",
    "FittedBody",
    "FittedGeometry",
    "FittingError",
    "LinkFit",
    "LinkMesh",
    "box_mesh",
    "capsule_surface_points",
    "fit_link",
    "load_fitted",
    "load_mesh",
    "merge_meshes",
    "mesh_distances",
    "point_segment_distances",
    "render_fitted",
    "rotate_fit",
    "subdivide",
    "transform_mesh",
    "winding_numbers",
]

FORMAT = "armwarden-fitted-geometry/1"
#: a part no vertex of which lies farther than this above a face's plane counts as convex [m]
_CONVEX_TOLERANCE_M = 0.002


class FittingError(ArmWardenError):
    """A fit that does not hold its mesh, or a data file that does not parse."""


# --------------------------------------------------------------------------- data model


@dataclass(frozen=True)
class FittedBody:
    """A capsule in its link's frame: segment `p0_m`–`p1_m` swept by a ball of `radius_m` [m]."""

    name: str
    p0_m: tuple[float, float, float]
    p1_m: tuple[float, float, float]
    radius_m: float


@dataclass(frozen=True)
class LinkMesh:
    """A link's collision surface in the link frame [m]: vertices (n, 3) and triangles (m, 3)."""

    link: str
    vertices: np.ndarray
    triangles: np.ndarray
    source: str
    #: per triangle, which closed surface it belongs to (a finger is several overlapping boxes)
    components: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def __post_init__(self) -> None:
        if len(self.components) != len(self.triangles):
            object.__setattr__(self, "components", np.zeros(len(self.triangles), dtype=np.int64))

    def unique_vertices(self) -> np.ndarray:
        """The distinct vertices, sorted (the vertex cloud the containment test reads)."""
        return np.unique(self.vertices[np.unique(self.triangles)], axis=0)


@dataclass(frozen=True)
class LinkFit:
    """The fitted capsules of one link and how well they fit."""

    link: str
    source: str
    bodies: tuple[FittedBody, ...]
    n_vertices: int
    n_triangles: int
    worst_over_approximation_m: float
    #: the worst over-approximation for each number of capsules tried (1, 2, …), measured on
    #: points twice as far apart as the reported figure's; for a mesh of several parts, that of
    #: each part's chosen capsules
    tried_m: tuple[float, ...]
    #: SHA-256 of the unique vertices (float32, little-endian, sorted) the fit was made to hold
    vertices_sha256: str = ""


@dataclass(frozen=True)
class FitOptions:
    """Settings of `fit_link`, all in metres unless named otherwise."""

    margin_m: float = 0.001  # every mesh point lies at least this far inside the union
    max_edge_m: float = 0.02  # triangles are halved until no edge is longer
    interior_pitch_m: float = 0.005  # grid spacing of the interior points checked after the fit
    surface_spacing_m: float = 0.002  # spacing of the points the over-approximation is measured on
    max_bodies: int = 6
    #: the fewest capsules whose worst over-approximation is within this of the best tried
    body_tolerance_m: float = 0.002
    decimals: int = 5  # rounding of every coordinate and radius in the output (5: 10 µm)
    lloyd_iterations: int = 25
    simplex_evaluations: int = 1200

    def __post_init__(self) -> None:
        if not (self.margin_m >= 0 and self.max_edge_m > 0 and self.interior_pitch_m > 0 and self.surface_spacing_m > 0):
            raise FittingError("margin_m must be ≥ 0 and every spacing > 0")
        if self.max_bodies < 1 or self.decimals < 3:
            raise FittingError("max_bodies must be ≥ 1 and decimals ≥ 3")


# --------------------------------------------------------------------------- geometry helpers


def point_segment_distances(points: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """Distances (N, K) from each of `points` (N, 3) to each segment `p0[k]`–`p1[k]` (K, 3)."""
    points = np.asarray(points, dtype=float)
    p0 = np.atleast_2d(np.asarray(p0, dtype=float))
    p1 = np.atleast_2d(np.asarray(p1, dtype=float))
    d = p1 - p0  # (K, 3)
    length2 = np.einsum("ki,ki->k", d, d)
    rel = points[:, None, :] - p0[None, :, :]  # (N, K, 3)
    t = np.einsum("nki,ki->nk", rel, d) / np.where(length2 > 0.0, length2, 1.0)
    t = np.clip(np.where(length2 > 0.0, t, 0.0), 0.0, 1.0)
    closest = rel - t[..., None] * d[None, :, :]
    return np.sqrt(np.einsum("nki,nki->nk", closest, closest))


def box_mesh(link: str, size_m: Sequence[float], origin_m: Sequence[float], rotation: np.ndarray, source: str) -> LinkMesh:
    """The 8 corners and 12 triangles of a box (URDF `<box size>` at `origin`, rotated)."""
    half = np.asarray(size_m, dtype=float) / 2.0
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    corners = (signs * half) @ np.asarray(rotation, dtype=float).T + np.asarray(origin_m, dtype=float)
    # corner index = 4·(x>0) + 2·(y>0) + (z>0); two triangles per face, outward winding
    faces = [
        (0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5),  # x−, x+
        (0, 4, 5), (0, 5, 1), (2, 3, 7), (2, 7, 6),  # y−, y+
        (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3),  # z−, z+
    ]
    return LinkMesh(link, corners, np.array(faces, dtype=np.int64), source)


def merge_meshes(link: str, meshes: Sequence[LinkMesh], source: str) -> LinkMesh:
    """Several closed surfaces of one link as one triangle set (each stays closed)."""
    vertices, triangles, components, offset = [], [], [], 0
    for number, mesh in enumerate(meshes):
        vertices.append(mesh.vertices)
        triangles.append(mesh.triangles + offset)
        components.append(np.full(len(mesh.triangles), number, dtype=np.int64))
        offset += len(mesh.vertices)
    return LinkMesh(link, np.vstack(vertices), np.vstack(triangles), source, np.concatenate(components))


def transform_mesh(mesh: LinkMesh, rotation: np.ndarray, translation_m: Sequence[float], source: str | None = None) -> LinkMesh:
    """The mesh in another frame: p' = R p + t."""
    vertices = mesh.vertices @ np.asarray(rotation, dtype=float).T + np.asarray(translation_m, dtype=float)
    return LinkMesh(mesh.link, vertices, mesh.triangles, source or mesh.source, mesh.components)


def load_mesh(link: str, data: bytes, file_type: str, source: str) -> LinkMesh:
    """A mesh file's (STL/OBJ/DAE bytes) vertices and triangles, merged and as written.

    `trimesh` is imported here only: the fitting tool needs it, the runtime does not.
    """
    import io

    import trimesh  # pyright: ignore[reportMissingImports] - the optional `fit` extra

    loaded: Any = trimesh.load(io.BytesIO(data), file_type=file_type, force="mesh", process=True)
    vertices = np.asarray(loaded.vertices, dtype=float)
    triangles = np.asarray(loaded.faces, dtype=np.int64)
    if len(triangles) == 0:
        raise FittingError(f"{source}: no triangles")
    return LinkMesh(link, vertices, triangles, source)


def subdivide(vertices: np.ndarray, triangles: np.ndarray, max_edge_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Halve every triangle across its longest edge until no edge exceeds `max_edge_m`.

    The halves tile the triangle exactly, so a set holding every piece holds the triangle.
    Returns the points (shared corners merged) and the pieces as corner indices.
    """
    points = [tuple(float(c) for c in v) for v in vertices]
    index = {p: i for i, p in enumerate(points)}
    coords = [np.array(p) for p in points]

    def midpoint(i: int, j: int) -> int:
        key = tuple(float(c) for c in (coords[i] + coords[j]) / 2.0)
        if key not in index:
            index[key] = len(coords)
            coords.append(np.array(key))
        return index[key]

    pieces: list[tuple[int, int, int]] = []
    stack = [tuple(int(i) for i in tri) for tri in triangles[::-1]]
    while stack:
        a, b, c = stack.pop()
        edges = (np.linalg.norm(coords[b] - coords[a]), np.linalg.norm(coords[c] - coords[b]), np.linalg.norm(coords[a] - coords[c]))
        longest = int(np.argmax(edges))
        if edges[longest] <= max_edge_m:
            pieces.append((a, b, c))
            continue
        a, b, c = ((a, b, c), (b, c, a), (c, a, b))[longest]  # a–b is the longest edge
        m = midpoint(a, b)
        stack += [(m, b, c), (a, m, c)]
    return np.array(coords), np.array(pieces, dtype=np.int64)


def winding_numbers(points: np.ndarray, vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Generalised winding number of each point (≈1 inside a closed surface, ≈0 outside;
    overlapping closed surfaces add up). Van Oosterom–Strackee solid angles, summed."""
    total = np.zeros(len(points))
    tri = vertices[triangles]  # (M, 3, 3)
    for start in range(0, len(points), 512):
        rel = tri[None, :, :, :] - points[start:start + 512, None, None, :]  # (n, M, 3, 3)
        a, b, c = rel[:, :, 0], rel[:, :, 1], rel[:, :, 2]
        la, lb, lc = (np.linalg.norm(v, axis=-1) for v in (a, b, c))
        det = np.einsum("nmi,nmi->nm", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("nmi,nmi->nm", a, b) * lc + np.einsum("nmi,nmi->nm", b, c) * la
               + np.einsum("nmi,nmi->nm", c, a) * lb)
        total[start:start + 512] = np.sum(2.0 * np.arctan2(det, den), axis=1) / (4.0 * math.pi)
    return total


def mesh_distances(mesh: LinkMesh, points: np.ndarray) -> np.ndarray:
    """Distance from each point to the mesh's surface (coal's BVH distance; exact)."""
    return _distances(_bvh(mesh), points)


def _bvh(mesh: LinkMesh) -> coal.BVHModelOBBRSS:
    bvh = coal.BVHModelOBBRSS()
    bvh.beginModel(len(mesh.triangles), len(mesh.vertices))
    bvh.addVertices(np.ascontiguousarray(mesh.vertices, dtype=float))
    bvh.addTriangles(np.ascontiguousarray(mesh.triangles, dtype=np.int64))
    bvh.endModel()
    return bvh


def _distances(bvh: coal.BVHModelOBBRSS, points: np.ndarray) -> np.ndarray:
    probe, identity, request, rotation = coal.Sphere(0.0), coal.Transform3s(), coal.DistanceRequest(), np.eye(3)
    out = np.empty(len(points))
    for k, point in enumerate(points):
        out[k] = coal.distance(bvh, identity, probe, coal.Transform3s(rotation, point), request, coal.DistanceResult())
    return out


def capsule_surface_points(p0: np.ndarray, p1: np.ndarray, radius: float, spacing: float) -> np.ndarray:
    """Points on a capsule's surface, no surface point farther than about `spacing` from one."""
    axis = p1 - p0
    length = float(np.linalg.norm(axis))
    w = axis / length if length > 0 else np.array([0.0, 0.0, 1.0])
    helper = np.array([1.0, 0.0, 0.0]) if abs(w[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(w, helper)
    u /= np.linalg.norm(u)
    v = np.cross(w, u)
    n_around = max(8, math.ceil(2 * math.pi * radius / spacing))
    phi = np.arange(n_around) * (2 * math.pi / n_around)
    ring = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v  # (n_around, 3)
    points = []
    n_along = max(1, math.ceil(length / spacing))
    for t in np.linspace(0.0, 1.0, n_along + 1):
        points.append(p0 + t * axis + radius * ring)
    n_polar = max(2, math.ceil((math.pi / 2) * radius / spacing))
    for end, sign in ((p1, 1.0), (p0, -1.0)):
        for theta in np.linspace(0.0, math.pi / 2, n_polar + 1)[1:]:
            count = max(1, math.ceil(2 * math.pi * radius * math.cos(theta) / spacing))
            around = np.arange(count) * (2 * math.pi / count)
            circle = np.cos(around)[:, None] * u + np.sin(around)[:, None] * v
            points.append(end + radius * (math.cos(theta) * circle + sign * math.sin(theta) * w))
    return np.vstack(points)


# --------------------------------------------------------------------------- the fit


def _nelder_mead(f: Callable[[np.ndarray], float], x0: np.ndarray, step: float, max_evals: int) -> np.ndarray:
    """Minimise f from x0 (plain Nelder–Mead, deterministic). No SciPy in the runtime's set."""
    n = len(x0)
    simplex = [x0.copy()] + [x0 + step * np.eye(n)[i] for i in range(n)]
    values = [f(x) for x in simplex]
    evals = n + 1
    while evals < max_evals:
        order = np.argsort(values, kind="stable")
        simplex = [simplex[i] for i in order]
        values = [values[i] for i in order]
        if values[-1] - values[0] <= 1e-12 * max(1.0, abs(values[0])) and np.max(
            np.abs(np.array(simplex[1:]) - simplex[0])
        ) < 1e-7:
            break
        centroid = np.mean(simplex[:-1], axis=0)
        reflected = centroid + (centroid - simplex[-1])
        f_r = f(reflected)
        evals += 1
        if f_r < values[0]:
            expanded = centroid + 2.0 * (centroid - simplex[-1])
            f_e = f(expanded)
            evals += 1
            simplex[-1], values[-1] = (expanded, f_e) if f_e < f_r else (reflected, f_r)
            continue
        if f_r < values[-2]:
            simplex[-1], values[-1] = reflected, f_r
            continue
        contracted = centroid + 0.5 * (simplex[-1] - centroid) if f_r >= values[-1] else centroid + 0.5 * (reflected - centroid)
        f_c = f(contracted)
        evals += 1
        if f_c < min(f_r, values[-1]):
            simplex[-1], values[-1] = contracted, f_c
            continue
        for i in range(1, n + 1):
            simplex[i] = simplex[0] + 0.5 * (simplex[i] - simplex[0])
            values[i] = f(simplex[i])
        evals += n
    return simplex[int(np.argmin(values))]


def _initial_segments(points: np.ndarray, k: int) -> np.ndarray:
    """k segments from a farthest-point k-means of `points`, each along its cluster's principal axis."""
    centre = points.mean(axis=0)
    seeds = [int(np.argmax(np.linalg.norm(points - centre, axis=1)))]
    for _ in range(1, k):
        nearest = np.min(np.linalg.norm(points[:, None, :] - points[seeds][None], axis=2), axis=1)
        seeds.append(int(np.argmax(nearest)))
    centres = points[seeds].copy()
    for _ in range(30):
        label = np.argmin(np.linalg.norm(points[:, None, :] - centres[None], axis=2), axis=1)
        centres = np.array([points[label == i].mean(axis=0) if np.any(label == i) else centres[i] for i in range(k)])
    label = np.argmin(np.linalg.norm(points[:, None, :] - centres[None], axis=2), axis=1)
    segments = []
    for i in range(k):
        cluster = points[label == i]
        if len(cluster) < 2:
            segments.append(np.concatenate([centres[i], centres[i]]))
            continue
        mean = cluster.mean(axis=0)
        _, _, vt = np.linalg.svd(cluster - mean, full_matrices=False)
        axis = vt[0] * (1.0 if vt[0][np.argmax(np.abs(vt[0]))] > 0 else -1.0)  # a fixed sign: deterministic
        along = (cluster - mean) @ axis
        spread = np.max(np.linalg.norm((cluster - mean) - along[:, None] * axis, axis=1))
        lo, hi = float(np.min(along)), float(np.max(along))
        inset = min(spread, (hi - lo) / 2.0)
        segments.append(np.concatenate([mean + (lo + inset) * axis, mean + (hi - inset) * axis]))
    return np.array(segments)


@dataclass
class _Problem:
    """The subdivided surface (points, pieces as corner indices) and the mesh's signed depth."""

    mesh: LinkMesh
    points: np.ndarray
    pieces: np.ndarray

    def needs(self, segments: np.ndarray) -> np.ndarray:
        """(E, K): how far each piece's farthest corner is from each segment."""
        dist = point_segment_distances(self.points, segments[:, :3], segments[:, 3:])
        return np.max(dist[self.pieces], axis=1)

    def __post_init__(self) -> None:
        tri = self.mesh.vertices[self.mesh.triangles]
        normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        lengths = np.linalg.norm(normals, axis=1)
        keep = lengths > 1e-15  # a degenerate triangle has no plane
        self._normals = normals[keep] / lengths[keep, None]
        self._offsets = np.einsum("fi,fi->f", self._normals, tri[keep, 0])
        self._component = self.mesh.components[keep]
        self._labels = np.unique(self._component)
        heights = self.mesh.vertices @ self._normals.T - self._offsets[None, :]  # (V, F): above each face plane
        self._convex = bool(np.max(heights) <= _CONVEX_TOLERANCE_M) if len(self._labels) == 1 else True
        self._bvh = None if self._convex else _bvh(self.mesh)

    def depth(self, points: np.ndarray) -> np.ndarray:
        """Depth of each point in the solid, negative outside. For convex parts (the FR3's meshes
        are convex to within 1 mm; boxes are) the least distance to a face plane, the deepest part
        counting; otherwise the distance to the surface, signed by the winding number. It only
        steers the fit: containment is enforced and the over-approximation measured separately."""
        points = np.atleast_2d(points)
        if self._bvh is not None:
            inside = winding_numbers(points, self.mesh.vertices, self.mesh.triangles) > 0.5
            return np.where(inside, 1.0, -1.0) * _distances(self._bvh, points)
        heights = self._offsets[None, :] - points @ self._normals.T  # (N, F)
        return np.max([np.min(heights[:, self._component == c], axis=1) for c in self._labels], axis=0)

    def end_depth(self, segments: np.ndarray) -> np.ndarray:
        """(K,): the shallower end point's depth of each segment."""
        return np.minimum(self.depth(segments[:, :3]), self.depth(segments[:, 3:]))


def _overshoot(problem: _Problem, points: np.ndarray, segment: np.ndarray) -> float:
    """How far the capsule on `segment` that holds `points` reaches beyond the solid, estimated:
    its radius minus its shallower end's depth (exact where the farthest point of the capsule
    from the solid lies over a face, which is where it lies for a convex solid)."""
    radius = float(np.max(point_segment_distances(points, segment[:3], segment[3:])))
    return radius - float(problem.end_depth(segment[None])[0])


def _lloyd(problem: _Problem, segments: np.ndarray, options: FitOptions) -> np.ndarray:
    """Alternate (1) each piece to the capsule it overshoots least from, (2) each capsule's segment
    to the least overshoot holding its pieces, until the assignment settles. Both steps only
    lower the worst overshoot, so the loop descends."""
    segments = segments.copy()
    assign = np.argmin(problem.needs(segments) - problem.end_depth(segments)[None, :], axis=1)
    for _ in range(options.lloyd_iterations):
        for i in range(len(segments)):
            members = np.unique(problem.pieces[assign == i].ravel())
            if len(members) == 0:
                continue
            held = problem.points[members]
            x = segments[i]
            for step in (0.01, 0.003):
                x = _nelder_mead(lambda s, held=held: _overshoot(problem, held, s), x, step, options.simplex_evaluations)
            segments[i] = x
        new_assign = np.argmin(problem.needs(segments) - problem.end_depth(segments)[None, :], axis=1)
        if np.array_equal(new_assign, assign):
            break
        assign = new_assign
    used = [i for i in range(len(segments)) if np.any(assign == i)]
    return segments[used]


def _split(problem: _Problem, segments: np.ndarray) -> np.ndarray:
    """One more capsule: a point capsule at the piece the current set overshoots most from."""
    over = np.min(problem.needs(segments) - problem.end_depth(segments)[None, :], axis=1)
    worst = problem.points[problem.pieces[int(np.argmax(over))]].mean(axis=0)
    return np.vstack([segments, np.concatenate([worst, worst])])


def _sized(problem: _Problem, segments: np.ndarray, options: FitOptions) -> tuple[np.ndarray, np.ndarray]:
    """Round the segments; give each piece to the capsule it overshoots least from; size each
    radius to hold its pieces; then shrink: a piece another capsule already holds leaves, the
    fattest capsule first, until nothing moves. Radii get the margin and are rounded up, so
    rounding never lets a piece out."""
    scale = 10.0**options.decimals
    segments = np.round(segments * scale) / scale
    needs = problem.needs(segments)
    assign = np.argmin(needs - problem.end_depth(segments)[None, :], axis=1)
    k = len(segments)

    def radii_of(assignment: np.ndarray) -> np.ndarray:
        return np.array([np.max(needs[assignment == i, i]) if np.any(assignment == i) else 0.0 for i in range(k)])

    radii = radii_of(assign)
    for _ in range(4 * k):
        moved = False
        for i in np.argsort(-radii, kind="stable"):
            mine = np.flatnonzero(assign == i)
            held = needs[mine] <= radii[None, :]
            held[:, i] = False
            movable = np.any(held, axis=1)
            if np.any(movable):
                assign[mine[movable]] = np.argmax(held[movable], axis=1)
                radii = radii_of(assign)
                moved = True
        if not moved:
            break
    used = np.array([np.any(assign == i) for i in range(k)])
    radii = np.ceil((radii + options.margin_m) * scale - 1e-9) / scale
    return segments[used], radii[used]


def _over_approximation(mesh: LinkMesh, segments: np.ndarray, radii: np.ndarray, spacing: float) -> float:
    """Largest distance from a point of the union's outer surface to the mesh (sampled)."""
    worst = 0.0
    for i, (seg, radius) in enumerate(zip(segments, radii, strict=True)):
        points = capsule_surface_points(seg[:3], seg[3:], float(radius), spacing)
        others = [j for j in range(len(segments)) if j != i]
        if others:
            dist = point_segment_distances(points, segments[others, :3], segments[others, 3:])
            points = points[np.all(dist >= radii[others] - 1e-9, axis=1)]
        if len(points):
            worst = max(worst, float(np.max(mesh_distances(mesh, points))))
    return worst


def _interior_points(mesh: LinkMesh, pitch: float) -> np.ndarray:
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    axes = [np.arange(lo[i] + pitch / 2, hi[i], pitch) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return grid[winding_numbers(grid, mesh.vertices, mesh.triangles) > 0.5]


def _cover_interior(interior: np.ndarray, segments: np.ndarray, radii: np.ndarray, options: FitOptions) -> np.ndarray:
    """Radii grown (segments never move) until every interior grid point is inside the union
    with the margin: an uncovered point widens the capsule that needs the least growth."""
    radii = radii.copy()
    if len(interior) == 0:
        return radii
    scale = 10.0**options.decimals
    dist = point_segment_distances(interior, segments[:, :3], segments[:, 3:]) + options.margin_m
    for row in dist:
        if not np.any(row <= radii):
            i = int(np.argmin(row - radii))
            radii[i] = np.ceil(row[i] * scale - 1e-9) / scale
    return radii


def fit_link(mesh: LinkMesh, options: FitOptions | None = None) -> LinkFit:
    """Capsules containing `mesh` with `options.margin_m`: the fewest whose worst
    over-approximation is within `body_tolerance_m` of the best tried with up to `max_bodies`.

    A mesh of several closed parts (a finger's four boxes) is fitted part by part — fitted
    together, a capsule straddles two parts and bulges over the space between them — and each
    part gets the fewest capsules within `body_tolerance_m` of what the worst part can reach.
    Raises `FittingError` if a vertex, a surface piece or an interior grid point is left outside.
    """
    options = options or FitOptions()
    parts = _parts(mesh)
    candidates = [_fit_part(part, options) for part in parts]
    # the union is as good as its worst part at best: no part needs to be much better than that
    reachable = max(min(c[2] for c in part) for part in candidates)
    chosen = [next(c for c in part if c[2] <= reachable + options.body_tolerance_m) for part in candidates]
    tried = [c[2] for c in candidates[0]] if len(parts) == 1 else [c[2] for c in chosen]
    segments = np.vstack([c[0] for c in chosen])
    radii = np.concatenate([c[1] for c in chosen])
    worst = _over_approximation(mesh, segments, radii, options.surface_spacing_m)
    bodies = tuple(
        FittedBody(
            name=f"{mesh.link}/{i}",
            p0_m=(float(s[0]), float(s[1]), float(s[2])),
            p1_m=(float(s[3]), float(s[4]), float(s[5])),
            radius_m=float(r),
        )
        for i, (s, r) in enumerate(zip(segments, radii, strict=True))
    )
    return LinkFit(
        link=mesh.link,
        source=mesh.source,
        bodies=bodies,
        n_vertices=len(mesh.unique_vertices()),
        n_triangles=len(mesh.triangles),
        worst_over_approximation_m=round(worst, 4),
        tried_m=tuple(round(t, 4) for t in tried),
    )


def _parts(mesh: LinkMesh) -> list[LinkMesh]:
    """The mesh's closed parts (by `components`), each with only its own vertices."""
    labels = np.unique(mesh.components)
    if len(labels) == 1:
        return [mesh]
    parts = []
    for label in labels:
        triangles = mesh.triangles[mesh.components == label]
        used = np.unique(triangles)
        parts.append(LinkMesh(mesh.link, mesh.vertices[used], np.searchsorted(used, triangles), mesh.source))
    return parts


def _fit_part(mesh: LinkMesh, options: FitOptions) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """(segments, radii, measured over-approximation) with 1, 2, … capsules for one closed part,
    each checked to hold the part.

    Triangles are halved to `max_edge_m` or a tenth of the part's size, whichever is smaller,
    so that a small part still gets pieces to share out."""
    size = float(np.linalg.norm(mesh.vertices.max(axis=0) - mesh.vertices.min(axis=0)))
    points, pieces = subdivide(mesh.vertices, mesh.triangles, min(options.max_edge_m, size / 10.0))
    problem = _Problem(mesh, points, pieces)
    interior = _interior_points(mesh, min(options.interior_pitch_m, size / 10.0))
    candidates: list[tuple[np.ndarray, np.ndarray, float]] = []
    previous: np.ndarray | None = None
    for k in range(1, options.max_bodies + 1):
        # two starts: the last set plus a capsule where it reaches farthest out, and a fresh
        # k-means split (which finds the arms of an L that one big capsule hides)
        starts = [_initial_segments(points, k)] if previous is None else [_split(problem, previous), _initial_segments(points, k)]
        tried = []
        for start in starts:
            segments = _lloyd(problem, start, options)
            sized, radii = _sized(problem, segments, options)
            radii = _cover_interior(interior, sized, radii, options)
            _verify(mesh, problem, interior, sized, radii, options.margin_m)
            # measured (on a coarser sampling than the reported figure): the depth estimate that
            # steers the fit is exact over faces only
            tried.append((segments, sized, radii, _over_approximation(mesh, sized, radii, 2.0 * options.surface_spacing_m)))
        previous, sized, radii, over = min(tried, key=lambda t: t[3])  # the first on a tie
        candidates.append((sized, radii, over))
    return candidates


def rotate_fit(fit: LinkFit, rotation: np.ndarray, link: str, decimals: int = FitOptions.decimals) -> LinkFit:
    """The same capsules seen from a frame turned by `rotation` (p' = R p), for `link`.

    End points are rounded to `decimals` again; if that moved any, every radius grows by the
    largest such move (rounded up), so the turned set still holds everything the original held.
    """
    rotation = np.asarray(rotation, dtype=float)
    scale = 10.0**decimals
    bodies = []
    for number, body in enumerate(fit.bodies):
        ends = np.array([body.p0_m, body.p1_m]) @ rotation.T
        rounded = np.round(ends * scale) / scale
        moved = float(np.max(np.linalg.norm(rounded - ends, axis=1)))
        radius = body.radius_m if moved == 0.0 else math.ceil((body.radius_m + moved) * scale) / scale
        bodies.append(FittedBody(f"{link}/{number}", tuple(float(v) for v in rounded[0]),  # type: ignore[arg-type]
                                 tuple(float(v) for v in rounded[1]), radius))  # type: ignore[arg-type]
    return LinkFit(link, fit.source, tuple(bodies), fit.n_vertices, fit.n_triangles, fit.worst_over_approximation_m,
                   fit.tried_m, fit.vertices_sha256)


def _verify(mesh: LinkMesh, problem: _Problem, interior: np.ndarray, segments: np.ndarray, radii: np.ndarray,
            margin: float) -> None:
    inner = radii - margin + 1e-12
    if not np.all(np.any(problem.needs(segments) <= inner, axis=1)):
        raise FittingError(f"{mesh.link}: a surface piece lies outside every fitted capsule")
    vertex_dist = point_segment_distances(mesh.unique_vertices(), segments[:, :3], segments[:, 3:])
    if not np.all(np.any(vertex_dist <= inner, axis=1)):
        raise FittingError(f"{mesh.link}: a mesh vertex lies outside every fitted capsule")
    if len(interior):
        dist = point_segment_distances(interior, segments[:, :3], segments[:, 3:])
        if not np.all(np.any(dist <= inner, axis=1)):
            raise FittingError(f"{mesh.link}: an interior point lies outside every fitted capsule")


# --------------------------------------------------------------------------- the data file


class _BodyModel(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    name: str
    p0: tuple[float, float, float]
    p1: tuple[float, float, float]
    radius: float = Field(gt=0)


class _LinkModel(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    source: str
    vertices: int = Field(ge=0)
    triangles: int = Field(ge=0)
    worst_over_approximation_m: float = Field(ge=0)
    tried_m: list[float]
    vertices_sha256: str = Field(pattern=r"^([0-9a-f]{64})?$")
    bodies: list[_BodyModel] = Field(min_length=1)


class _ExcludedModel(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    bodies: tuple[str, str]
    reason: Literal["apart", "overlapping", "adjacent"]
    proof: str


class _PairsModel(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    joint_limits: dict[str, tuple[float, float]]
    clearance_m: float = Field(ge=0)
    included: list[tuple[str, str]]
    excluded: list[_ExcludedModel]


class _FileModel(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    format: Literal["armwarden-fitted-geometry/1"]
    robot: str
    source: dict[str, str]
    margin_m: float = Field(ge=0)
    links: dict[str, _LinkModel]
    pairs: _PairsModel | None = None

    @field_validator("links")
    @classmethod
    def _names_match_links(cls, links: dict[str, _LinkModel]) -> dict[str, _LinkModel]:
        for link, entry in links.items():
            for body in entry.bodies:
                if not body.name.startswith(f"{link}/"):
                    raise ValueError(f"body {body.name!r} is listed under link {link!r}")
        return links


@dataclass(frozen=True)
class ExcludedPair:
    """A body pair left out of self-collision checks, and the proof that it may be."""

    bodies: tuple[str, str]
    reason: Literal["apart", "overlapping", "adjacent"]
    proof: str


@dataclass(frozen=True)
class FittedGeometry:
    """What a fitted-geometry file holds: capsules per link (link frame, metres) and the pair analysis."""

    robot: str
    source: Mapping[str, str]
    margin_m: float
    links: Mapping[str, LinkFit]
    joint_limits: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    #: excluded "apart" pairs stay at least this far apart (capsule surfaces) [m]
    pair_clearance_m: float = 0.0
    included_pairs: tuple[tuple[str, str], ...] = ()
    excluded_pairs: tuple[ExcludedPair, ...] = ()

    def bodies(self) -> dict[str, FittedBody]:
        """Every body by name, in file order."""
        return {body.name: body for fit in self.links.values() for body in fit.bodies}


def load_fitted(path: Path) -> FittedGeometry:
    """Read and validate a fitted-geometry file.

    The file is read every time; what it says is parsed once per distinct content (`_parse_fitted`):
    every robot model reads it (every daemon start, every Guard a test builds), and parsing the
    bundled ~4,000 lines costs 0.05-0.1 s even with libyaml, which made YAML most of the test
    suite's time. The result is immutable, so sharing it is safe."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise FittingError(f"cannot read fitted geometry {path}: {exc}") from exc
    return _parse_fitted(text, str(path))


@functools.lru_cache(maxsize=8)
def _parse_fitted(text: str, path: str) -> FittedGeometry:
    """The geometry `text` (the file at `path`) describes; a memo of a pure function of its arguments."""
    try:
        # libyaml's safe loader where PyYAML has it (0.05 s instead of 0.4 s for the bundled file)
        loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
        raw = yaml.load(text, Loader=loader)  # a safe loader either way
        parsed = _FileModel.model_validate(raw)
    except (yaml.YAMLError, ValueError) as exc:
        raise FittingError(f"cannot read fitted geometry {path}: {exc}") from exc
    links = {
        name: LinkFit(
            link=name,
            source=entry.source,
            bodies=tuple(FittedBody(b.name, b.p0, b.p1, b.radius) for b in entry.bodies),
            n_vertices=entry.vertices,
            n_triangles=entry.triangles,
            worst_over_approximation_m=entry.worst_over_approximation_m,
            tried_m=tuple(entry.tried_m),
            vertices_sha256=entry.vertices_sha256,
        )
        for name, entry in parsed.links.items()
    }
    pairs = parsed.pairs
    return FittedGeometry(  # read-only mappings: one parse is shared by every model of this content
        robot=parsed.robot,
        source=MappingProxyType(dict(parsed.source)),
        margin_m=parsed.margin_m,
        links=MappingProxyType(links),
        joint_limits=MappingProxyType(dict(pairs.joint_limits) if pairs else {}),
        pair_clearance_m=pairs.clearance_m if pairs else 0.0,
        included_pairs=tuple(tuple(p) for p in pairs.included) if pairs else (),  # type: ignore[misc]
        excluded_pairs=tuple(ExcludedPair(e.bodies, e.reason, e.proof) for e in pairs.excluded) if pairs else (),
    )


def _num(value: float) -> str:
    text = repr(float(value))
    return "0.0" if text == "-0.0" else text


def _vec(values: Sequence[float]) -> str:
    return "[" + ", ".join(_num(v) for v in values) + "]"


def render_fitted(geometry: FittedGeometry, header: Sequence[str]) -> str:
    """The data file's text: `header` as comment lines, then YAML in a fixed order (same input,
    same bytes)."""
    lines = [f"# {line}".rstrip() for line in header]
    lines += [f"format: {FORMAT}", f"robot: {geometry.robot}", "source:"]
    lines += [f"  {key}: {_quote(value)}" for key, value in geometry.source.items()]
    lines += [f"margin_m: {_num(geometry.margin_m)}", "links:"]
    for name, fit in geometry.links.items():
        lines += [
            f"  {name}:",
            f"    source: {_quote(fit.source)}",
            f"    vertices: {fit.n_vertices}",
            f"    triangles: {fit.n_triangles}",
            f"    worst_over_approximation_m: {_num(fit.worst_over_approximation_m)}",
            f"    tried_m: {_vec(fit.tried_m)}",
            f"    vertices_sha256: {_quote(fit.vertices_sha256)}",
            "    bodies:",
        ]
        lines += [
            f"      - {{name: {body.name}, p0: {_vec(body.p0_m)}, p1: {_vec(body.p1_m)}, radius: {_num(body.radius_m)}}}"
            for body in fit.bodies
        ]
    if geometry.joint_limits or geometry.included_pairs or geometry.excluded_pairs:
        lines += ["pairs:", "  joint_limits:"]
        lines += [f"    {joint}: {_vec(limits)}" for joint, limits in geometry.joint_limits.items()]
        lines += [f"  clearance_m: {_num(geometry.pair_clearance_m)}"]
        lines += ["  included:"] + [f"    - [{a}, {b}]" for a, b in geometry.included_pairs]
        if not geometry.included_pairs:
            lines[-1] = "  included: []"
        lines += ["  excluded:"]
        for pair in geometry.excluded_pairs:
            lines += [
                f"    - bodies: [{pair.bodies[0]}, {pair.bodies[1]}]",
                f"      reason: {pair.reason}",
                f"      proof: {_quote(pair.proof)}",
            ]
        if not geometry.excluded_pairs:
            lines[-1] = "  excluded: []"
    return "\n".join(lines) + "\n"


def _quote(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'
