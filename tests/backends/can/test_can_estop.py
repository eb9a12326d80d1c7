"""The e-stop on CAN, through the daemon's tools: `estop` damps every joint (kp = 0, kd > 0) on the
bus and keeps damping until a reset and the next admitted move; `stop_motion` holds position.
Assertions are about the order of frames on the bus, never about wall time."""

from __future__ import annotations

from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import pytest

from armwarden.backends.can.backend import CanBackend
from tests.backends.can.test_can_backend import Seen, Spy
from tests.scenarios.steps import execute, joint_positions, offset, plan_joints, text_of, wait_until
from tests.server.harness import ArmHarness, approve, arm_harness, policy_with

pytestmark = pytest.mark.anyio


@pytest.fixture
async def arm(tmp_path: Path) -> AsyncIterator[ArmHarness]:
    async with arm_harness(tmp_path, policy_with(**{"force.require_wrench": False}), backend="can") as harness:
        yield harness


@pytest.fixture
def spy(arm: ArmHarness) -> Iterator[Spy]:
    assert isinstance(arm.inner, CanBackend)
    watcher = Spy(arm.inner)
    try:
        yield watcher
    finally:
        watcher.close()


def motors_of(arm: ArmHarness) -> set[int]:
    assert isinstance(arm.inner, CanBackend)
    return {j.can_id for j in arm.inner.config.joints}


def commands(spy: Spy, after: int = -1) -> list[Seen]:
    return [s for s in spy.seen() if s.command is not None and s.index > after]


def each_motor_has(seen: list[Seen], motors: set[int], count: int, damping: bool) -> bool:
    return all(sum(1 for s in seen if s.motor == m and s.damping == damping) >= count for m in motors)


async def test_estop_damps_every_joint_and_keeps_damping_through_a_stop_until_a_reset_and_a_move(arm, spy) -> None:
    motors = motors_of(arm)
    async with arm.client() as client:
        await wait_until(lambda: each_motor_has(commands(spy), motors, 3, damping=False))  # holding before
        result = await client.call_tool("estop", {"reason": "person entered the cell"})
        assert not result.is_error, text_of(result)
        # every later tick streams damping to every joint
        await wait_until(lambda: each_motor_has(commands(spy), motors, 5, damping=True))
        seen = commands(spy)
        first = next(s.index for s in seen if s.damping)
        assert [s for s in seen if s.index > first and not s.damping] == []
        assert arm.backend.emergency_stops >= 1

        # a stop while the e-stop is latched must not stiffen the arm again
        stopped = await client.call_tool("stop_motion", {})
        assert not stopped.is_error, text_of(stopped)
        mark = spy.seen()[-1].index
        await wait_until(lambda: each_motor_has(commands(spy, mark), motors, 3, damping=True))
        assert [s for s in commands(spy, first) if not s.damping] == []

    async with arm.client("legacy", approve("bob")) as client:
        released = await client.call_tool("reset_estop", {})
        assert not released.is_error, text_of(released)
        # the reset alone does not stiffen the arm: the next admitted move does
        mark = spy.seen()[-1].index
        await wait_until(lambda: each_motor_has(commands(spy, mark), motors, 3, damping=True))
        assert [s for s in commands(spy, first) if not s.damping] == []

        goal = offset(await joint_positions(client), j2=-0.1)
        done = await execute(client, (await plan_joints(client, goal))["plan_id"])
        assert not done.is_error and done.structured_content["status"] == "succeeded", text_of(done)
        mark = spy.seen()[-1].index
        await wait_until(lambda: each_motor_has(commands(spy, mark), motors, 3, damping=False))
        assert [s for s in commands(spy, mark) if s.damping] == []  # held at the goal, not damped


async def test_stop_motion_holds_position_on_every_joint_it_does_not_damp(arm, spy) -> None:
    motors = motors_of(arm)
    async with arm.client() as client:
        stopped = await client.call_tool("stop_motion", {})
        assert not stopped.is_error, text_of(stopped)
        mark = spy.seen()[-1].index
        await wait_until(lambda: each_motor_has(commands(spy, mark), motors, 3, damping=False))
        after = commands(spy, mark)
        assert [s for s in after if s.damping] == []
        assert all(s.command is not None and s.command.kp > 0.0 for s in after)
    assert arm.backend.emergency_stops == 0 and arm.backend.stops >= 1
