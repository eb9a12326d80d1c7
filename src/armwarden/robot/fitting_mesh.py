"""Collision meshes for the fitter: loading (trimesh, imported only by `load_mesh`: the `fit`
extra), subdividing, inside/outside by winding number, exact point–mesh distances (coal) and
points on a capsule's surface. Used by `armwarden.robot.fitting`; never by the runtime.

Winding numbers run in a numba kernel (`_winding_into`, compiled on first use): in numpy they
were 94 % of a Kinova Gen3 link's fit (every interior grid point against every triangle, and two
points per step of the segment search), and `armwarden init` took hours on its meshes.
tests/robot/test_link_meshes.py holds the kernel equal to the numpy formula."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import coal  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import numba
import numpy as np

from armwarden.robot.fitted_file import FittingError
from armwarden.robot.jit_compile import compile_cached

__all__ = [
    "LinkMesh",
    "SignedDistance",
    "box_mesh",
    "bvh_distances",
    "capsule_surface_points",
    "corner_winding_numbers",
    "interior_points",
    "is_closed",
    "load_mesh",
    "merge_meshes",
    "mesh_bvh",
    "mesh_distances",
    "over_approximation",
    "point_segment_distances",
    "subdivide",
    "transform_mesh",
    "triangle_corners",
    "winding_numbers",
]

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
    return corner_winding_numbers(points, triangle_corners(vertices, triangles))


def triangle_corners(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(M, 3, 3) each triangle's corners, as `corner_winding_numbers` takes them (made once per mesh)."""
    return np.ascontiguousarray(vertices[triangles], dtype=np.float64)


