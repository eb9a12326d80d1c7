"""Fitting friction to the residuals of an arm that touches nothing, and the limits recommended."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from armwarden.calibration.friction_fit import MIN_FORCE_ROOM_N, MIN_LIMIT_NM, fit_friction, force_limit_for, recommend
from armwarden.safety.contact_observer import COULOMB_SMOOTHING_RAD_S


def friction(v: np.ndarray, coulomb: float, viscous: float) -> np.ndarray:
    return coulomb * np.tanh(v / COULOMB_SMOOTHING_RAD_S) + viscous * v


@given(coulomb=st.floats(0.0, 5.0), viscous=st.floats(0.0, 3.0))
@settings(max_examples=50, deadline=None)
def test_friction_without_noise_is_recovered_exactly(coulomb: float, viscous: float) -> None:
    v = np.linspace(-1.5, 1.5, 301)
    fitted = fit_friction(v, -friction(v, coulomb, viscous))
    assert fitted == pytest.approx((coulomb, viscous), abs=1e-6)


def test_noisy_friction_is_recovered_within_the_noise() -> None:
    rng = np.random.default_rng(1)
    v = rng.uniform(-1.0, 1.0, 4000)
    residual = -friction(v, 1.2, 0.4) + rng.normal(0.0, 0.1, v.size)
    coulomb, viscous = fit_friction(v, residual)
    assert coulomb == pytest.approx(1.2, abs=0.02) and viscous == pytest.approx(0.4, abs=0.03)


def test_a_residual_that_helps_motion_is_not_fitted_as_negative_friction() -> None:
    v = np.linspace(-1.0, 1.0, 200)
    assert fit_friction(v, +friction(v, 1.0, 0.5)) == (0.0, 0.0)


def test_an_arm_that_never_moved_has_no_friction_to_fit() -> None:
    assert fit_friction(np.zeros(50), np.full(50, 0.3)) == (0.0, 0.0)


def test_the_limit_is_the_margin_over_what_is_left_after_friction() -> None:
    rng = np.random.default_rng(2)
    v = rng.uniform(-1.0, 1.0, (3000, 2))
    noise = rng.uniform(-0.8, 0.8, (3000, 2))
    residual = -friction(v, 2.0, 0.0) + noise
    found = recommend(["a", "b"], v, residual, margin=2.0)
    for joint in found:
        assert joint.peak_residual_nm > 2.0  # the friction dominated what was read
        assert joint.peak_after_friction_nm < 1.0
        assert joint.limit_nm == pytest.approx(2.0 * joint.peak_after_friction_nm, abs=0.01)
        assert joint.margin == pytest.approx(2.0, abs=0.02)


def test_no_limit_is_recommended_below_the_floor() -> None:
    v = np.linspace(-1.0, 1.0, 100).reshape(-1, 1)
    found = recommend(["quiet"], v, np.full_like(v, 0.01))
    assert found[0].limit_nm == MIN_LIMIT_NM and found[0].margin == pytest.approx(100.0)


def test_a_joint_that_read_nothing_at_all_has_an_infinite_margin() -> None:
    found = recommend(["still"], np.zeros((10, 1)), np.zeros((10, 1)))
    assert math.isinf(found[0].margin) and found[0].limit_nm == MIN_LIMIT_NM


def test_a_margin_below_one_is_refused() -> None:
    with pytest.raises(ValueError, match="margin"):
        recommend(["a"], np.zeros((2, 1)), np.zeros((2, 1)), margin=0.5)


def test_what_an_observer_with_the_fitted_friction_really_read_raises_the_limit() -> None:
    v = np.linspace(-1.0, 1.0, 200).reshape(-1, 1)
    residual = -friction(v, 1.0, 0.0) + 0.2 * np.sin(40 * v)  # friction the fit removes, and 0.2 N·m left
    estimated = recommend(["a"], v, residual)[0]
    replayed = recommend(["a"], v, residual, peaks_after_friction_nm=[0.9])[0]  # its low-pass left more
    assert estimated.peak_after_friction_nm < 0.3 and estimated.limit_nm == MIN_LIMIT_NM
    assert replayed.peak_after_friction_nm == 0.9 and replayed.limit_nm == pytest.approx(1.8)
    assert recommend(["a"], v, residual, peaks_after_friction_nm=[0.1])[0] == estimated  # never lowers it


def test_the_tcp_force_limit_is_the_margin_over_the_free_motion_estimate() -> None:
    assert force_limit_for(10.2, 2.0, 30.0) == 21.0  # 2x, rounded up to 1 N


def test_a_small_free_motion_estimate_still_leaves_some_newtons_of_room() -> None:
    assert force_limit_for(1.0, 2.0, 30.0) == 1.0 + MIN_FORCE_ROOM_N


def test_no_tcp_force_limit_is_recommended_above_the_policys_contact_force() -> None:
    assert force_limit_for(20.0, 2.0, 30.0) is None  # the estimate keeps max_contact_force_n


def test_a_nan_peak_force_is_refused() -> None:
    with pytest.raises(ValueError, match="finite"):
        force_limit_for(math.nan, 2.0, 30.0)
