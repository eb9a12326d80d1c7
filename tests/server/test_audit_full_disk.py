"""A full audit disk, end to end through the SDK client (issue 24, item 2).

The audit log's disk fills up (`tests.fulldisk.SmallDisk`: every write fails with ENOSPC). Then:
an e-stop is never released unrecorded — a reset whose record cannot be written does not take
effect and the human is told so; a stop or an e-stop still takes effect and says, as a success,
that its record could not be written; `get_safety_status` answers and says the log is unusable;
the stop channel still latches and stops the arm.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from pathlib import Path
from typing import Any

import anyio
import pytest

from armwarden.approval.plans import PlanRefusal
from armwarden.core.errors import RefusalCode, SafetyRefusal
from armwarden.stopchannel import StopChannel
from armwarden.stopchannel.external import ExternalStops
from tests.fulldisk import SmallDisk
from tests.helpers import records_of, text_of
from tests.server.harness import MODES, approve, arm_harness, plan_down, wait_until
from tests.stopchannel.conftest import TOKENS, post

pytestmark = pytest.mark.anyio

ENOSPC_TEXT = "No space left on device"


async def estop(client: Any, reason: str = "inspecting the gripper") -> dict[str, Any]:
    result = await client.call_tool("estop", {"reason": reason})
    assert not result.is_error, text_of(result)
    return result.structured_content


async def safety(client: Any) -> dict[str, Any]:
    result = await client.call_tool("get_safety_status", {})
    assert not result.is_error, text_of(result)
    return result.structured_content


def released_in(path: Path) -> list[dict[str, Any]]:
    """The records of releases, and of reset calls that answered ok."""
    return [r for r in records_of(path)
            if r["event"] == "estop_release" or (r["tool"] == "reset_estop" and r["outcome"] == "ok")]


# ------------------------------------------------------------------ reset_estop
@pytest.mark.parametrize("mode", MODES)
async def test_a_reset_on_a_full_audit_disk_leaves_the_estop_latched_and_says_it_was_not_applied(tmp_path, mode) -> None:
    disk = SmallDisk()
    async with arm_harness(tmp_path, audit_disk=disk) as arm, arm.client(mode, approve("erin")) as client:
        number = (await estop(client))["estop_event"]["number"]
        disk.fill()
        reset = await client.call_tool("reset_estop", {})
        assert reset.is_error, text_of(reset)
        text = text_of(reset)
        assert RefusalCode.AUDIT_UNAVAILABLE.value in text and "stays latched" in text and "nothing was released" in text, text
        assert ENOSPC_TEXT in text
        latched = arm.guard.latch.current_event
        assert latched is not None and latched.number == number
        status = await safety(client)
        assert status["estopped"] is True and status["audit_ok"] is False
    assert released_in(arm.audit_path) == []


async def test_a_reset_is_not_put_to_a_human_while_the_audit_log_is_unusable(tmp_path) -> None:
    disk = SmallDisk()
    human = approve("erin")
    async with arm_harness(tmp_path, audit_disk=disk) as arm, arm.client("legacy", human) as client:
        await estop(client)
        disk.fill()
        await estop(client, "again")  # its record fails: the log is now unusable
        reset = await client.call_tool("reset_estop", {})
        assert reset.is_error and RefusalCode.AUDIT_UNAVAILABLE.value in text_of(reset), text_of(reset)
        assert arm.guard.latch.is_latched
    assert human.prompts == []  # type: ignore[attr-defined]  # nobody is asked to approve what cannot be done


async def test_a_reset_is_on_disk_before_the_estop_is_released(tmp_path) -> None:
    async with arm_harness(tmp_path) as arm, arm.client("legacy", approve("erin")) as client:
        number = (await estop(client))["estop_event"]["number"]
        on_disk_at_release: list[list[dict[str, Any]]] = []
        release = arm.guard.latch.release

        def note_then_release(event_number: object):
            on_disk_at_release.append(released_in(arm.audit_path))
            return release(event_number)

        arm.guard.latch.release = note_then_release  # type: ignore[method-assign]
        reset = await client.call_tool("reset_estop", {})
        assert not reset.is_error, text_of(reset)
        assert not arm.guard.latch.is_latched
    ((record,),) = on_disk_at_release
    assert record["event"] == "estop_release" and record["operator"] == "erin"
    assert record["extra"]["estop_event"] == number


async def test_a_console_reset_on_a_full_audit_disk_leaves_the_estop_latched(tmp_path) -> None:
    disk = SmallDisk()
    async with arm_harness(tmp_path, audit_disk=disk) as arm, arm.client() as client:
        number = (await estop(client))["estop_event"]["number"]
        disk.fill()
        with pytest.raises(SafetyRefusal) as refused:
            await arm.guard.reset_estop_typed(str(number), operator="op")
        assert refused.value.code is RefusalCode.AUDIT_UNAVAILABLE and ENOSPC_TEXT in str(refused.value)
        assert arm.guard.latch.is_latched
    assert released_in(arm.audit_path) == []


# ------------------------------------------------------------------ estop, stop_motion, get_safety_status
@pytest.mark.parametrize("mode", MODES)
async def test_an_estop_on_a_full_audit_disk_latches_and_answers_success_with_the_warning(tmp_path, mode) -> None:
    disk = SmallDisk()
    async with arm_harness(tmp_path, audit_disk=disk) as arm, arm.client(mode, approve()) as client:
        plan = await plan_down(client, z=0.40)
        disk.fill()
        result = await client.call_tool("estop", {"reason": "smoke"})
        assert not result.is_error, text_of(result)
        answer = result.structured_content
        assert answer["estopped"] is True and ENOSPC_TEXT in answer["audit_error"]
        number = answer["estop_event"]["number"]
        assert f"e-stop #{number} is latched and in force" in text_of(result)
        assert "audit record could not be written" in text_of(result)
        assert arm.guard.latch.is_latched and arm.backend.emergency_stops == 1
        voided = arm.guard.plans.peek(plan["plan_id"])
        assert isinstance(voided, PlanRefusal) and voided.code is RefusalCode.INVALIDATED_PLAN


@pytest.mark.parametrize("mode", MODES)
async def test_get_safety_status_on_a_full_audit_disk_answers_that_the_audit_log_is_unusable(tmp_path, mode) -> None:
    disk = SmallDisk()
    async with arm_harness(tmp_path, audit_disk=disk) as arm, arm.client(mode) as client:
        healthy = await safety(client)
        assert healthy["audit_ok"] is True and healthy["audit_error"] is None
        disk.fill()
        await estop(client)  # its record is the first that does not fit
        status = await safety(client)
        assert status["estopped"] is True
        assert status["audit_ok"] is False and ENOSPC_TEXT in status["audit_error"]
        assert str(arm.audit_path) in status["audit_error"]


async def test_stop_motion_on_a_full_audit_disk_stops_the_arm_and_says_its_record_could_not_be_written(tmp_path) -> None:
    disk = SmallDisk()
    async with arm_harness(tmp_path, audit_disk=disk, speedup=0.5) as arm, arm.client("legacy", approve()) as client:
        plan = await plan_down(client, z=0.35)
        result: Any = None
        async with anyio.create_task_group() as group:
            async def run() -> None:
                with contextlib.suppress(Exception):  # its own record cannot be written either
                    await client.call_tool("execute_plan", {"plan_id": plan["plan_id"]})

            group.start_soon(run)
            await wait_until(lambda: arm.guard.motion_status().progress > 0.05, what="motion started")
            disk.fill()
            result = await client.call_tool("stop_motion", {})
        assert not result.is_error, text_of(result)
        assert result.structured_content["stopped"] is True
        assert ENOSPC_TEXT in result.structured_content["audit_error"]
        assert "the stop was commanded" in text_of(result) and "audit record could not be written" in text_of(result)
        assert arm.backend.stops >= 1 and not arm.guard.motion_status().executing
        assert (await arm.inner.read_joint_state()).velocities.tolist() == [0.0] * 7


# ------------------------------------------------------------------ the independent stop channel
async def test_the_stop_channel_on_a_full_audit_disk_latches_stops_and_logs_the_lost_record(tmp_path, caplog) -> None:
    disk = SmallDisk()
    async with arm_harness(tmp_path, audit_disk=disk) as arm:
        external = ExternalStops(arm.guard.stopper, arm.audit, asyncio.get_running_loop())
        channel = StopChannel(authenticate=TOKENS.get, latch_and_stop=external.latch_and_stop_for("stop_channel"),
                              on_event=external.record).start()
        try:
            disk.fill()
            with caplog.at_level(logging.ERROR, logger="armwarden.audit"):
                status, _, answer = await anyio.to_thread.run_sync(lambda: post(channel.port, b"full disk"))
                assert status == 200 and answer["estopped"] is True, answer
                assert arm.guard.latch.is_latched and arm.backend.emergency_stops == 1
                await wait_until(lambda: arm.audit.unusable is not None, what="the record refused")
        finally:
            channel.close()
    assert any(ENOSPC_TEXT in r.getMessage() for r in caplog.records)
    assert all(r["event"] != "estop" for r in records_of(arm.audit_path))
