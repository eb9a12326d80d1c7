"""The short history of published joint states a servo-loop backend keeps for the contact observer."""

from __future__ import annotations

import numpy as np
import pytest

from armwarden.backends.state_history import JointStateHistory
from armwarden.core.state import JointState


def state(stamp: float) -> JointState:
    return JointState(("j1",), np.zeros(1), np.zeros(1), stamp, np.zeros(1))


def test_the_states_after_a_stamp_come_oldest_first() -> None:
    history = JointStateHistory()
    for stamp in (1.0, 2.0, 3.0, 4.0):
        history.append(state(stamp))
    assert [s.stamp for s in history.since(2.0)] == [3.0, 4.0]
    assert [s.stamp for s in history.since(0.5)] == [1.0, 2.0, 3.0, 4.0]


def test_nothing_newer_is_an_empty_answer() -> None:
    history = JointStateHistory()
    history.append(state(1.0))
    assert history.since(1.0) == ()
    assert JointStateHistory().since(0.0) == ()


def test_only_the_last_capacity_states_are_kept_so_a_late_reader_sees_a_gap() -> None:
    history = JointStateHistory(capacity=3)
    for stamp in range(1, 11):
        history.append(state(float(stamp)))
    assert [s.stamp for s in history.since(2.0)] == [8.0, 9.0, 10.0]


def test_a_history_without_room_is_refused() -> None:
    with pytest.raises(ValueError, match="at least one sample"):
        JointStateHistory(capacity=0)


def test_a_reader_with_nothing_newer_gets_the_newest_kept_state_again() -> None:
    history = JointStateHistory()
    assert history.since_or_latest(0.0) == ()
    history.append(state(1.0))
    history.append(state(2.0))
    assert [s.stamp for s in history.since_or_latest(2.0)] == [2.0]
    assert [s.stamp for s in history.since_or_latest(1.5)] == [2.0]