def corner_winding_numbers(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """`winding_numbers` of the triangles with `corners` (`triangle_corners`)."""
    points = np.ascontiguousarray(np.atleast_2d(points), dtype=np.float64)
    out = np.empty(len(points))
    _winding_kernel()(points, corners, out)
    return out


def _winding_into(points, corners, out):  # pragma: no cover - compiled
    """Each point's winding number into `out`: per triangle (corners a, b, c taken from the point)
    the solid angle 2·atan2(a·(b×c), |a||b||c| + (a·b)|c| + (b·c)|a| + (c·a)|b|), summed over 4π."""
    for n in range(points.shape[0]):
        px, py, pz = points[n, 0], points[n, 1], points[n, 2]
        total = 0.0
        for m in range(corners.shape[0]):
            ax, ay, az = corners[m, 0, 0] - px, corners[m, 0, 1] - py, corners[m, 0, 2] - pz
            bx, by, bz = corners[m, 1, 0] - px, corners[m, 1, 1] - py, corners[m, 1, 2] - pz
            cx, cy, cz = corners[m, 2, 0] - px, corners[m, 2, 1] - py, corners[m, 2, 2] - pz
            la = math.sqrt(ax * ax + ay * ay + az * az)
            lb = math.sqrt(bx * bx + by * by + bz * bz)
            lc = math.sqrt(cx * cx + cy * cy + cz * cz)
            det = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
            den = (la * lb * lc + (ax * bx + ay * by + az * bz) * lc + (bx * cx + by * cy + bz * cz) * la
                   + (cx * ax + cy * ay + cz * az) * lb)
            total += 2.0 * math.atan2(det, den)
        out[n] = total / (4.0 * math.pi)


@functools.cache
def _winding_kernel() -> Callable[[np.ndarray, np.ndarray, np.ndarray], None]:
    """`_winding_into`, compiled on first use (the fitter's, never the daemon's start-up)."""
    signature = numba.void(numba.float64[:, ::1], numba.float64[:, :, ::1], numba.float64[::1])
    return compile_cached(_winding_into, signature)[0]


def mesh_distances(mesh: LinkMesh, points: np.ndarray) -> np.ndarray:
    """Distance from each point to the mesh's surface (coal's BVH distance; exact)."""
    return bvh_distances(mesh_bvh(mesh), points)


def mesh_bvh(mesh: LinkMesh) -> coal.BVHModelOBBRSS:
    bvh = coal.BVHModelOBBRSS()
    bvh.beginModel(len(mesh.triangles), len(mesh.vertices))
    bvh.addVertices(np.ascontiguousarray(mesh.vertices, dtype=float))
    bvh.addTriangles(np.ascontiguousarray(mesh.triangles, dtype=np.int64))
    bvh.endModel()
    return bvh


def bvh_distances(bvh: coal.BVHModelOBBRSS, points: np.ndarray) -> np.ndarray:
    probe, identity, request, rotation = coal.Sphere(0.0), coal.Transform3s(), coal.DistanceRequest(), np.eye(3)
    out = np.empty(len(points))
    for k, point in enumerate(points):
        out[k] = coal.distance(bvh, identity, probe, coal.Transform3s(rotation, point), request, coal.DistanceResult())
    return out


def is_closed(triangles: np.ndarray) -> bool:
    """Whether the triangles bound solids without holes: every directed edge a→b is matched by
    exactly one b→a (each edge shared by two consistently wound triangles). Off such a surface the
    winding number is a whole number, constant until the surface is crossed."""
    triangles = np.asarray(triangles, dtype=np.int64)
    directed = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    forward = np.unique(directed, axis=0, return_counts=True)
    backward = np.unique(directed[:, ::-1], axis=0, return_counts=True)
    return (len(forward[0]) == len(directed) and len(backward[0]) == len(directed)
            and np.array_equal(forward[0], backward[0]))


#: how much nearer than the surface a grid node must be to lend a point its sign [m]: rounding room
_SIGN_CLEARANCE_M = 1e-6


class SignedDistance:
    """Each point's distance to the mesh's surface (coal, exact), positive inside (winding number
    above ½): what steers the fit on a part that is not convex.

    The winding number sums every triangle, for each point. On a closed surface (`is_closed`) it
    is constant off the surface, so a point farther from the surface than from its nearest node of
    a grid (pitch `pitch_m`) has that node's sign: no surface crosses the segment between them.
    Each node's sign is summed once and kept; only points nearer the surface than their node are
    summed themselves. The answer is the winding number's, to the bit; an open surface is summed
    point by point as before (tests/robot/test_link_meshes.py holds both equal to the sum)."""

    def __init__(self, mesh: LinkMesh, pitch_m: float = 0.004) -> None:
        self._bvh = mesh_bvh(mesh)
        self._corners = triangle_corners(mesh.vertices, mesh.triangles)
        self._closed = is_closed(mesh.triangles)
        self._origin = mesh.vertices.min(axis=0)
        self._pitch = pitch_m
        self._node_inside: dict[tuple[int, int, int], bool] = {}
        self.summed = 0  # points whose winding number was summed (the nodes' included)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        points = np.atleast_2d(np.asarray(points, dtype=float))
        distances = bvh_distances(self._bvh, points)
        inside = np.empty(len(points), dtype=bool)
        direct: list[int] = []
        for k, point in enumerate(points):
            node = self._near_node(point, float(distances[k]))
            if node is None:
                direct.append(k)
            else:
                inside[k] = node
        if direct:
            inside[direct] = self._winding(points[direct]) > 0.5
        return np.where(inside, 1.0, -1.0) * distances

    def _near_node(self, point: np.ndarray, distance: float) -> bool | None:
        """Whether the point's nearest grid node is inside, if no surface lies between them."""
        if not self._closed:
            return None
        index = np.round((point - self._origin) / self._pitch)
        if not np.all(np.isfinite(index)):
            return None
        node = self._origin + index * self._pitch
        if float(np.linalg.norm(point - node)) >= distance - _SIGN_CLEARANCE_M:  # the surface may pass between
            return None
        key = (int(index[0]), int(index[1]), int(index[2]))
        found = self._node_inside.get(key)
        if found is None:
            found = self._node_inside[key] = bool(self._winding(node[None])[0] > 0.5)
        return found

    def _winding(self, points: np.ndarray) -> np.ndarray:
        self.summed += len(points)
        return corner_winding_numbers(points, self._corners)


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


def over_approximation(mesh: LinkMesh, segments: np.ndarray, radii: np.ndarray, spacing: float) -> float:
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


def interior_points(mesh: LinkMesh, pitch: float) -> np.ndarray:
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    axes = [np.arange(lo[i] + pitch / 2, hi[i], pitch) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return grid[winding_numbers(grid, mesh.vertices, mesh.triangles) > 0.5]
