"""The grasp outcome every simulated or driven gripper reports: a stop ends it "stopped", else
grasped exactly when the fingers came to rest within the margins around the asked width."""

from __future__ import annotations

import pytest

from armwarden.backends.gripper_checks import grasp_outcome


def test_a_stopped_grasp_is_stopped_and_holds_nothing_wherever_the_fingers_are() -> None:
    result = grasp_outcome(0.03, 0.03, True, 0.005, 0.005)
    assert (result.success, result.is_grasped, result.detail, result.width_m) == (False, False, "stopped", 0.03)


@pytest.mark.parametrize(("final_m", "grasped"), [(0.0251, True), (0.03, True), (0.0349, True), (0.0249, False),
                                                  (0.0351, False), (0.0, False)])
def test_a_grasp_holds_when_the_fingers_rest_within_the_margins(final_m: float, grasped: bool) -> None:
    result = grasp_outcome(0.03, final_m, False, 0.005, 0.005)
    assert result.success is grasped and result.is_grasped is grasped
    assert (result.detail == "") is grasped
