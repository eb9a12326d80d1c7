"""A ROS executor that hangs (alive, no callback runs) is a latched, audited backend fault, like
one that dies (issue 24, item 1), and during a motion it is the cause the answer names.

Found by review: one callback that blocks (queued with `RosBridge.call_soon`) held the executor
for 5 s; `get_robot_state` answered stale while `get_safety_status` said not e-stopped, no
faults, and nothing was audited — the backend's own watchdog (`_watch`) is a timer on that
executor and stopped with it. Each hang here is held by an event the test controls and released
before the backend closes; every wait is for a condition.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator

import pytest
from tests.helpers import text_of
from tests.scenarios.steps import executing, joints, plan_joints
from tests.server.harness import approve, arm_harness, wait_until
from tests.server.test_backend_thread_death import assert_a_latched_audited_fault, safety

from armwarden.backends.ros2.backend import Ros2Backend
from armwarden.backends.ros2.bridge import HEARTBEAT_PERIOD_S
from armwarden.backends.ros2.config import JointStatesConfig
from armwarden.backends.watchdog import STALL_LIMIT_S, stall_deadline_s

pytestmark = pytest.mark.anyio

HUNG = "the executor thread made no progress for"


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


@pytest.fixture
def release() -> Iterator[threading.Event]:
    """Ends the hang (set at the latest when the test ends, before the backend closes)."""
    event = threading.Event()
    try:
        yield event
    finally:
        event.set()


def block_the_executor(backend: Ros2Backend, release: threading.Event) -> threading.Event:
    """Queue a callback that blocks the executor until `release`; returns an event set once it blocks."""
    blocked = threading.Event()

    def block() -> None:
        blocked.set()
        release.wait(60)

    backend.bridge.call_soon(block)
    return blocked


async def test_an_executor_that_hangs_while_idle_is_a_latched_audited_backend_fault(tmp_path, release) -> None:
    async with arm_harness(tmp_path, backend="ros2") as arm, arm.client("legacy", approve()) as client:
        backend = arm.inner
        assert isinstance(backend, Ros2Backend)
        assert not (await safety(client))["estopped"]
        try:
            blocked = block_the_executor(backend, release)
            await wait_until(blocked.is_set, timeout_s=10.0, what="the executor blocked")
            await assert_a_latched_audited_fault(arm, client, HUNG)
            assert backend.bridge.spinning  # a hang, not a death
            assert arm.actuations == []
        finally:
            release.set()


async def test_an_executor_that_hangs_mid_motion_is_answered_as_a_backend_fault_and_the_goal_cancelled(
        tmp_path, release) -> None:
    async with arm_harness(tmp_path, backend="ros2") as arm, arm.client("legacy", approve()) as client:
        backend = arm.inner
        assert isinstance(backend, Ros2Backend)
        summary = await plan_joints(client, joints(j1=0.3), velocity_scaling=0.1, acceleration_scaling=0.1)
        try:
            async with executing(arm, client, summary["plan_id"], past=0.05) as outcome:
                blocked = block_the_executor(backend, release)
                await wait_until(blocked.is_set, timeout_s=10.0, what="the executor blocked")
                await wait_until(lambda: "result" in outcome, timeout_s=10.0, what="execute_plan answered")
                # the cancel went out beside the hung executor (a cancel request needs none)
                await wait_until(lambda: arm.cell.counters().goals_canceled >= 1, timeout_s=10.0,
                                 what="the cell saw the goal cancelled")
                status = await safety(client)  # while it still hangs
        finally:
            release.set()
        result = outcome["result"]
        text = text_of(result)
        assert result.is_error and "BACKEND_FAULT" in text and HUNG in text, text
        assert "FORCE_LIMIT" not in text and "stopped arriving" not in text, text  # the cause, not a symptom
        assert status["estopped"] and status["estop_event"]["source"] == "backend_fault", status
        assert HUNG in status["estop_event"]["reason"] and not status["force_violation_latched"], status


def test_the_executor_hang_deadline_is_within_the_state_max_age() -> None:
    """20 heartbeat periods, under the joint states' default max age: the hang is named first."""
    deadline_s = stall_deadline_s(HEARTBEAT_PERIOD_S)
    assert deadline_s <= STALL_LIMIT_S
    assert deadline_s < JointStatesConfig.model_fields["max_age_s"].default
