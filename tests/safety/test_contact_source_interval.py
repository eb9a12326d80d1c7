"""The observer's interval cap is on the arm's time: a backend whose joint states lie as far
apart on the arm's time as the cap or more (a fake sped up 20 times and more). Every interval is then
skipped (a free motion read as a lost reading, the e-stop latched); the Guard says so before
anything moves instead (`unintegrable_joint_states`)."""

from __future__ import annotations

import pytest

from armwarden.backends.fake.backend import FakeBackend
from armwarden.safety.contact_source import unintegrable_joint_states


@pytest.mark.parametrize(("speedup", "refused"), [(1.0, False), (10.0, False), (20.0, True), (50.0, True)])
def test_a_fake_says_how_far_apart_its_joint_states_are_and_the_observer_refuses_too_far(speedup: float,
                                                                                          refused: bool) -> None:
    capabilities = FakeBackend(speedup=speedup).capabilities
    assert capabilities.joint_state_interval_s == pytest.approx(0.001)
    reason = unintegrable_joint_states(capabilities.joint_state_interval_s, capabilities.time_scale)
    assert (reason is not None) == refused
    assert reason is None or "lower the speedup" in reason


def test_a_backend_that_does_not_say_is_not_refused() -> None:
    assert unintegrable_joint_states(None, 50.0) is None
