"""End-to-end execution behaviour through the SDK client (in-memory, both protocol modes).

Force limit, fail-closed wrench monitoring, cancellation and disconnect mid-motion, an e-stop
from another client, progress, dry run and a failing stop. Every scenario runs the real Guard
and server on the fake backend (see `harness.py`); the fake's fault injection (`table_height_m`,
`freeze_wrench`, `stall_wrench_s`, `fail_stop`, `wrench`) stands in for the hardware fault.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import math
from collections.abc import AsyncIterator
from typing import Any

import anyio
import pytest
from mcp import Client, MCPError

from tests.helpers import records_of, text_of
from tests.server import harness
from tests.server.harness import HOME_TCP_X, MODES, approve, arm_harness, policy_with, wait_until

DOWN_TARGET_Z = 0.30  # a plan straight down from home: 0.19 m of TCP travel, 1.5 s at the default scaling
TABLE_Z = DOWN_TARGET_Z + 0.02  # the virtual table top, just above the planned target


# ------------------------------------------------------------------ helpers
@contextlib.asynccontextmanager
async def executing(arm: Any, client: Client, plan_id: str, past: float = 0.05) -> AsyncIterator[dict[str, Any]]:
    """`execute_plan(plan_id)` in the background; the body runs once the arm is `past` that fraction
    of the motion; after the block the call's result is in `outcome["result"]`."""
    outcome: dict[str, Any] = {}

    async def run() -> None:
        outcome["result"] = await client.call_tool("execute_plan", {"plan_id": plan_id})

    async with anyio.create_task_group() as group:
        group.start_soon(run)
        await wait_until(lambda: arm.guard.motion_status().progress > past, what="motion started")
        yield outcome


async def plan_down(client: Client, z: float = DOWN_TARGET_Z) -> dict[str, Any]:
    """A plan down to `z` that needs no approval."""
    return await harness.plan_down(client, z, status="ok")


async def tcp_z(client: Client) -> float:
    state = await client.call_tool("get_robot_state", {})
    return state.structured_content["tcp_pose"]["position"]["z"]


async def assert_arm_still(client: Client) -> list[float]:
    """Two joint-state reads 50 ms apart are identical (the fake is kinematic: still means equal)."""
    first = (await client.call_tool("get_robot_state", {})).structured_content
    await anyio.sleep(0.05)
    second = (await client.call_tool("get_robot_state", {})).structured_content
    assert first["joint_positions"] == second["joint_positions"]
    assert all(v == 0.0 for v in second["joint_velocities"])
    return second["joint_positions"]


async def safety(client: Client) -> dict[str, Any]:
    return (await client.call_tool("get_safety_status", {})).structured_content


async def motion(client: Client) -> dict[str, Any]:
    return (await client.call_tool("get_motion_status", {})).structured_content


# ------------------------------------------------------------------ force limit
@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_pressing_into_the_table_over_the_force_limit_aborts_mid_motion_and_latches_the_estop(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, table_height_m=TABLE_Z, speedup=2.0) as arm, arm.client(mode, approve()) as client:
        earlier = await client.call_tool("plan_to_pose", {"position": {"x": 0.35, "y": 0.05, "z": 0.45}})
        assert earlier.structured_content["status"] == "ok"
        summary = await plan_down(client)
        assert summary["force_monitoring"] is True

        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})

        assert result.is_error
        assert "FORCE_LIMIT" in text_of(result) and "reset_estop" in text_of(result)
        status = await safety(client)
        assert status["estopped"] is True
        assert status["force_violation_latched"] is True
        assert status["estop_event"]["source"] == "force_monitor"
        # stopped on the table, well short of the planned target below its top
        await assert_arm_still(client)
        assert await tcp_z(client) > DOWN_TARGET_Z + 0.005
        last = (await motion(client))["last_result"]
        assert last["status"] == "aborted" and last["max_observed_force_n"] > 30.0
        # a plan made before the violation can no longer run
        again = await client.call_tool("execute_plan", {"plan_id": earlier.structured_content["plan_id"]})
        assert again.is_error and "INVALIDATED_PLAN" in text_of(again)
        assert arm.actuations == ["execute"]


