"""Capsules fitted to a robot's collision meshes: the fitting tool (the file it writes: `fitted_file`).

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

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from armwarden.robot.fitted_file import FittedBody, FittingError, LinkFit
from armwarden.robot.fitting_mesh import (
    LinkMesh,
    SignedDistance,
    interior_points,
    over_approximation,
    point_segment_distances,
    subdivide,
)

__all__ = [
    "FitOptions",
    "fit_link",
    "rotate_fit",
]

#: a part no vertex of which lies farther than this above a face's plane counts as convex [m]
_CONVEX_TOLERANCE_M = 0.002


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
        self._convex = self._highest_above_a_face() <= _CONVEX_TOLERANCE_M if len(self._labels) == 1 else True
        self._signed = None if self._convex else SignedDistance(self.mesh)

    def _highest_above_a_face(self) -> float:
        """How far the highest vertex lies above any face's plane [m] (0: convex), in blocks of
        faces: the whole (vertices × faces) table of a 10k-triangle mesh is 0.4 GB."""
        highest = -math.inf
        for start in range(0, len(self._normals), 512):
            heights = self.mesh.vertices @ self._normals[start:start + 512].T - self._offsets[None, start:start + 512]
            highest = max(highest, float(np.max(heights)))
        return highest

    def depth(self, points: np.ndarray) -> np.ndarray:
        """Depth of each point in the solid, negative outside. For convex parts (the FR3's meshes
        are convex to within 1 mm; boxes are) the least distance to a face plane, the deepest part
        counting; otherwise the distance to the surface, signed by the winding number. It only
        steers the fit: containment is enforced and the over-approximation measured separately."""
        points = np.atleast_2d(points)
        if self._signed is not None:
            return self._signed(points)
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
    worst = over_approximation(mesh, segments, radii, options.surface_spacing_m)
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
    interior = interior_points(mesh, min(options.interior_pitch_m, size / 10.0))
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
            tried.append((segments, sized, radii, over_approximation(mesh, sized, radii, 2.0 * options.surface_spacing_m)))
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
