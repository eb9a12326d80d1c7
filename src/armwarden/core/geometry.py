"""Vectorised geometric predicates on capsules, segments and axis-aligned boxes.

Everything here operates on whole batches (samples × bodies) with numpy, because per-object
calls into a collision library from Python cost ~10× the forward kinematics they follow: a coal
capsule–box distance is ≈ 20 µs a pair, most of it building the shapes and transforms. The
predicates are exact for capsules except `segments_hit_boxes`, which is a conservative
(over-approximating) broad phase. Written here rather than taken from a library for that reason
only; tests/safety/test_geometry.py checks each against coal's distances as the oracle.
"""

from __future__ import annotations

import numpy as np

_EPS = 1e-12


def capsule_bounds(p0: np.ndarray, p1: np.ndarray, radius: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounds (lo, hi) of each capsule (segment p0–p1 swept by a ball of `radius`)."""
    r = radius[..., None]
    return np.minimum(p0, p1) - r, np.maximum(p0, p1) + r


def bounds_inside(lo: np.ndarray, hi: np.ndarray, box_lo: np.ndarray, box_hi: np.ndarray) -> np.ndarray:
    """Whether each bounds [lo, hi] lies entirely inside the box [box_lo, box_hi]."""
    return np.all(lo >= box_lo, axis=-1) & np.all(hi <= box_hi, axis=-1)


def capsules_inside_box(p0: np.ndarray, p1: np.ndarray, radius: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Whether each capsule lies entirely inside the box [lo, hi].

    Exact: a capsule (segment ⊕ ball r) is inside a box iff the segment is inside the box shrunk
    by r, and a segment is inside a convex set iff both end points are — which is exactly the
    capsule's axis-aligned bounds lying inside the box.
    """
    return bounds_inside(*capsule_bounds(p0, p1, radius), lo, hi)


def segments_hit_boxes(p0: np.ndarray, p1: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Slab test: whether each segment p0→p1 intersects the closed box [lo, hi] (broadcasting)."""
    d = p1 - p0
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(np.abs(d) > _EPS, 1.0 / np.where(np.abs(d) > _EPS, d, 1.0), np.inf)
        t_a = (lo - p0) * inv
        t_b = (hi - p0) * inv
    parallel = np.abs(d) <= _EPS
    inside_slab = (p0 >= lo) & (p0 <= hi)
    t_near = np.where(parallel, np.where(inside_slab, -np.inf, np.inf), np.minimum(t_a, t_b))
    t_far = np.where(parallel, np.where(inside_slab, np.inf, -np.inf), np.maximum(t_a, t_b))
    enter = np.max(t_near, axis=-1)
    leave = np.min(t_far, axis=-1)
    return (enter <= leave) & (leave >= 0.0) & (enter <= 1.0)


def segment_box_distance(p0: np.ndarray, p1: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Distance between each segment p0–p1 and each axis-aligned box [lo, hi] (0 when they
    touch or overlap), element-wise over leading axes. A capsule of radius r touches the box
    exactly when this is ≤ r.

    Exact: the squared distance from the point p0 + t·(p1 − p0) to the box is convex and
    piecewise quadratic in t, its pieces bounded by the parameters where the point crosses a
    face plane (at most six). On each piece every axis stays below, inside or above its slab,
    so the piece's quadratic has a closed-form minimiser; the minimum over [0, 1] is at one of
    those minimisers (clamped to its piece) or at a piece's end, and all of them are evaluated.
    """
    p0, p1 = np.asarray(p0, dtype=float), np.asarray(p1, dtype=float)
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    d = p1 - p0
    moving = np.abs(d) > _EPS
    safe_d = np.where(moving, d, 1.0)
    # the parameters where the segment crosses a face plane; a still axis crosses none (0 is a knot anyway)
    crossings = np.concatenate([np.where(moving, (lo - p0) / safe_d, 0.0), np.where(moving, (hi - p0) / safe_d, 0.0)], axis=-1)
    ends = np.broadcast_to(np.array([0.0, 1.0]), (*crossings.shape[:-1], 2))
    knots = np.sort(np.concatenate([ends, np.clip(crossings, 0.0, 1.0)], axis=-1), axis=-1)  # (..., 8)
    start, end = knots[..., :-1], knots[..., 1:]  # the pieces, (..., 7)
    # which side of each slab the segment is on inside each piece (taken at the piece's middle)
    middle = p0[..., None, :] + ((start + end) / 2.0)[..., None] * d[..., None, :]  # (..., 7, 3)
    below, above = middle < lo[..., None, :], middle > hi[..., None, :]
    bound = np.where(below, lo[..., None, :], np.where(above, hi[..., None, :], 0.0))
    active = below | above
    slope = np.where(active, d[..., None, :], 0.0)
    curvature = np.sum(slope * slope, axis=-1)
    pull = np.sum(slope * (bound - p0[..., None, :]), axis=-1)
    # a flat piece (no axis outside its slab moves: exactly zero) keeps one distance all along,
    # zero where the segment is inside the box: its middle, where rounding cannot put the point
    # outside a slab it is inside. Any other piece, however slight its slope, gets its minimiser.
    flat = curvature == 0.0
    minimiser = np.where(flat, (start + end) / 2.0, np.clip(pull / np.where(flat, 1.0, curvature), start, end))
    candidates = np.concatenate([knots, minimiser], axis=-1)  # (..., 15)
    points = p0[..., None, :] + candidates[..., None] * d[..., None, :]
    outside = points - np.clip(points, lo[..., None, :], hi[..., None, :])
    return np.sqrt(np.min(np.sum(outside * outside, axis=-1), axis=-1))


def segment_segment_distance(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """Closest distance between segments p0–p1 and q0–q1, element-wise over leading axes."""
    d1 = p1 - p0
    d2 = q1 - q0
    r = p0 - q0
    a = np.einsum("...i,...i->...", d1, d1)
    e = np.einsum("...i,...i->...", d2, d2)
    f = np.einsum("...i,...i->...", d2, r)
    c = np.einsum("...i,...i->...", d1, r)
    b = np.einsum("...i,...i->...", d1, d2)
    a_safe = np.maximum(a, _EPS)
    e_safe = np.maximum(e, _EPS)
    denom = a * e - b * b
    s = np.where(denom > _EPS * np.maximum(a * e, _EPS), np.clip((b * f - c * e) / np.maximum(denom, _EPS), 0.0, 1.0), 0.0)
    t = (b * s + f) / e_safe
    # t outside [0, 1]: clamp it and recompute s for the clamped t
    s = np.where(t < 0.0, np.clip(-c / a_safe, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / a_safe, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    # degenerate segments (points)
    p_is_point = a <= _EPS
    q_is_point = e <= _EPS
    s = np.where(p_is_point, 0.0, s)
    t = np.where(p_is_point, np.clip(f / e_safe, 0.0, 1.0), t)
    t = np.where(q_is_point, 0.0, t)
    s = np.where(q_is_point & ~p_is_point, np.clip(-c / a_safe, 0.0, 1.0), s)
    closest_p = p0 + s[..., None] * d1
    closest_q = q0 + t[..., None] * d2
    return np.linalg.norm(closest_p - closest_q, axis=-1)
