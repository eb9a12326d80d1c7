"""The base class's own "stopped before it started" in `Backend.execute`, reached on its own.

Every real backend re-checks `_stop_landed()` in its `_execute` hook too (under the lock its stop
takes), so a contract test on them passes whether or not the base class checks. `_Unguarded` is a
backend whose hook does not re-check: there, only `Backend.execute`'s check keeps a trajectory
decided before a stop from being handed over after it.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

from armwarden.backends.base import Backend
from armwarden.backends.values import PREEMPTED, ExecutionResult
from armwarden.core.state import JointState
from armwarden.core.trajectory import JointTrajectory

NAMES = ("j1", "j2")


class _Unguarded(Backend):
    """A kinematic two-joint arm whose `_execute` trusts the base class: it jumps to the goal
    without asking whether a stop landed, and counts how often it was given a trajectory."""

    name = "unguarded"

    def __init__(self) -> None:
        super().__init__(NAMES, start_tolerance_rad=0.01)
        self.positions = np.zeros(2)
        self.handed_over = 0

    async def _open(self) -> None:
        pass

    async def _close(self) -> None:
        pass

    async def _read_joint_state(self) -> JointState:
        return JointState(NAMES, self.positions.copy(), np.zeros(2), 0.0)

    async def _execute(self, trajectory, progress) -> ExecutionResult:
        self.handed_over += 1
        self.positions = trajectory.goal.copy()
        progress(1.0)
        return ExecutionResult(True, "completed", self.positions.copy())

    async def _stop(self) -> None:
        pass

    def _stop_now(self) -> None:
        pass


def _move() -> JointTrajectory:
    return JointTrajectory(NAMES, np.array([0.0, 1.0]), np.array([[0.0, 0.0], [0.5, -0.5]]))


@pytest.mark.anyio
async def test_a_trajectory_decided_before_a_stop_from_another_thread_is_not_handed_to_the_hook() -> None:
    backend = _Unguarded()
    await backend.open()
    try:
        decided = backend.stop_epoch
        stopper = threading.Thread(target=backend.stop_now)  # the stop channel's thread
        stopper.start()
        stopper.join()

        result = await backend.execute(_move(), stop_epoch=decided)

        assert not result.completed and result.reason == PREEMPTED
        assert backend.handed_over == 0
        assert np.array_equal(result.final_positions, np.zeros(2))
    finally:
        await backend.close()


@pytest.mark.anyio
async def test_a_trajectory_decided_after_the_last_stop_is_handed_to_the_hook() -> None:
    """The other side of the same check: no stop since the decision, so the hook runs it."""
    backend = _Unguarded()
    await backend.open()
    try:
        await backend.stop()
        decided = backend.stop_epoch

        result = await backend.execute(_move(), stop_epoch=decided)

        assert result.completed and backend.handed_over == 1
    finally:
        await backend.close()
