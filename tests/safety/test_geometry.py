"""The vectorised capsule/box/segment predicates against coal as an independent oracle."""

from __future__ import annotations

import coal
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from armwarden.safety import geometry
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


def test_capsule_box_distance_is_signed_and_exact_for_a_simple_case() -> None:
    lo, hi = np.zeros(3), np.ones(3)
    above = geometry.capsule_box_distance(np.array([0.5, 0.5, 1.3]), np.array([0.5, 0.5, 2.0]), 0.1, lo, hi)
    assert abs(above - 0.2) < 1e-6
    inside = geometry.capsule_box_distance(np.array([0.5, 0.5, 0.5]), np.array([0.5, 0.5, 0.6]), 0.1, lo, hi)
    assert inside <= 0.0
