"""A full audit disk, end to end through the SDK client (issue 24, item 2).

The audit log's disk fills up (`tests.fulldisk.SmallDisk`: every write fails with ENOSPC). Then
a stop or an e-stop still takes effect and says, as a success, that its record could not be
written; `get_safety_status` answers and says the log is unusable; the stop channel still
latches and stops the arm.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from typing import Any

import anyio
import pytest

from armwarden.errors import RefusalCode
from armwarden.safety.plans import PlanRefusal
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
            with caplog.at_level(logging.ERROR, logger="armwarden.safety.audit"):
                status, _, answer = await anyio.to_thread.run_sync(lambda: post(channel.port, b"full disk"))
                assert status == 200 and answer["estopped"] is True, answer
                assert arm.guard.latch.is_latched and arm.backend.emergency_stops == 1
                await wait_until(lambda: arm.audit.unusable is not None, what="the record refused")
        finally:
            channel.close()
    assert any(ENOSPC_TEXT in r.getMessage() for r in caplog.records)
    assert all(r["event"] != "estop" for r in records_of(arm.audit_path))
