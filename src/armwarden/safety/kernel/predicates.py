"""The geometric predicates of `core.geometry`, ported line for line into compiled helpers: the
distances and box tests the samples' checks are made of, and the placing of a link's capsules."""

from __future__ import annotations

import math

import numpy as np

from armwarden.safety.kernel.jit import helper, inlined


@helper
def segment_box_distance(p0x, p0y, p0z, p1x, p1y, p1z, boxes, row, knots):  # pragma: no cover - compiled
    """`geometry.segment_box_distance` for one segment and the box `boxes[row]` (lo xyz, hi
    xyz): the same knots, pieces, minimisers and candidates. `knots`: scratch (at least 8)."""
    p0 = (p0x, p0y, p0z)
    d = (p1x - p0x, p1y - p0y, p1z - p0z)
    lo = (boxes[row, 0], boxes[row, 1], boxes[row, 2])
    hi = (boxes[row, 3], boxes[row, 4], boxes[row, 5])
    knots[0] = 0.0
    knots[1] = 1.0
    for a in range(3):
        if abs(d[a]) > 1e-12:
            knots[2 + a] = min(max((lo[a] - p0[a]) / d[a], 0.0), 1.0)
            knots[5 + a] = min(max((hi[a] - p0[a]) / d[a], 0.0), 1.0)
        else:
            knots[2 + a] = 0.0
            knots[5 + a] = 0.0
    for i in range(1, 8):  # insertion sort (numba's sort costs seconds of compile time)
        value = knots[i]
        j = i - 1
        while j >= 0 and knots[j] > value:
            knots[j + 1] = knots[j]
            j -= 1
        knots[j + 1] = value
    best = np.inf
    for c in range(15):
        if c < 8:
            t = knots[c]
        else:
            start = knots[c - 8]
            end = knots[c - 7]
            half = (start + end) / 2.0
            curvature = 0.0
            pull = 0.0
            for a in range(3):
                middle = p0[a] + half * d[a]
                if middle < lo[a]:
                    curvature += d[a] * d[a]
                    pull += d[a] * (lo[a] - p0[a])
                elif middle > hi[a]:
                    curvature += d[a] * d[a]
                    pull += d[a] * (hi[a] - p0[a])
            if curvature == 0.0:
                t = half
            else:
                t = min(max(pull / curvature, start), end)
        total = 0.0
        for a in range(3):
            x = p0[a] + t * d[a]
            out = x - min(max(x, lo[a]), hi[a])
            total += out * out
        if total < best:
            best = total
    return math.sqrt(best)


@inlined
def segment_hits_box(tcp, boxes, row, grow):  # pragma: no cover - compiled
    """`geometry.segments_hit_boxes` (the slab test) for the segment tcp[0]–tcp[1] and the box
    `boxes[row]` grown by `grow`."""
    enter = -np.inf
    leave = np.inf
    for a in range(3):
        lo = boxes[row, a] - grow
        hi = boxes[row, 3 + a] + grow
        start = tcp[0, a]
        d = tcp[1, a] - start
        if abs(d) > 1e-12:
            inv = 1.0 / d
            t_a = (lo - start) * inv
            t_b = (hi - start) * inv
            near = min(t_a, t_b)
            far = max(t_a, t_b)
        elif start >= lo and start <= hi:
            near = -np.inf
            far = np.inf
        else:
            near = np.inf
            far = -np.inf
        enter = max(enter, near)
        leave = min(leave, far)
    return enter <= leave and leave >= 0.0 and enter <= 1.0


@inlined
def clip01(x):  # pragma: no cover - compiled
    return min(max(x, 0.0), 1.0)


