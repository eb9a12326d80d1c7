"""Float <-> uint mapping: truncating encode, exact decode, refuse (never clamp) bad values."""

from __future__ import annotations

import math

import pytest

from armwarden.backends.can.mapping import decode, encode, lsb
from armwarden.backends.can.ranges import Range

VELOCITY = Range(-50.0, 50.0)


def test_range_ends_map_to_zero_and_full_scale() -> None:
    assert encode(-50.0, VELOCITY, 12, "v") == 0
    assert encode(50.0, VELOCITY, 12, "v") == 4095
    assert decode(0, VELOCITY, 12) == -50.0
    assert decode(4095, VELOCITY, 12) == 50.0


def test_zero_is_truncated_to_the_code_below_it() -> None:
    raw = encode(0.0, VELOCITY, 12, "v")
    assert raw == 2047
    assert decode(raw, VELOCITY, 12) == pytest.approx(-0.0122, abs=1e-4)
    assert abs(decode(raw, VELOCITY, 12)) <= lsb(VELOCITY, 12)


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_non_finite_values_are_refused_naming_the_field(value: float) -> None:
    with pytest.raises(ValueError, match="velocity must be a finite number"):
        encode(value, VELOCITY, 12, "velocity")


@pytest.mark.parametrize("value", [-50.0001, 50.0001, 1e9])
def test_out_of_range_values_are_refused_not_clamped(value: float) -> None:
    with pytest.raises(ValueError, match=r"velocity = .* outside its range \[-50.0, 50.0\]"):
        encode(value, VELOCITY, 12, "velocity")


def test_raw_values_wider_than_the_field_are_refused() -> None:
    with pytest.raises(ValueError, match="does not fit in 12 bits"):
        decode(4096, VELOCITY, 12)
