"""Motion on every backend: a safe plan runs to its goal; an e-stop, a stop and a client's cancel
each end a running motion with the arm held; a second execution while one runs is refused. Each
scenario checks what the arm did (the counting wrapper, joint positions, e-stop state) and what
the audit log recorded."""

from __future__ import annotations

import threading
from typing import Any

import anyio
import pytest
from mcp import Client

from tests.scenarios.steps import (
    SLOW,
    assert_refused,
    assert_still,
    calls,
    events,
    execute,
    executing,
    joint_positions,
    joints,
    last_result,
    offset,
    plan_joints,
    safety,
    text_of,
    wait_until,
)
from tests.server.harness import MODES, ArmHarness, approve

pytestmark = pytest.mark.anyio


def between(held: list[float], start: list[float], goal: list[float]) -> bool:
    """`held` lies strictly between `start` and `goal` on the moving joints: it moved, then stopped short."""
    moving = [i for i, (a, b) in enumerate(zip(start, goal, strict=True)) if abs(b - a) > 1e-9]
    return all(min(start[i], goal[i]) < held[i] < max(start[i], goal[i]) for i in moving)


async def estop_mid_motion(arm: ArmHarness, mover: Client, other: Client) -> tuple[list[float], dict[str, Any], Any]:
    """A slow plan from where the arm is, e-stopped by `other` once it runs: (start, plan, result)."""
    start = await joint_positions(mover)
    summary = await plan_joints(mover, offset(start, j1=0.3), **SLOW)
    async with executing(arm, mover, summary["plan_id"]) as outcome:
        stopped = await other.call_tool("estop", {"reason": "person entered the cell"})
        assert stopped.structured_content["estopped"] is True
    return start, summary, outcome["result"]


# ------------------------------------------------------------------ a safe plan
@pytest.mark.policy(**{"approval.mode": "always"})
@pytest.mark.parametrize("mode", MODES)
async def test_an_approved_safe_plan_runs_to_its_goal_with_the_operator_on_record(arm, mode, goal_tolerance_rad) -> None:
    human = approve("alice")
    goal = joints(j1=0.2, j4=0.1)
    async with arm.client(mode, human) as client:
        summary = await plan_joints(client, goal)
        assert summary["status"] == "needs_approval"

        done = await execute(client, summary["plan_id"])

        assert not done.is_error, text_of(done)
        assert done.structured_content["status"] == "succeeded"
        assert len(human.prompts) == 1 and summary["plan_id"] in human.prompts[0]
        assert arm.actuations == ["execute"]
        assert await assert_still(arm, client) == pytest.approx(goal, abs=goal_tolerance_rad)
    record = calls(arm, "execute_plan")[-1]
    assert (record["outcome"], record["operator"]) == ("ok", "alice")
    assert record["extra"]["approval"]["via"] == "elicitation"
    started = events(arm, "execution_started")
    assert [r["arguments"]["plan_id"] for r in started] == [summary["plan_id"]]
    assert started[0]["seq"] < record["seq"]  # on disk before the arm moved


# ------------------------------------------------------------------ e-stop
async def test_an_estop_during_motion_holds_the_arm_latches_and_invalidates_every_plan(arm) -> None:
    async with arm.client() as mover, arm.client() as other:
        spare = await plan_joints(mover, joints(j1=-0.1))  # made before the e-stop

        start, summary, result = await estop_mid_motion(arm, mover, other)

        assert not result.is_error, text_of(result)  # it was moving: aborted, not refused
        assert result.structured_content["status"] == "aborted" and result.structured_content["duration_s"] > 0.0
        held = await assert_still(arm, other)
        assert between(held, start, offset(start, j1=0.3)), held
        status = await safety(other)
        assert status["estopped"] is True and status["estop_event"]["source"] == "estop"
        assert arm.actuations == ["execute"] and arm.backend.stops >= 1
        assert_refused(arm, await execute(mover, spare["plan_id"]), "INVALIDATED_PLAN", moved_before=("execute",))
    estop = calls(arm, "estop")[-1]
    assert estop["outcome"] == "ok" and estop["arguments"] == {"reason": "person entered the cell"}
    moved = calls(arm, "execute_plan")[0]
    assert moved["arguments"] == {"plan_id": summary["plan_id"]} and moved["extra"]["result"]["status"] == "aborted"


async def test_after_an_estop_during_motion_only_a_human_releases_it_and_motion_works_again(arm, goal_tolerance_rad) -> None:
    async with arm.client() as mover, arm.client() as other:
        await estop_mid_motion(arm, mover, other)

        assert_refused(arm, await other.call_tool("reset_estop", {}), "APPROVAL_UNAVAILABLE", tool="reset_estop",
                       moved_before=("execute",))
        assert (await safety(other))["estopped"] is True
    async with arm.client("legacy", approve("bob")) as client:
        released = await client.call_tool("reset_estop", {})
        assert not released.is_error and released.structured_content["estopped"] is False, text_of(released)
        goal = offset(await joint_positions(client), j2=-0.1)
        summary = await plan_joints(client, goal)
        done = await execute(client, summary["plan_id"])
        assert done.structured_content["status"] == "succeeded", text_of(done)
        assert await assert_still(arm, client) == pytest.approx(goal, abs=goal_tolerance_rad)
        assert arm.actuations == ["execute", "execute"]
    reset = calls(arm, "reset_estop")[-1]
    assert (reset["outcome"], reset["operator"]) == ("ok", "bob")
    assert calls(arm, "execute_plan")[-1]["outcome"] == "ok"


