"""A client that drops its HTTP connection, or cancels its call, in the middle of `execute_plan`
leaves the arm stopped, under both protocol revisions (on a disconnect under 2026-07-28 the SDK
cancels the call; under 2025-11-25 the call outlives its request, and ArmWarden's
`AbandonedMotionStop` layer stops it). Real daemon subprocess on 127.0.0.1, slowed down so that
the motion is still running when the client goes away."""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import anyio
import pytest

from armwarden.transport.request_body import MAX_BODY_BYTES
from tests.helpers import records_of
from tests.server.harness import HOME_TCP_X, MODES, MotionStarted
from tests.server.harness import approve as approving
from tests.server.http_daemon import Daemon, RawSession, http_daemon, session


@pytest.fixture(scope="module")
def slow_daemon(tmp_path_factory) -> Iterator[Daemon]:
    with http_daemon(tmp_path_factory.mktemp("http-disconnect"), speedup=0.5) as running:
        yield running


async def plan_a_slow_move(client: Any) -> dict[str, Any]:
    """A 0.13 m vertical TCP move from wherever the arm is (about 1 s at full speed, 2 s here)."""
    start = (await client.call_tool("get_robot_state", {})).structured_content["tcp_pose"]["position"]
    target = {"x": HOME_TCP_X, "y": 0.0, "z": 0.35 if start["z"] > 0.42 else 0.48}
    plan = (await client.call_tool("plan_to_pose", {"position": target})).structured_content
    assert plan["status"] == "ok" and plan["duration_s"] > 0.8, plan
    return plan


async def state_and_motion(daemon: Daemon, mode: str) -> tuple[list[float], dict[str, Any]]:
    http, client = session(daemon, daemon.operator_token, mode)
    async with http, client:
        state = (await client.call_tool("get_robot_state", {})).structured_content
        motion = (await client.call_tool("get_motion_status", {})).structured_content
    return state["joint_positions"], motion


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_a_client_that_disconnects_mid_motion_leaves_the_arm_stopped(slow_daemon, mode) -> None:
    on_progress = MotionStarted()

    with anyio.fail_after(30):
        async with anyio.create_task_group() as group:
            http, client = session(slow_daemon, slow_daemon.operator_token, mode, approving())
            async with http, client:
                plan = await plan_a_slow_move(client)

                async def execute() -> None:
                    await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]}, progress_callback=on_progress)

                group.start_soon(execute)
                await on_progress.event.wait()
                group.cancel_scope.cancel()  # the whole client goes: streams closed, connection dropped

        # the arm must come to rest well before the plan's end (2 × duration at speedup 0.5)
        for _ in range(100):
            first, motion = await state_and_motion(slow_daemon, mode)
            if not motion["executing"]:
                break
            await anyio.sleep(0.05)
        await anyio.sleep(0.1)
        second, motion = await state_and_motion(slow_daemon, mode)
    plan_id = plan["plan_id"]
    assert first == second  # still
    assert motion["last_result"]["plan_id"] == plan_id
    assert motion["last_result"]["status"] == "aborted"
    records = records_of(slow_daemon.audit)
    interrupted = [r for r in records if r["event"] == "execution_interrupted" and plan_id in r["detail"]]
    assert [r["outcome"] for r in interrupted] == ["stopped"], interrupted
    gone = [r for r in records if r["event"] == "client_disconnected" and r["arguments"] == {"plan_id": plan_id}]
    assert [(r["principal"], r["outcome"]) for r in gone] == [
        ("alice", "cancelled" if mode == "legacy" else "ended_with_request")], gone  # 2026-07-28: the SDK cancelled it


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_a_client_that_cancels_execute_plan_mid_motion_leaves_the_arm_stopped(slow_daemon, mode) -> None:
    on_progress = MotionStarted()

    with anyio.fail_after(30):
        http, client = session(slow_daemon, slow_daemon.operator_token, mode, approving())
        async with http, client:
            plan = await plan_a_slow_move(client)
            async with anyio.create_task_group() as group:
                async def execute() -> None:
                    await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]}, progress_callback=on_progress)

                group.start_soon(execute)
                await on_progress.event.wait()
                group.cancel_scope.cancel()  # this call only: the session stays open
            for _ in range(100):
                motion = (await client.call_tool("get_motion_status", {})).structured_content
                if not motion["executing"]:
                    break
                await anyio.sleep(0.05)
            first = (await client.call_tool("get_robot_state", {})).structured_content["joint_positions"]
            await anyio.sleep(0.1)
            second = (await client.call_tool("get_robot_state", {})).structured_content["joint_positions"]
    plan_id = plan["plan_id"]
    assert first == second
    assert motion["last_result"]["plan_id"] == plan_id and motion["last_result"]["status"] == "aborted"


def test_an_approval_answered_after_its_client_dropped_the_call_moves_nothing(slow_daemon) -> None:
    raw = RawSession(slow_daemon, slow_daemon.operator_token)
    start = raw.call("get_robot_state", {})["result"]["structuredContent"]["joint_positions"]
    goal = [start[0] + 1.0 if start[0] < 1.0 else start[0] - 1.0, *start[1:]]  # 1 rad: a human must approve
    plan = raw.call("plan_to_joints", {"joint_positions": goal})["result"]["structuredContent"]
    assert plan["status"] == "needs_approval", plan
    call = raw.open_call("execute_plan", {"plan_id": plan["plan_id"]})
    question = call.wait_for(lambda event: event.get("method") == "elicitation/create")
    call.drop()  # the client goes away while the human is deciding
    time.sleep(0.5)
    # the human approves anyway, and the answer reaches the session
    raw.post({"jsonrpc": "2.0", "id": question["id"],
              "result": {"action": "accept", "content": {"approve": True, "operator": "late"}}})
    time.sleep(1.0)
    after = raw.call("get_robot_state", {})["result"]["structuredContent"]["joint_positions"]
    motion = raw.call("get_motion_status", {})["result"]["structuredContent"]
    assert after == start and not motion["executing"]
    records = records_of(slow_daemon.audit)
    assert any(r["event"] == "client_disconnected" and r["outcome"] == "cancelled"
               and r["arguments"] == {"plan_id": plan["plan_id"]} for r in records)


@pytest.mark.anyio
async def test_a_call_abandoned_by_another_client_does_not_stop_this_motion(slow_daemon) -> None:
    http, client = session(slow_daemon, slow_daemon.operator_token, "legacy", approving())
    async with http, client:
        plan = await plan_a_slow_move(client)
        outcome: dict[str, Any] = {}
        on_progress = MotionStarted()

        async def execute() -> None:
            outcome["result"] = await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]},
                                                       progress_callback=on_progress)

        async with anyio.create_task_group() as group:
            group.start_soon(execute)
            await on_progress.event.wait()
            observer = RawSession(slow_daemon, slow_daemon.observer_token)  # names the same plan, hangs up
            await anyio.to_thread.run_sync(lambda: observer.open_call("execute_plan", {"plan_id": plan["plan_id"]}).drop())
    result = outcome["result"].structured_content
    assert result["status"] == "succeeded", result


def test_a_post_body_over_the_limit_is_refused_before_the_sdk_sees_it(slow_daemon) -> None:
    raw = RawSession(slow_daemon, slow_daemon.operator_token)
    message = {"jsonrpc": "2.0", "id": 99, "method": "tools/call",
               "params": {"name": "execute_plan", "arguments": {"plan_id": "plan_x"}, "_meta": {"pad": "x" * MAX_BODY_BYTES}}}
    assert raw.post(message).status_code == 413
