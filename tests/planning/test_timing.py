"""Time parameterisation: limits respected by the same estimator the envelope uses."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from armwarden.planning.timing import MAX_WAYPOINTS, TimingError, time_parameterize
from armwarden.safety.envelope import estimate_accelerations, estimate_velocities

NAMES = tuple(f"j{i}" for i in range(3))
VMAX = np.array([1.0, 2.0, 0.5])
AMAX = np.array([3.0, 5.0, 2.0])

paths = arrays(np.float64, st.tuples(st.integers(2, 8), st.just(3)), elements=st.floats(-2.0, 2.0))


@settings(max_examples=150, deadline=None)
@given(paths)
def test_velocity_and_acceleration_stay_within_the_limits(path: np.ndarray) -> None:
    trajectory = time_parameterize(NAMES, path, VMAX, AMAX)
    vel = np.abs(estimate_velocities(trajectory.times, trajectory.positions)) / VMAX
    acc = np.abs(estimate_accelerations(trajectory.times, trajectory.positions)) / AMAX
    assert vel.max() <= 1.0 + 1e-9
    assert acc.max() <= 1.0 + 1e-9


@settings(max_examples=100, deadline=None)
@given(paths)
def test_trajectory_starts_and_ends_at_the_path_ends(path: np.ndarray) -> None:
    trajectory = time_parameterize(NAMES, path, VMAX, AMAX)
    np.testing.assert_array_equal(trajectory.positions[0], path[0])
    np.testing.assert_allclose(trajectory.positions[-1], path[-1], atol=1e-9)
    assert trajectory.times[0] == 0.0 and np.all(np.diff(trajectory.times) > 0)


def test_every_vertex_of_the_path_is_a_waypoint() -> None:
    path = np.array([[0.0, 0.0, 0.0], [0.3, 0.1, 0.0], [0.5, -0.2, 0.1]])
    trajectory = time_parameterize(NAMES, path, VMAX, AMAX, stops=(1,))
    for vertex in path:
        assert np.min(np.linalg.norm(trajectory.positions - vertex, axis=1)) < 1e-12


def test_trajectory_comes_to_rest_at_a_stop() -> None:
    path = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.0, 0.0]])  # out and back
    trajectory = time_parameterize(NAMES, path, VMAX, AMAX, stops=(1,))
    turn = int(np.argmax(trajectory.positions[:, 0]))
    segment_velocity = np.abs(estimate_velocities(trajectory.times, trajectory.positions))[:, 0]
    assert segment_velocity[turn - 1] < 0.2 * VMAX[0] and segment_velocity[turn] < 0.2 * VMAX[0]


def test_a_path_that_does_not_move_is_a_two_waypoint_hold() -> None:
    trajectory = time_parameterize(NAMES, np.zeros((3, 3)), VMAX, AMAX)
    assert len(trajectory.times) == 2
    np.testing.assert_array_equal(trajectory.positions, np.zeros((2, 3)))


def test_the_slowest_joint_sets_the_duration() -> None:
    # 1 rad on joint 2 (0.5 rad/s, 2 rad/s²) takes 0.25 s to accelerate, 1.75 s to cruise... 2.25 s
    path = np.array([[0.0, 0.0, 0.0], [0.1, 0.1, 1.0]])
    trajectory = time_parameterize(NAMES, path, VMAX, AMAX)
    assert abs(trajectory.duration_s - 2.25) < 0.02


def test_a_motion_that_would_need_too_many_waypoints_is_refused_before_they_are_built() -> None:
    path = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]])
    with pytest.raises(TimingError, match="waypoints"):
        time_parameterize(NAMES, path, VMAX * 1e-7, AMAX)  # 0.5 rad at 1e-7 rad/s: 5e8 waypoints of 10 ms


def test_a_slow_motion_within_the_waypoint_cap_is_timed() -> None:
    path = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]])
    trajectory = time_parameterize(NAMES, path, VMAX * 0.01, AMAX * 0.01)
    assert len(trajectory.positions) <= MAX_WAYPOINTS and trajectory.duration_s > 50.0
