"""The vectorised capsule/box/segment predicates against coal as an independent oracle."""

from __future__ import annotations

import coal
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from armwarden.core import geometry
from tests.safety.coal_shapes import coal_capsule

coords = st.floats(-1.0, 1.0, allow_nan=False)
point = st.tuples(coords, coords, coords).map(np.array)


@settings(max_examples=300, deadline=None)
@given(point, point, point, point)
def test_segment_distance_matches_coal_capsule_distance(p0, p1, q0, q1) -> None:
    radius = 0.01
    a, ta = coal_capsule(p0, p1, radius)
    b, tb = coal_capsule(q0, q1, radius)
    result = coal.DistanceResult()
    coal.distance(a, ta, b, tb, coal.DistanceRequest(), result)
    expected = result.min_distance + 2 * radius
    got = float(geometry.segment_segment_distance(p0, p1, q0, q1))
    if result.min_distance > 0:
        assert abs(got - expected) < 1e-6
    else:
        assert got <= 2 * radius + 1e-6


def test_parallel_and_degenerate_segments_have_the_obvious_distance() -> None:
    a0, a1 = np.array([0.0, 0, 0]), np.array([1.0, 0, 0])
    assert geometry.segment_segment_distance(a0, a1, a0 + [0, 0.3, 0], a1 + [0, 0.3, 0]) == np.float64(0.3)
    assert abs(geometry.segment_segment_distance(a0, a0, np.array([0.0, 2, 0]), np.array([0.0, 2, 0])) - 2.0) < 1e-12
    assert abs(geometry.segment_segment_distance(a0, a1, np.array([2.0, 0, 0]), np.array([3.0, 0, 0])) - 1.0) < 1e-12


@settings(max_examples=300, deadline=None)
@given(point, point, st.floats(0.0, 0.3))
def test_capsule_inside_box_is_exact(p0, p1, radius) -> None:
    lo, hi = np.array([-0.8, -0.7, -0.9]), np.array([0.9, 0.8, 0.7])
    got = bool(geometry.capsules_inside_box(p0, p1, np.array(radius), lo, hi))
    # brute force: dense points on the segment, each must keep `radius` from every face
    ts = np.linspace(0.0, 1.0, 401)[:, None]
    pts = p0 + ts * (p1 - p0)
    expected = bool(np.all(pts - radius >= lo) and np.all(pts + radius <= hi))
    assert got == expected


@settings(max_examples=300, deadline=None)
@given(point, point)
def test_segment_box_slab_test_agrees_with_dense_sampling(p0, p1) -> None:
    lo, hi = np.array([-0.2, -0.3, -0.1]), np.array([0.3, 0.1, 0.4])
    got = bool(geometry.segments_hit_boxes(p0, p1, lo, hi))
    ts = np.linspace(0.0, 1.0, 20001)[:, None]
    pts = p0 + ts * (p1 - p0)
    sampled = bool(np.any(np.all((pts >= lo) & (pts <= hi), axis=1)))
    if sampled:
        assert got  # a sampled hit is a hit
    if not got:
        assert not sampled


def coal_capsule_box_distance(p0: np.ndarray, p1: np.ndarray, radius: float, lo: np.ndarray, hi: np.ndarray) -> float:
    capsule, placement = coal_capsule(p0, p1, radius)
    box = coal.Box(*(hi - lo))
    result = coal.DistanceResult()
    coal.distance(capsule, placement, box, coal.Transform3s(np.eye(3), (lo + hi) / 2), coal.DistanceRequest(), result)
    return float(result.min_distance)


box_corner = st.tuples(coords, coords, coords).map(np.array)
box_size = st.tuples(*[st.floats(0.01, 1.0)] * 3).map(np.array)


@settings(max_examples=500, deadline=None)
@given(point, point, box_corner, box_size, st.floats(0.0, 0.2))
def test_segment_box_distance_matches_coal_capsule_box_distance(p0, p1, lo, size, radius) -> None:
    hi = lo + size
    expected = coal_capsule_box_distance(p0, p1, radius, lo, hi)
    got = float(geometry.segment_box_distance(p0, p1, lo, hi))
    if expected > 1e-6:
        # apart: the distance of the surfaces (coal's GJK is within ≈ 1e-6 relative far apart; ours is exact)
        assert abs((got - radius) - expected) < 1e-6 + 5e-6 * expected
    elif expected < -1e-6:
        assert got <= radius + 1e-12  # overlapping: a hit, as for coal (up to rounding)
    else:
        assert abs(got - radius) < 1e-5  # touching


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(point, point, box_corner, box_size), min_size=1, max_size=12))
def test_segment_box_distance_of_a_batch_is_each_pairs_own(pairs) -> None:
    p0, p1, lo, size = (np.array(column) for column in zip(*pairs, strict=True))
    batch = geometry.segment_box_distance(p0, p1, lo, lo + size)
    one_by_one = [float(geometry.segment_box_distance(*row[:3], row[2] + row[3])) for row in pairs]
    assert np.allclose(batch, one_by_one, rtol=0.0, atol=1e-12)


def test_segment_box_distance_of_simple_cases() -> None:
    lo, hi = np.zeros(3), np.ones(3)
    above = geometry.segment_box_distance(np.array([0.5, 0.5, 1.3]), np.array([0.5, 0.5, 2.0]), lo, hi)
    assert abs(above - 0.3) < 1e-12
    through = geometry.segment_box_distance(np.array([-1.0, 0.5, 0.5]), np.array([2.0, 0.5, 0.5]), lo, hi)
    assert through == 0.0
    past_an_edge = geometry.segment_box_distance(np.array([-1.0, 2.0, 0.5]), np.array([2.0, -1.0 + 1.0, 2.5]), lo, hi)
    assert past_an_edge > 0.0
    a_point = geometry.segment_box_distance(np.array([2.0, 2.0, 2.0]), np.array([2.0, 2.0, 2.0]), lo, hi)
    assert abs(a_point - np.sqrt(3.0)) < 1e-12


def test_segment_box_distance_finds_the_minimum_inside_a_piece_that_barely_slopes() -> None:
    """A segment a micrometre from the box, moving less than a micrometre out of the slabs it is
    outside of: its closest point lies inside a piece whose slope is tiny but not zero (found by
    review: a 'nearly flat' shortcut once evaluated only the piece's ends and middle there)."""
    lo, hi = np.zeros(3), np.ones(3)
    p0 = np.array([1.000000823534618, 0.5, 1.000000083433075])
    p1 = np.array([1.000000148949435, 0.8, 1.0000004618304457])
    a, b = p0[0] - 1.0, p0[2] - 1.0  # how far out along x and z at the start
    da, db = p1[0] - p0[0], p1[2] - p0[2]
    t = np.clip(-(a * da + b * db) / (da * da + db * db), 0.0, 1.0)  # the exact closest parameter
    exact = np.hypot(a + da * t, b + db * t)
    assert abs(float(geometry.segment_box_distance(p0, p1, lo, hi)) - exact) < 1e-12