@inlined
def segment_segment_distance(points, ia, ib):  # pragma: no cover - compiled
    """`geometry.segment_segment_distance` for the segments of bodies ia and ib (`points` rows:
    p0 xyz, p1 xyz)."""
    eps = 1e-12
    d1x, d1y, d1z = points[ia, 3] - points[ia, 0], points[ia, 4] - points[ia, 1], points[ia, 5] - points[ia, 2]
    d2x, d2y, d2z = points[ib, 3] - points[ib, 0], points[ib, 4] - points[ib, 1], points[ib, 5] - points[ib, 2]
    rx, ry, rz = points[ia, 0] - points[ib, 0], points[ia, 1] - points[ib, 1], points[ia, 2] - points[ib, 2]
    a = d1x * d1x + d1y * d1y + d1z * d1z
    e = d2x * d2x + d2y * d2y + d2z * d2z
    f = d2x * rx + d2y * ry + d2z * rz
    c = d1x * rx + d1y * ry + d1z * rz
    b = d1x * d2x + d1y * d2y + d1z * d2z
    a_safe = max(a, eps)
    e_safe = max(e, eps)
    denom = a * e - b * b
    if denom > eps * max(a * e, eps):
        s = clip01((b * f - c * e) / max(denom, eps))
    else:
        s = 0.0
    t = (b * s + f) / e_safe
    if t < 0.0:
        s = clip01(-c / a_safe)
    elif t > 1.0:
        s = clip01((b - c) / a_safe)
    t = clip01(t)
    p_is_point = a <= eps
    q_is_point = e <= eps
    if p_is_point:
        s = 0.0
        t = clip01(f / e_safe)
    if q_is_point:
        t = 0.0
        if not p_is_point:
            s = clip01(-c / a_safe)
    x = (points[ia, 0] + s * d1x) - (points[ib, 0] + t * d2x)
    y = (points[ia, 1] + s * d1y) - (points[ib, 1] + t * d2y)
    z = (points[ia, 2] + s * d1z) - (points[ib, 2] + t * d2z)
    return math.sqrt(x * x + y * y + z * z)


@inlined
def transform(poses, j, x, y, z):  # pragma: no cover - compiled
    """R · (x, y, z) + t for the homogeneous pose `poses[j]`."""
    return (poses[j, 0, 0] * x + poses[j, 0, 1] * y + poses[j, 0, 2] * z + poses[j, 0, 3],
            poses[j, 1, 0] * x + poses[j, 1, 1] * y + poses[j, 1, 2] * z + poses[j, 1, 3],
            poses[j, 2, 0] * x + poses[j, 2, 1] * y + poses[j, 2, 2] * z + poses[j, 2, 3])


@helper
def place_group(g, group, group_bodies, body_ints, body_floats, poses, points, placed):  # pragma: no cover - compiled
    """World end points of group g's bodies into points[b] (p0 xyz, p1 xyz, midpoint xyz), once
    per sample."""
    if placed[g]:
        return
    for m in range(group[g, 2], group[g, 3]):
        b = group_bodies[m, 0]
        j = body_ints[b, 0]
        points[b, 0], points[b, 1], points[b, 2] = transform(poses, j, body_floats[b, 0], body_floats[b, 1],
                                                              body_floats[b, 2])
        points[b, 3], points[b, 4], points[b, 5] = transform(poses, j, body_floats[b, 3], body_floats[b, 4],
                                                              body_floats[b, 5])
        points[b, 6] = (points[b, 0] + points[b, 3]) / 2.0
        points[b, 7] = (points[b, 1] + points[b, 4]) / 2.0
        points[b, 8] = (points[b, 2] + points[b, 5]) / 2.0
    placed[g] = True


@inlined
def outside_box(points, b, radius, boxes, row):  # pragma: no cover - compiled
    """Whether body b's capsule (`points[b]`: p0 xyz, p1 xyz) with `radius` leaves the box
    `boxes[row]` (the numpy pass: its bounds not inside the box)."""
    for a in range(3):
        low = min(points[b, a], points[b, 3 + a]) - radius
        high = max(points[b, a], points[b, 3 + a]) + radius
        if not (low >= boxes[row, a]) or not (high <= boxes[row, 3 + a]):
            return True
    return False


@inlined
def boxes_apart(points, ia, ib, allowance):  # pragma: no cover - compiled
    """Whether the bounds of bodies ia's and ib's segments, grown by `allowance`, miss each
    other: then the segments are farther apart than it."""
    for a in range(3):
        if (min(points[ia, a], points[ia, 3 + a]) - allowance > max(points[ib, a], points[ib, 3 + a])
                or min(points[ib, a], points[ib, 3 + a]) - allowance > max(points[ia, a], points[ia, 3 + a])):
            return True
    return False


@inlined
def bounds_overlap(points, b, radius, boxes, row):  # pragma: no cover - compiled
    for a in range(3):
        low = min(points[b, a], points[b, 3 + a]) - radius
        high = max(points[b, a], points[b, 3 + a]) + radius
        if not (low <= boxes[row, 3 + a]) or not (high >= boxes[row, a]):
            return False
    return True

