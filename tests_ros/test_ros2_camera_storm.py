"""Many camera snapshots at once on the ROS 2 backend (issue 24, item 1): the executor thread
survives, the camera's subscription is made and destroyed on that thread only, and nothing else
suffers — joint states stay fresh, no fault is reported, and a motion running meanwhile ends at
its goal.

Found by review: 30 concurrent `camera_snapshot` calls killed the executor thread (`InvalidHandle:
cannot use Destroyable because destruction was requested`: each snapshot subscribed and
unsubscribed from the event loop while the executor walked the node's subscriptions); the
daemon then served stale joint states and reported itself healthy.

The race needs the interpreter to switch threads at the wrong bytecode; these tests shorten the
interpreter's switch interval (`switching_often`) so that a destruction from the wrong thread
lands in the executor's walk in nearly every run, as it does now and then in a daemon under load.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import random
import sys
from collections.abc import Iterator
from typing import Any

import pytest
from tests.backends.contract import straight_line
from tests.helpers import text_of
from tests.scenarios.steps import executing, joints, plan_joints
from tests.server.harness import MODES, approve, arm_harness, policy_with

from armwarden.backends.values import CameraImage
from tests_ros.backend_setup import opened
from tests_ros.cell import Cell

pytestmark = pytest.mark.anyio

#: how many snapshots, and over how long [s] they start (several camera frames: 10 Hz)
SNAPSHOTS = 150
SPREAD_S = 1.5
#: the interpreter's thread switch interval during the storm [s] (CPython's default: 5 ms)
SWITCH_INTERVAL_S = 1e-5


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


@contextlib.contextmanager
def switching_often() -> Iterator[None]:
    before = sys.getswitchinterval()
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    try:
        yield
    finally:
        sys.setswitchinterval(before)


async def storm(take: Any, count: int = SNAPSHOTS, spread_s: float = SPREAD_S, seed: int = 24) -> list[Any]:
    """`count` calls of `take()`, each starting at a random moment within `spread_s`; their outcomes."""
    rng = random.Random(seed)

    async def one(delay_s: float) -> Any:
        await asyncio.sleep(delay_s)
        return await take()

    return await asyncio.gather(*(one(rng.uniform(0.0, spread_s)) for _ in range(count)), return_exceptions=True)


async def test_a_storm_of_snapshots_during_a_motion_leaves_the_executor_and_the_motion_alone(cell: Cell) -> None:
    async with opened() as backend:
        faults: list[str] = []
        backend.set_fault_listener(faults.append)
        q = (await backend.read_joint_state()).positions.copy()
        trajectory = straight_line(backend.joint_names, q, q + 0.2, 3.0)
        with switching_often():
            moving = asyncio.create_task(backend.execute(trajectory))
            outcomes = await storm(lambda: backend.camera_snapshot("scene"))
            result = await moving
        failed = [o for o in outcomes if not isinstance(o, CameraImage)]
        assert not failed, f"{len(failed)} of {len(outcomes)} snapshots failed, e.g. {failed[0]!r}"
        assert backend.bridge.spinning, "the executor thread died"
        assert faults == [] and backend.worker_failure is None
        assert result.completed, result
        await backend.read_joint_state()  # fresh: the stream still arrives


async def test_the_cameras_subscription_exists_only_while_snapshots_wait(cell: Cell) -> None:
    async with opened() as backend:
        assert backend.cameras is not None
        feed = backend.cameras.feeds["scene"]
        node = backend.bridge.node
        before = len(list(node.subscriptions))
        images = await asyncio.gather(*(backend.camera_snapshot("scene") for _ in range(20)))
        assert all(image.width == 64 for image in images)
        deadline = asyncio.get_running_loop().time() + 10.0
        while feed.subscribed:  # unsubscribed on the executor thread, on its next turn
            assert asyncio.get_running_loop().time() < deadline, "the camera stayed subscribed"
            await asyncio.sleep(0.01)
        assert len(list(node.subscriptions)) == before


async def test_a_storm_of_camera_tool_calls_from_many_sessions_during_an_execution_changes_nothing(tmp_path) -> None:
    """The whole stack (MCP tools, the Guard, the backend): 10 sessions call `camera_snapshot` 15
    times each (rate limits raised for it) while another executes a plan; afterwards the daemon
    is healthy and truthful."""
    roomy = policy_with(**{"rate_limits.global_per_minute": 1000, "rate_limits.per_tool.camera_snapshot": 1000})
    async with arm_harness(tmp_path, roomy, backend="ros2") as arm, contextlib.AsyncExitStack() as stack:
        mover = await stack.enter_async_context(arm.client("legacy", approve()))
        viewers = [await stack.enter_async_context(arm.client(mode)) for mode in MODES * 5]
        summary = await plan_joints(mover, joints(j1=0.3), velocity_scaling=0.1, acceleration_scaling=0.1)
        with switching_often():
            async with executing(arm, mover, summary["plan_id"], past=0.02) as outcome:
                turns = itertools.cycle(viewers)
                snapshots = await storm(lambda: next(turns).call_tool("camera_snapshot", {"camera": "scene"}))
        failed = [s for s in snapshots if isinstance(s, BaseException) or s.is_error]
        assert not failed, f"{len(failed)} of {len(snapshots)} snapshots failed, e.g. {failed[0]!r}"
        done = outcome["result"]
        assert not done.is_error and done.structured_content["status"] == "succeeded", text_of(done)
        status = (await mover.call_tool("get_safety_status", {})).structured_content
        assert not status["estopped"] and status["faults"] == [], status
        state = await mover.call_tool("get_robot_state", {})
        assert not state.is_error, text_of(state)
        assert arm.inner.bridge.spinning
