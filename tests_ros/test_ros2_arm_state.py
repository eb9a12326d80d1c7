"""The ROS 2 backend's arm state against the cell, through the action and the topic fallback: an
execution is moving from the hand-over until it completes (then idle), a stop holds the arm, a
held arm moves again, and a fault mid-motion latches faulted until a recovery."""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator

import pytest
from tests.backends.contract import straight_line

from armwarden.backends.arm_state import ArmState
from armwarden.backends.ros2.backend import Ros2Backend
from armwarden.backends.values import ExecutionResult
from armwarden.core.errors import BackendError
from armwarden.core.trajectory import JointTrajectory
from tests_ros.backend_setup import example_config, example_document, opened
from tests_ros.cell import Cell

pytestmark = pytest.mark.anyio

#: generous: the cell and the backend share this process with other suites on 2 cores
DEADLINE_S = 10.0
TOPIC = {"action": None, "topic": "/fr3_arm_controller/joint_trajectory"}


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


@pytest.fixture(params=["action", "topic"])
async def backend(request: pytest.FixtureRequest, cell: Cell) -> AsyncIterator[Ros2Backend]:
    """An open backend whose trajectories go through the action or the topic fallback."""
    changes = {"trajectory": TOPIC} if request.param == "topic" else {}
    # the cell publishes from a thread of this process: ages on a scale its stalls do not reach
    joint_states = {**example_document()["joint_states"], "max_age_s": 1.0}
    async with opened(example_config(joint_states=joint_states, **changes)) as opened_backend:
        yield opened_backend


async def motion(backend: Ros2Backend, duration_s: float, reach_rad: float = 0.1) -> JointTrajectory:
    q = (await backend.read_joint_state()).positions.copy()
    return straight_line(backend.joint_names, q, q + reach_rad, duration_s)


async def moving(backend: Ros2Backend, trajectory: JointTrajectory) -> asyncio.Task[ExecutionResult]:
    """`execute(trajectory)` as a task, returned once the arm state says moving."""
    task = asyncio.create_task(backend.execute(trajectory))
    deadline = time.monotonic() + DEADLINE_S
    while backend.arm_state is not ArmState.MOVING:
        if task.done():
            pytest.fail(f"the execution ended ({task.result()}) with the arm state {backend.arm_state} never moving")
        assert time.monotonic() < deadline, f"the arm state stayed {backend.arm_state}"
        await asyncio.sleep(0.005)
    return task


async def test_an_execution_is_moving_until_it_completes_then_idle(backend: Ros2Backend) -> None:
    assert backend.arm_state is ArmState.IDLE
    task = await moving(backend, await motion(backend, 1.0))
    result = await task
    assert result.completed and backend.arm_state is ArmState.IDLE


async def test_a_stop_mid_motion_holds_the_arm(backend: Ros2Backend) -> None:
    task = await moving(backend, await motion(backend, 5.0))
    backend.stop_now()  # (from this thread, as the e-stop channel does)
    result = await task
    assert result.reason == "stopped" and backend.arm_state is ArmState.HELD


async def test_a_held_arm_moves_again_and_rests_idle(backend: Ros2Backend) -> None:
    await backend.stop()
    assert backend.arm_state is ArmState.HELD
    task = await moving(backend, await motion(backend, 0.5))
    assert (await task).completed and backend.arm_state is ArmState.IDLE


async def test_joint_states_that_stop_mid_motion_latch_faulted_until_a_recovery(backend: Ros2Backend,
                                                                               cell: Cell) -> None:
    task = await moving(backend, await motion(backend, 5.0))
    cell.pause_joint_states()
    with pytest.raises(BackendError, match="execution aborted: joint states on /joint_states stopped arriving"):
        await task
    assert backend.arm_state is ArmState.FAULTED
    cell.pause_joint_states(False)
    await backend.error_recovery()
    assert backend.arm_state is ArmState.IDLE