# ------------------------------------------------------------------ stop_motion
async def test_stop_motion_during_motion_holds_the_arm_without_latching(arm) -> None:
    async with arm.client() as client, arm.client() as other:
        start = await joint_positions(client)
        goal = offset(start, j1=0.3)
        summary = await plan_joints(client, goal, **SLOW)

        async with executing(arm, client, summary["plan_id"]) as outcome:
            stop = await other.call_tool("stop_motion", {})
            assert not stop.is_error and stop.structured_content["stopped"] is True, text_of(stop)

        result = outcome["result"]
        assert not result.is_error, text_of(result)
        assert result.structured_content["status"] == "aborted" and result.structured_content["duration_s"] > 0.0
        assert between(await assert_still(arm, client), start, goal)
        assert (await safety(client))["estopped"] is False
        assert arm.actuations == ["execute"] and arm.backend.stops >= 1
    assert calls(arm, "stop_motion")[-1]["outcome"] == "ok"
    record = calls(arm, "execute_plan")[-1]
    assert record["outcome"] == "ok" and record["extra"]["result"]["status"] == "aborted"
    assert events(arm, "execution_interrupted") == []


# ------------------------------------------------------------------ the client cancels
@pytest.mark.parametrize("mode", MODES)
async def test_a_client_cancel_during_motion_stops_the_arm_and_is_audited(arm, mode) -> None:
    async with arm.client(mode) as client:
        start = await joint_positions(client)
        goal = offset(start, j1=0.3)
        summary = await plan_joints(client, goal, **SLOW)
        stops_before = arm.backend.stops

        async with anyio.create_task_group() as group:
            group.start_soon(execute, client, summary["plan_id"])
            await wait_until(lambda: arm.guard.motion_status().progress > 0.1)
            group.cancel_scope.cancel()
        await wait_until(lambda: bool(events(arm, "execution_interrupted")))

        assert arm.backend.stops > stops_before  # a stop was commanded
        assert between(await assert_still(arm, client), start, goal)
        last = await last_result(client)
        assert last["status"] == "aborted" and 0.0 < last["duration_s"] < summary["duration_s"]
        assert (await safety(client))["estopped"] is False
        assert arm.actuations == ["execute"]
    interrupted = events(arm, "execution_interrupted")
    assert [r["outcome"] for r in interrupted] == ["stopped"]
    assert summary["plan_id"] in interrupted[0]["detail"]
    assert calls(arm, "execute_plan")[-1]["outcome"] == "cancelled"


# ------------------------------------------------------------------ one execution at a time
async def test_a_second_execution_while_one_runs_is_refused_busy_and_its_plan_stays_usable(arm, goal_tolerance_rad) -> None:
    async with arm.client() as client:
        start = await joint_positions(client)
        first = await plan_joints(client, offset(start, j1=0.3), **SLOW)
        second = await plan_joints(client, offset(start, j2=-0.1))  # from the same start

        async with executing(arm, client, first["plan_id"]) as outcome:
            busy = await execute(client, second["plan_id"])
            assert_refused(arm, busy, "BUSY", moved_before=("execute",))

        assert outcome["result"].structured_content["status"] == "succeeded", text_of(outcome["result"])
        back = await plan_joints(client, start)
        assert (await execute(client, back["plan_id"])).structured_content["status"] == "succeeded"
        done = await execute(client, second["plan_id"])  # back at its start, the refused plan runs

        assert done.structured_content["status"] == "succeeded", text_of(done)
        assert await assert_still(arm, client) == pytest.approx(offset(start, j2=-0.1), abs=goal_tolerance_rad)
        assert arm.actuations == ["execute", "execute", "execute"]
    outcomes = [(r["arguments"]["plan_id"], r["outcome"]) for r in calls(arm, "execute_plan")]
    assert outcomes == [(second["plan_id"], "refused"), (first["plan_id"], "ok"), (back["plan_id"], "ok"),
                        (second["plan_id"], "ok")]


# ------------------------------------------------------------------ a stop from another thread
async def test_a_stop_from_another_thread_just_before_the_hand_over_keeps_the_arm_still(arm, monkeypatch) -> None:
    """The stop channel and SIGUSR1 stop from their own thread; one that lands after the Guard's
    last check but before the backend receives the trajectory must still win."""
    hand_over = arm.backend.execute

    async def stopped_from_elsewhere_first(trajectory, progress=None, *, stop_epoch=None):
        thread = threading.Thread(target=arm.inner.stop_now)
        thread.start()
        thread.join()
        return await hand_over(trajectory, progress, stop_epoch=stop_epoch)

    monkeypatch.setattr(arm.backend, "execute", stopped_from_elsewhere_first)
    async with arm.client() as client:
        start = await joint_positions(client)
        summary = await plan_joints(client, offset(start, j1=0.2))
        result = await execute(client, summary["plan_id"])
        report = result.structured_content
        assert report["status"] == "aborted" and "stopped before it started" in report["detail"], report
        assert await assert_still(arm, client) == pytest.approx(start, abs=max(arm.inner.hold_accuracy_rad, 1e-12))
