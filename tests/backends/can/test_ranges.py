"""Per-model value ranges: validated on construction, looked up by model name."""

from __future__ import annotations

import math

import pytest

from armwarden.backends.can.errors import UnknownModel
from armwarden.backends.can.ranges import MODELS, Protocol, Range, model_ranges
from armwarden.core.errors import ConfigurationError


def test_mit_models_share_position_and_gain_ranges() -> None:
    for name in ("AK80-9", "AK70-10", "AK10-9", "AK80-6"):
        ranges = model_ranges(name)
        assert ranges.protocol is Protocol.MIT
        assert (ranges.position, ranges.kp, ranges.kd) == (Range(-12.5, 12.5), Range(0, 500), Range(0, 5))


def test_mit_velocity_and_torque_are_per_model() -> None:
    assert (model_ranges("AK80-9").velocity, model_ranges("AK80-9").torque) == (Range(-50, 50), Range(-18, 18))
    assert model_ranges("AK70-10").torque == Range(-25, 25)
    assert model_ranges("AK10-9").torque == Range(-65, 65)
    assert (model_ranges("AK80-6").velocity, model_ranges("AK80-6").torque) == (Range(-76, 76), Range(-12, 12))


def test_robstride_models_use_four_pi_angle_and_their_own_limits() -> None:
    rs03 = model_ranges("RS03")
    assert rs03.protocol is Protocol.ROBSTRIDE
    assert rs03.position == Range(-4 * math.pi, 4 * math.pi)
    assert (rs03.velocity, rs03.torque, rs03.kp, rs03.kd) == (Range(-20, 20), Range(-60, 60), Range(0, 5000), Range(0, 100))
    assert model_ranges("RS05").torque == Range(-5.5, 5.5)
    assert {f"RS0{i}" for i in range(7)} <= set(MODELS)


def test_unknown_model_is_a_configuration_error_listing_known_models() -> None:
    with pytest.raises(UnknownModel, match=r"'AK99'.*AK80-9.*RS06") as info:
        model_ranges("AK99")
    assert isinstance(info.value, ConfigurationError)


@pytest.mark.parametrize(("lo", "hi"), [(1.0, 1.0), (2.0, -2.0), (math.nan, 1.0), (-math.inf, 0.0), (0.0, math.inf)])
def test_range_refuses_empty_reversed_or_non_finite_bounds(lo: float, hi: float) -> None:
    with pytest.raises(ValueError, match="range"):
        Range(lo, hi)


def test_model_table_is_read_only() -> None:
    with pytest.raises(TypeError):
        MODELS["X"] = MODELS["RS00"]  # type: ignore[index]  # the table is a read-only mapping