# ------------------------------------------------------------------ wrench monitoring fails closed
@pytest.mark.anyio
@pytest.mark.parametrize("fault", ["freeze_wrench", "stall_wrench_s"])
@pytest.mark.parametrize("mode", MODES)
async def test_a_wrench_that_freezes_or_stalls_mid_motion_aborts_the_motion(tmp_path, mode, fault) -> None:
    # the bundled policy as it is (`policy_with()`): its 0.1 s wrench timeout, not the harness's stall-tolerant one
    async with arm_harness(tmp_path, policy_with(), speedup=1.0) as arm, arm.client(mode, approve()) as client:
        summary = await plan_down(client, z=0.40)
        async with executing(arm, client, summary["plan_id"]) as outcome:
            setattr(arm.fake, fault, True if fault == "freeze_wrench" else 0.5)

        arm.fake.stall_wrench_s = 0.0  # state reads below read the wrench too; keep them quick
        result = outcome["result"]
        assert result.is_error and "FORCE_LIMIT" in text_of(result)
        # a frozen sensor is caught as frozen or, as its one sample ages, as stale: either stops the arm
        expected = ("has not advanced", "s old") if fault == "freeze_wrench" else ("longer than",)
        assert any(text in text_of(result) for text in expected), text_of(result)
        status = await safety(client)
        # latched for the lost wrench; no force over the limit was measured, so no force violation
        assert status["estopped"] and not status["force_violation_latched"], status
        assert status["estop_event"]["source"] == "wrench_lost", status
        await assert_arm_still(client)
        assert await tcp_z(client) > 0.40 + 0.01  # stopped short of the goal


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_a_wrench_that_is_already_stalled_refuses_execution_before_anything_moves(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, policy_with(), stall_wrench_s=0.3) as arm, arm.client(mode, approve()) as client:
        summary = await plan_down(client, z=0.40)
        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
        assert result.is_error and "NO_WRENCH" in text_of(result)
        assert arm.actuations == []


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_no_wrench_at_all_is_refused_when_the_policy_requires_one(tmp_path, mode) -> None:
    policy = policy_with(**{"force.source": "sensor"})  # the fake's joint torques would serve `auto`
    async with arm_harness(tmp_path, policy, wrench=False) as arm, arm.client(mode, approve()) as client:
        summary = await plan_down(client, z=0.40)
        assert summary["force_monitoring"] is False
        assert any("execute_plan will refuse" in note for note in summary["notes"])
        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
        assert result.is_error and "NO_WRENCH" in text_of(result)
        assert arm.actuations == []


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_no_wrench_at_all_runs_when_the_policy_allows_it_and_says_force_is_not_enforced(tmp_path, mode) -> None:
    policy = policy_with(**{"force.require_wrench": False, "approval.mode": "always", "force.source": "sensor"})
    prompts = approve()
    async with arm_harness(tmp_path, policy, wrench=False) as arm, arm.client(mode, prompts) as client:
        result = await client.call_tool("plan_to_pose", {"position": {"x": HOME_TCP_X, "y": 0.0, "z": 0.40}})
        summary = result.structured_content
        assert summary["force_monitoring"] is False
        assert any("NOT enforced" in note for note in summary["notes"])

        done = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})

        assert not done.is_error, text_of(done)
        report = done.structured_content
        assert report["status"] == "succeeded"
        assert report["max_observed_force_n"] is None
        assert "NOT enforced" in report["detail"]
        assert any("Force monitoring" in p and "NOT enforced" in p for p in prompts.prompts)
        assert arm.actuations == ["execute"]


# ------------------------------------------------------------------ cancellation and disconnect
@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_client_cancel_mid_motion_stops_the_arm_and_is_audited(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, speedup=1.0) as arm, arm.client(mode, approve()) as client:
        summary = await plan_down(client)
        start_z = await tcp_z(client)
        with anyio.move_on_after(0.4) as scope:
            await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
        assert scope.cancelled_caught, "the call should still have been running"

        await wait_until(lambda: not arm.guard.motion_status().executing, what="execution ended")
        await wait_until(
            lambda: any(r["event"] == "execution_interrupted" for r in records_of(arm.audit_path))
            and any(r["tool"] == "execute_plan" and r["outcome"] == "cancelled" for r in records_of(arm.audit_path)),
            what="cancellation audited",
        )
        await assert_arm_still(client)
        z = await tcp_z(client)
        assert DOWN_TARGET_Z + 0.01 < z < start_z - 0.005  # it moved, then stopped short of the goal
        status = await motion(client)
        assert status["executing"] is False
        assert status["last_result"]["status"] == "aborted"
        assert arm.backend.stops >= 1


