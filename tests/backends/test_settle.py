"""Settling after the last setpoint: complete only at the goal and still; a stop, a fault or the
timeout ends it otherwise."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import pytest

from armwarden.backends.settle import settle
from armwarden.core.errors import BackendError

pytestmark = pytest.mark.anyio

GOAL = np.array([0.5, -0.25])


@dataclass(frozen=True)
class Sample:
    positions: np.ndarray
    velocities: np.ndarray


def samples(*items: tuple[list[float], list[float]]) -> Iterator[Sample]:
    """The given samples, then the last one for ever."""
    for positions, velocities in items:
        yield Sample(np.array(positions), np.array(velocities))
    while True:
        yield Sample(np.array(items[-1][0]), np.array(items[-1][1]))


async def nowhere() -> np.ndarray:
    raise AssertionError("no stop landed: the rest position is not asked for")


def nothing() -> None:
    return None


async def run(feed: Iterator[Sample], *, stop_landed=lambda: False, rest_position=nowhere, check=nothing,
              timeout_s: float = 30.0, speedup: float = 1.0):
    return await settle(GOAL, measure=lambda: next(feed), check=check, stop_landed=stop_landed,
                        rest_position=rest_position, accuracy_rad=1e-3, rest_speed_rad_s=1e-3,
                        timeout_s=timeout_s, poll_s=0.001, speedup=speedup)


async def test_an_arm_at_the_goal_and_still_completes_where_it_was_measured() -> None:
    result = await run(samples(([0.5005, -0.25], [0.0, 0.0])))
    assert result.completed and result.reason == "completed"
    np.testing.assert_array_equal(result.final_positions, [0.5005, -0.25])


async def test_an_arm_passing_through_the_goal_completes_only_once_it_is_still() -> None:
    feed = samples(([0.4, -0.25], [0.3, 0.0]), ([0.5, -0.25], [0.2, 0.0]), ([0.5002, -0.25], [0.0, 0.0]))
    result = await run(feed)
    assert result.completed
    np.testing.assert_array_equal(result.final_positions, [0.5002, -0.25])


async def test_a_stop_ends_it_stopped_where_the_arm_came_to_rest() -> None:
    async def rest() -> np.ndarray:
        return np.array([0.3, -0.1])

    result = await run(samples(([0.5, -0.25], [0.0, 0.0])), stop_landed=lambda: True, rest_position=rest)
    assert not result.completed and result.reason == "stopped"
    np.testing.assert_array_equal(result.final_positions, [0.3, -0.1])


async def test_a_fault_found_by_the_check_raises_before_anything_completes() -> None:
    def faulted() -> None:
        raise BackendError("actuator fault")

    with pytest.raises(BackendError, match="actuator fault"):
        await run(samples(([0.5, -0.25], [0.0, 0.0])), check=faulted)


async def test_an_arm_that_never_arrives_ends_not_completed_naming_the_timeout_and_the_error() -> None:
    result = await run(samples(([0.4, -0.25], [0.0, 0.0])), timeout_s=2.0, speedup=100.0)
    assert not result.completed
    assert result.reason == "did not settle at the goal within 2.0 s (off by 0.1000 rad)"
    np.testing.assert_array_equal(result.final_positions, [0.4, -0.25])
