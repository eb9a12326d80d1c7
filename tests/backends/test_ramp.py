"""The finger ramp every backend's gripper follows: from start to target at its speed, never past
the target, ending exactly on it."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from armwarden.backends.ramp import Ramp

widths = st.floats(-1.0, 1.0, allow_nan=False)
speeds = st.floats(1e-3, 10.0, allow_nan=False)
times = st.floats(-10.0, 100.0, allow_nan=False)


@given(widths, widths, speeds, times, times)
def test_the_position_moves_from_start_toward_target_without_passing_it(start, target, speed, now, later):
    ramp = Ramp(start, target, speed, 0.0)
    low, high = min(start, target), max(start, target)
    first, second = ramp.position(min(now, later)), ramp.position(max(now, later))
    assert low <= first <= high and low <= second <= high
    assert abs(second - start) >= abs(first - start)  # never turns back


@given(widths, widths, speeds)
def test_a_ramp_ends_exactly_on_its_target_and_stands_still(start, target, speed):
    ramp = Ramp(start, target, speed, 2.0)
    end = 2.0 + ramp.duration_s
    assert ramp.done(end + 1e-9)
    assert ramp.position(end + 1e-9) == target
    assert ramp.velocity(end + 1e-9) == 0.0


def test_before_it_begins_a_ramp_is_at_its_start():
    ramp = Ramp(0.01, 0.08, 0.1, 5.0)
    assert ramp.position(4.0) == 0.01 and not ramp.done(4.0)


def test_while_moving_the_velocity_points_at_the_target_at_the_ramps_speed():
    closing = Ramp(0.08, 0.02, 0.05, 0.0)
    assert closing.velocity(0.5) == pytest.approx(-0.05)
    assert closing.position(0.5) == pytest.approx(0.08 - 0.025)


def test_a_ramp_of_no_length_has_ended_from_its_start():
    ramp = Ramp(0.04, 0.04, 0.1, 3.0)
    assert ramp.done(0.0) and ramp.position(0.0) == 0.04 and ramp.velocity(0.0) == 0.0