# In-memory, only the legacy mode has a connection to lose: the SDK's 2026-07-28 in-process client
# dispatches directly in the caller's task. test_daemon_stdio.py covers a real disconnect in both modes.
@pytest.mark.anyio
@pytest.mark.parametrize("mode", ["legacy"])
async def test_client_disconnect_mid_motion_stops_the_arm(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, speedup=1.0) as arm:
        errors: list[BaseException] = []
        with anyio.fail_after(10):
            async with anyio.create_task_group() as group:
                async with arm.client(mode, approve()) as client:
                    summary = await plan_down(client)  # a plan runs only for the client that made it

                    async def run() -> None:
                        try:
                            await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
                        except Exception as exc:  # the connection closes under the call
                            errors.append(exc)

                    group.start_soon(run)
                    await wait_until(lambda: arm.guard.motion_status().progress > 0.1, what="motion started")
                # the client context has exited while the call was running
        await wait_until(lambda: not arm.guard.motion_status().executing, what="execution ended")
        await wait_until(
            lambda: any(r["event"] == "execution_interrupted" for r in records_of(arm.audit_path)),
            what="interruption audited",
        )
        async with arm.client(mode) as observer:
            await assert_arm_still(observer)
            assert await tcp_z(observer) > DOWN_TARGET_Z + 0.01
            assert (await motion(observer))["last_result"]["status"] == "aborted"


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_estop_from_a_second_client_stops_an_execution_started_by_the_first(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, speedup=1.0) as arm, arm.client(mode, approve()) as mover, \
            arm.client(mode) as other:
        summary = await plan_down(mover)
        async with executing(arm, mover, summary["plan_id"], past=0.1) as outcome:
            stop = await other.call_tool("estop", {"reason": "person entered the cell"})
            assert not stop.is_error and stop.structured_content["estopped"] is True

        result = outcome["result"]
        if result.is_error:
            assert "REFUSED" in text_of(result)
        else:
            assert result.structured_content["status"] == "aborted"
        assert (await safety(mover))["estopped"] is True
        await assert_arm_still(other)
        assert await tcp_z(other) > DOWN_TARGET_Z + 0.01
        assert not arm.guard.motion_status().executing


