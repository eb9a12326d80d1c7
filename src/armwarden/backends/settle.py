"""Settling: the trajectory's last setpoint is commanded, the measured arm is still catching up.

One rule for every servo-driven backend (MuJoCo, CAN): an execution is complete only once the
measured joints are at the goal (within the backend's `goal_accuracy_rad`) and still (below its
`rest_speed_rad_s`). A stop meanwhile ends it "stopped" where the arm came to rest; a fault the
backend's `check` finds raises; and an arm that never gets there ends it "not completed" after
`timeout_s`, never "completed" on time alone.
"""

from __future__ import annotations

import time
from collections.abc import Awaitable, Callable
from typing import Protocol

import anyio
import numpy as np

from armwarden.backends.values import ExecutionResult


class MeasuredJoints(Protocol):
    """What settling reads from one sample of the arm: joint positions [rad] and speeds [rad/s]."""

    @property
    def positions(self) -> np.ndarray: ...

    @property
    def velocities(self) -> np.ndarray: ...


async def settle(
    goal: np.ndarray,
    *,
    measure: Callable[[], MeasuredJoints],
    check: Callable[[], None],
    stop_landed: Callable[[], bool],
    rest_position: Callable[[], Awaitable[np.ndarray]],
    accuracy_rad: float,
    rest_speed_rad_s: float,
    timeout_s: float,
    poll_s: float,
    speedup: float = 1.0,
) -> ExecutionResult:
    """Poll until the arm is at `goal` and still. Each poll: `check` (raises on a fault or a dead
    servo thread), take one `measure`, end "stopped" at `rest_position()` if a stop landed.
    `timeout_s` is on the arm's own clock: a simulation running `speedup` times faster than the
    wall clock gets it in `timeout_s / speedup` wall seconds (the reason still names `timeout_s`)."""
    deadline = time.monotonic() + timeout_s / speedup
    while True:
        check()
        sample = measure()
        if stop_landed():
            return ExecutionResult(False, "stopped", await rest_position())
        error = float(np.max(np.abs(sample.positions - goal)))
        if error <= accuracy_rad and np.max(np.abs(sample.velocities)) <= rest_speed_rad_s:
            return ExecutionResult(True, "completed", sample.positions.copy())
        if time.monotonic() > deadline:
            return ExecutionResult(False, f"did not settle at the goal within {timeout_s} s "
                                   f"(off by {error:.4f} rad)", sample.positions.copy())
        await anyio.sleep(poll_s)


__all__ = ["MeasuredJoints", "settle"]
