"""The ROS 2 guardian process seen from the daemon's side, in the test process: started with the
backend, it is watched in turn. A guardian that dies is a fault: the e-stop latches and no goal is
sent while it is gone. (A daemon that dies or hangs mid-motion: tests_ros/test_daemon_ros2.py.)"""

from __future__ import annotations

import os
import signal

import anyio
import pytest
from tests.helpers import text_of
from tests.server.harness import HOME_TCP_X, approve, arm_harness, wait_until

pytestmark = pytest.mark.anyio

GUARDED = {"guardian": {"deadline_s": 0.5}}


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


async def test_the_backend_starts_a_guardian_that_closing_ends(tmp_path) -> None:
    async with arm_harness(tmp_path, backend="ros2", **GUARDED) as arm:
        guardian = arm.inner.guardian
        process = None if guardian is None else guardian.process
        assert guardian is not None and process is not None and guardian.problem is None
        assert process.poll() is None  # alive while the backend is open
    assert process.wait(timeout=10) == 0  # it left on "bye", nothing killed it


async def test_a_guardian_that_dies_latches_the_estop_and_no_goal_is_sent(tmp_path) -> None:
    async with arm_harness(tmp_path, backend="ros2", **GUARDED) as arm, arm.client("legacy", approve()) as client:
        guardian = arm.inner.guardian
        assert guardian is not None and guardian.process is not None
        guardian.process.kill()
        await wait_until(lambda: arm.guard.latch.current_event is not None, what="the e-stop latched")
        status = (await client.call_tool("get_safety_status", {})).structured_content
        assert status["estopped"] and "guardian process exited" in status["estop_event"]["reason"], status

        plan = await client.call_tool("plan_to_pose", {"position": {"x": HOME_TCP_X, "y": 0.0, "z": 0.4}})
        assert plan.is_error and "ESTOPPED" in text_of(plan), text_of(plan)
        assert arm.actuations == []
        assert guardian.problem is not None and "exited" in guardian.problem


async def test_the_guardian_outlives_signals_to_the_daemons_group_in_a_session_of_its_own(tmp_path) -> None:
    async with arm_harness(tmp_path, backend="ros2", **GUARDED) as arm:
        guardian = arm.inner.guardian
        assert guardian is not None and guardian.process is not None
        pid = guardian.process.pid
        assert os.getsid(pid) != os.getsid(0)  # a terminal's hang-up or Ctrl-C does not reach it
        for number in (signal.SIGTERM, signal.SIGHUP, signal.SIGINT):  # a group stop would send these
            os.kill(pid, number)
        await anyio.sleep(0.5)  # a guardian that died of them has exited by now
        assert guardian.process.poll() is None and guardian.problem is None
    assert guardian.process.wait(timeout=10) == 0  # only its pipe ends it
