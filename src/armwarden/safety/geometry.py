"""Vectorised geometric predicates on capsules, segments and axis-aligned boxes.

Everything here operates on whole batches (samples × bodies) with numpy, because per-object
calls into a collision library from Python cost ~10× the forward kinematics they follow. The
predicates are exact for capsules except `segments_hit_boxes`, which is a conservative
(over-approximating) broad phase; its hits are confirmed exactly with coal.
"""

from __future__ import annotations

import coal  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
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


def capsule_box_distance(p0: np.ndarray, p1: np.ndarray, radius: float, lo: np.ndarray, hi: np.ndarray) -> float:
    """Signed distance between one capsule and one box (negative when they overlap), with coal."""
    axis = p1 - p0
    length = float(np.linalg.norm(axis))
    if length > _EPS:
        z = axis / length
        helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        x = _cross(helper, z)
        x /= np.linalg.norm(x)
        rotation = np.column_stack([x, _cross(z, x), z])
    else:
        rotation = np.eye(3)
    capsule = coal.Capsule(float(radius), length)
    box = coal.Box(*(np.asarray(hi, dtype=float) - np.asarray(lo, dtype=float)))
    request = coal.DistanceRequest()
    result = coal.DistanceResult()
    coal.distance(
        capsule,
        coal.Transform3s(rotation, (p0 + p1) / 2.0),
        box,
        coal.Transform3s(np.eye(3), (np.asarray(lo) + np.asarray(hi)) / 2.0),
        request,
        result,
    )
    return float(result.min_distance)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of two 3-vectors (`np.cross` costs ~20× more on single vectors)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


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