# ------------------------------------------------------------------ progress, dry run, failing stop
@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_progress_notifications_stream_increasing_fractions_while_moving(tmp_path, mode) -> None:
    seen: list[tuple[float, float | None]] = []

    async def on_progress(progress: float, total: float | None, message: str | None) -> None:
        seen.append((progress, total))

    async with arm_harness(tmp_path, speedup=2.0) as arm, arm.client(mode, approve()) as client:
        summary = await plan_down(client)
        done = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]}, progress_callback=on_progress)
        assert not done.is_error and done.structured_content["status"] == "succeeded"

    values = [p for p, _ in seen]
    assert len(values) >= 2, seen
    assert all(0.0 <= v <= 1.0 and math.isfinite(v) for v in values)
    assert all(b > a for a, b in itertools.pairwise(values)), values
    assert all(total == 1.0 for _, total in seen)


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_dry_run_validates_and_approves_but_nothing_actuates(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, policy_with(dry_run=True)) as arm, arm.client(mode, approve()) as client:
        before = (await client.call_tool("get_robot_state", {})).structured_content["joint_positions"]
        summary = await plan_down(client, z=0.40)
        assert any("dry run" in note for note in summary["notes"])
        done = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
        assert not done.is_error, text_of(done)
        assert done.structured_content["status"] == "dry_run"
        assert arm.actuations == []
        after = await assert_arm_still(client)
        assert after == before
        assert (await safety(client))["dry_run"] is True


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_a_backend_that_fails_mid_motion_is_a_backend_fault_with_the_estop_latched(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, speedup=1.0) as arm, arm.client(mode, approve()) as client:
        summary = await plan_down(client, z=0.40)

        def crash(_q):
            raise RuntimeError("injected: servo loop crash")

        async with executing(arm, client, summary["plan_id"]) as outcome:
            arm.fake._compute_tcp = crash  # the control thread dies on its next tick

        result = outcome["result"]
        assert result.is_error and "BACKEND_FAULT" in text_of(result) and "reset_estop" in text_of(result)
        # latched for the fault; the stop sent with it cannot be confirmed by a dead servo loop,
        # so a second latch says the stop failed too (the human is told to use the hardware e-stop)
        assert arm.guard.latch.is_latched
        assert any("stop during e-stop" in fault for fault in arm.guard.faults)
        assert arm.actuations == ["execute"]


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_a_force_violation_while_stops_fail_still_reports_force_limit_and_latches_stop_failed(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, table_height_m=TABLE_Z, speedup=2.0) as arm, arm.client(mode, approve()) as client:
        summary = await plan_down(client)
        arm.fake.fail_stop = True  # the stop the force monitor sends is lost
        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
        arm.fake.fail_stop = False  # let the harness close the backend cleanly
        assert result.is_error and "FORCE_LIMIT" in text_of(result), text_of(result)
        event = arm.guard.latch.current_event
        assert event is not None and event.source == "stop_failed"
        assert arm.guard.force_violation_latched
        assert any("failed" in fault for fault in arm.guard.faults)
        assert arm.guard.last_result is not None and arm.guard.last_result.status == "aborted"


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_a_failed_stop_is_audited_without_claiming_the_arm_was_still(tmp_path, mode) -> None:
    async with arm_harness(tmp_path) as arm, arm.client(mode, approve()) as client:
        assert not (await client.call_tool("stop_motion", {})).is_error  # a working stop first
        arm.fake.fail_stop = True
        assert (await client.call_tool("stop_motion", {})).is_error
        arm.fake.fail_stop = False
        timings = [r["extra"]["stop_timing_ms"] for r in records_of(arm.audit_path)
                   if r.get("tool") == "stop_motion"]
        assert "still_after_receipt" in timings[0]
        assert timings[1]["issued_after_receipt"] >= 0 and "still_after_receipt" not in timings[1]


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_a_stop_that_fails_latches_the_estop_and_reports_stop_failed(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, fail_stop=True) as arm, arm.client(mode, approve()) as client:
        earlier = await plan_down(client, z=0.40)
        result = await client.call_tool("stop_motion", {})
        assert result.is_error
        assert "STOP_FAILED" in text_of(result) and "hardware e-stop" in text_of(result)
        status = await safety(client)
        assert status["estopped"] is True
        assert status["estop_event"]["source"] == "stop_failed"
        assert status["faults"]
        again = await client.call_tool("execute_plan", {"plan_id": earlier["plan_id"]})
        assert again.is_error
        assert arm.actuations == []
        arm.fake.fail_stop = False  # let the harness close the backend cleanly


# ------------------------------------------------------------------ a client that went away (HTTP, see transport/abandoned.py)
@pytest.mark.anyio
async def test_an_abandoned_call_whose_cancellation_failed_stops_only_the_motion_it_started(tmp_path) -> None:
    async with arm_harness(tmp_path, speedup=1.0) as arm, arm.client("2026-07-28", approve()) as client:
        summary = await plan_down(client, z=0.40)
        async with executing(arm, client, summary["plan_id"]) as outcome:
            await arm.guard.abandoned_call("execute_plan", {"plan_id": "plan_someone_else"}, 3, cancelled=False)
            await arm.guard.abandoned_call("gripper_move", {}, 4, cancelled=False)  # no gripper action runs
            await arm.guard.abandoned_call("execute_plan", {"plan_id": summary["plan_id"]}, 5, cancelled=True)
            await arm.guard.abandoned_call("execute_plan", {"plan_id": summary["plan_id"]}, 6, cancelled=None)
            assert arm.guard.motion_status().executing  # none of those stopped this motion
            await arm.guard.abandoned_call("execute_plan", {"plan_id": summary["plan_id"]}, 7, cancelled=False,
                                           principal="alice")

        assert outcome["result"].structured_content["status"] == "aborted"
        await assert_arm_still(client)
        assert not arm.guard.latch.is_latched
        gone = [(r["principal"], r["outcome"]) for r in records_of(arm.audit_path) if r["event"] == "client_disconnected"]
        assert gone == [(None, "nothing_running"), (None, "nothing_running"), (None, "cancelled"),
                        (None, "ended_with_request"), ("alice", "stopped")]


