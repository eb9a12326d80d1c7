"""A backend thread that hangs (alive, no progress) is a latched, audited backend fault, like one
that dies (issue 24, item 1), seen through the official MCP client on the real Guard.

Found by review: with the servo thread blocked for 5 s inside a tick (fake, CAN, MuJoCo),
`get_robot_state` answered stale while `get_safety_status` said not e-stopped, no faults, and
nothing was audited: only a thread that *ended* was noticed. Each hang here is held by an event
the test controls and released before the backend closes; every wait is for a condition.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest

from armwarden.backends.can.backend import CanBackend
from armwarden.backends.fake.backend import FakeBackend
from armwarden.backends.servo import ServoLoop
from tests.backends.can.test_can_backend import Spy
from tests.backends.contract import straight_line
from tests.helpers import text_of
from tests.scenarios.steps import SLOW, executing, joints, plan_joints
from tests.server.harness import approve, arm_harness, policy_with, wait_until
from tests.server.test_backend_thread_death import assert_a_latched_audited_fault, safety

pytestmark = pytest.mark.anyio

#: each backend's thread that runs its servo loop
SERVO_WORKER = {"fake": "control", "can": "servo", "mujoco": "physics"}


def servo_of(backend: Any) -> ServoLoop:
    return backend.servo


@contextlib.contextmanager
def servo_blocked_in(backend: Any, hook: str) -> Iterator[threading.Event]:
    """The backend's servo thread blocks in its `hook` (`servo_prepare`: outside the loop's lock;
    `servo_command`: under it) until the block ends, as in a deadlock or a driver call that never
    returns. Yields an event set once the thread is blocked."""
    loop = servo_of(backend)
    blocked, release = threading.Event(), threading.Event()
    original = getattr(backend, hook)

    def hang(*args: Any, **kwargs: Any) -> Any:
        if threading.current_thread() is loop.thread and not release.is_set():
            blocked.set()
            release.wait(60)
        return original(*args, **kwargs)

    setattr(backend, hook, hang)  # the loop calls its hooks through the backend instance
    try:
        yield blocked
    finally:
        release.set()
        delattr(backend, hook)


@pytest.mark.parametrize("backend", ["fake", "can", "mujoco"])
async def test_a_servo_thread_that_hangs_while_idle_is_a_latched_audited_backend_fault(tmp_path, backend) -> None:
    async with arm_harness(tmp_path, backend=backend) as arm, arm.client("legacy", approve()) as client:
        assert not (await safety(client))["estopped"]
        with servo_blocked_in(arm.inner, "servo_prepare") as blocked:
            await wait_until(blocked.is_set, timeout_s=10.0, what="the servo thread blocked")
            worker = SERVO_WORKER[backend]
            await assert_a_latched_audited_fault(arm, client, f"the {worker} thread made no progress for")
            thread = servo_of(arm.inner).thread
            assert thread is not None and thread.is_alive()  # a hang, not a death
            assert arm.actuations == []


@pytest.mark.realtime
async def test_the_damping_frames_go_out_while_the_can_servo_thread_hangs(tmp_path) -> None:
    async with arm_harness(tmp_path, policy_with(**{"force.require_wrench": False}), backend="can") as arm:
        backend = arm.inner
        assert isinstance(backend, CanBackend)
        motors = {j.can_id for j in backend.config.joints}
        spy = Spy(backend)
        try:
            with servo_blocked_in(backend, "servo_prepare") as blocked:
                await wait_until(blocked.is_set, timeout_s=10.0, what="the servo thread blocked")
                mark = len(spy.seen())  # every frame after this was sent while the servo thread was blocked

                def damped() -> bool:
                    after = [s for s in spy.seen()[mark:] if s.command is not None]
                    return {s.motor for s in after if s.damping} >= motors

                await wait_until(damped, timeout_s=10.0, what="a damping frame to every joint")
                await wait_until(lambda: arm.guard.latch.is_latched, timeout_s=10.0, what="the e-stop latched")
                commands = [s for s in spy.seen() if s.command is not None]
                first = next(s.index for s in commands if s.index >= mark and s.damping)
                assert [s for s in commands if s.index > first and not s.damping] == []  # nothing stiff after
        finally:
            spy.close()


async def test_a_servo_thread_hung_under_its_lock_is_still_reported_though_the_stop_cannot_be_confirmed(
        tmp_path) -> None:
    async with arm_harness(tmp_path) as arm, arm.client("legacy", approve()) as client:
        with servo_blocked_in(arm.fake, "servo_command") as blocked:  # the hold needs the lock it holds
            await wait_until(blocked.is_set, timeout_s=10.0, what="the servo thread blocked")
            await assert_a_latched_audited_fault(arm, client, "the control thread made no progress for")
            reason = (await safety(client))["estop_event"]["reason"]
            assert "the stop did not return within" in reason, reason


async def test_a_servo_thread_that_hangs_mid_motion_is_answered_as_a_backend_fault(tmp_path) -> None:
    async with arm_harness(tmp_path) as arm, arm.client("legacy", approve()) as client:
        summary = await plan_joints(client, joints(j1=0.3), **SLOW)
        async with executing(arm, client, summary["plan_id"], past=0.05) as outcome:
            with servo_blocked_in(arm.fake, "servo_prepare") as blocked:
                await wait_until(blocked.is_set, timeout_s=10.0, what="the servo thread blocked")
                await wait_until(lambda: "result" in outcome, timeout_s=10.0, what="execute_plan answered")
                status = await safety(client)  # while it still hangs
        result = outcome["result"]
        text = text_of(result)
        assert result.is_error and "BACKEND_FAULT" in text and "the control thread made no progress" in text, text
        assert "FORCE_LIMIT" not in text, text
        assert status["estopped"] and status["estop_event"]["source"] == "backend_fault", status
        assert not status["force_violation_latched"], status


async def test_a_slow_but_progressing_servo_loop_is_not_a_hang() -> None:
    """Every third tick takes three of the loop's longest (idle) periods: late, never stopped."""
    backend = FakeBackend()
    faults: list[str] = []
    backend.set_fault_listener(faults.append)
    await backend.open()
    try:
        loop = backend.servo
        slow_ticks = 0
        original = backend.servo_prepare

        def slow(setpoint: Any) -> Any:
            nonlocal slow_ticks
            if threading.current_thread() is loop.thread and loop.tick_count % 3 == 0:
                slow_ticks += 1
                time.sleep(3 * loop.idle_period_s)
            return original(setpoint)

        backend.servo_prepare = slow  # type: ignore[method-assign]
        await wait_until(lambda: slow_ticks >= 40, timeout_s=60.0, what="40 slow ticks")
        q = (await backend.read_joint_state()).positions.copy()
        result = await backend.execute(straight_line(backend.joint_names, q, q + 0.1, 0.5))
        assert result.completed, result
        await wait_until(lambda: slow_ticks >= 80, timeout_s=60.0, what="40 more slow ticks")
        assert faults == [] and backend.worker_failure is None
        await backend.read_joint_state()
    finally:
        await backend.close()