# ------------------------------------------------------------------ force at the very end; audit before motion
@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_a_force_limit_crossed_after_the_last_poll_still_aborts_and_latches(tmp_path, mode) -> None:
    # a stiff surface reached in the last millimetre: the force passes the limit only at the end
    async with arm_harness(tmp_path, speedup=1.0, table_stiffness_n_per_m=200_000.0) as arm, \
            arm.client(mode, approve()) as client:
        target = await tcp_z(client) - 0.02
        arm.fake.table_height_m = target + 0.00023
        summary = await plan_down(client, z=target)
        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
        assert result.is_error and "FORCE_LIMIT" in text_of(result), text_of(result)
        assert (await safety(client))["estopped"] is True
        assert arm.guard.last_result is not None and arm.guard.last_result.status == "aborted"


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_nothing_moves_while_the_audit_log_cannot_be_written(tmp_path, mode, caplog) -> None:
    with caplog.at_level(logging.INFO, logger="armwarden.server.registration"):
        async with arm_harness(tmp_path) as arm, arm.client(mode, approve()) as client:
            summary = await plan_down(client, z=0.40)
            arm.audit._broken = "injected: no space left on device"
            # each call is refused; the record of that refusal cannot be written either, so the
            # client gets a protocol error instead of an unaudited answer
            with pytest.raises(MCPError):
                await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
            with pytest.raises(MCPError):
                await client.call_tool("gripper_move", {"width_m": 0.02})
            assert arm.actuations == []
            arm.audit._broken = None  # let the harness verify and close the log
    refusals = [r.getMessage().split(":")[0] for r in caplog.records if " refused [" in r.getMessage()]
    assert refusals == ["execute_plan refused [AUDIT_UNAVAILABLE]", "gripper_move refused [AUDIT_UNAVAILABLE]"]


@pytest.mark.anyio
async def test_an_execution_is_on_disk_before_the_arm_moves(tmp_path) -> None:
    async with arm_harness(tmp_path) as arm, arm.client("legacy", approve("alice")) as client:
        summary = await plan_down(client, z=0.40)
        moved_at_record: list[int] = []
        execute = arm.fake.execute

        async def execute_and_note(*args: Any, **kwargs: Any) -> Any:
            moved_at_record.append(arm.audit.last_seq)
            return await execute(*args, **kwargs)

        arm.fake.execute = execute_and_note
        assert not (await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})).is_error
        records = records_of(arm.audit_path)
        started = [r for r in records if r["event"] == "execution_started"]
        assert [r["arguments"] for r in started] == [{"plan_id": summary["plan_id"]}]
        assert moved_at_record == [started[0]["seq"]]  # the record was the last one written when motion began


@pytest.mark.anyio
async def test_a_later_estop_does_not_hide_a_force_violation_from_the_human_who_releases_both(tmp_path) -> None:
    human = approve("bob")
    async with arm_harness(tmp_path) as arm, arm.client("legacy", human) as client:
        # what the force monitor does when the limit is crossed ...
        await arm.guard.emergency_stop("force monitor: 95.0 N > 30 N", source="force_monitor",
                                       force={"detail": "contact force 95.0 N above the 30 N limit"})
        # ... then the agent's own e-stop on top, with a soothing reason
        assert not (await client.call_tool("estop", {"reason": "routine pause, nothing happened"})).is_error
        reset = await client.call_tool("reset_estop", {})
    assert not reset.is_error, text_of(reset)
    (prompt,) = human.prompts
    assert "#2" in prompt
    assert "#1, force_monitor at" in prompt
    assert "Force violation (#1)" in prompt and "contact force 95.0 N above the 30 N limit" in prompt
