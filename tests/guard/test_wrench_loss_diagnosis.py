"""A lost wrench latches the e-stop at once; the backend is asked why only after (issue 24, item 12).

When the force monitor finds no usable wrench mid-motion, the runner asks the backend whether it
is the cause (`Backend.fault_behind_stale_data`): the ROS backend answers only once its joint
states have either moved on or aged past `joint_states.max_age_s`. Found by review of the first
fix: during that window the arm was stopped but nothing was latched, so another client's gripper
action could run. Now the e-stop latches before the question is asked, with a neutral cause (no
force was measured, so no force violation is latched), and the finding is audited when it comes.

The window is made observable deterministically: the fake's diagnosis hook blocks on an event the
test sets, so every scenario looks at the daemon while the question is still open.
"""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from typing import Any

import anyio
import pytest
from mcp import Client

from tests.helpers import records_of, text_of
from tests.server.harness import approve, arm_harness, plan_down, wait_until

pytestmark = pytest.mark.anyio


class HeldDiagnosis:
    """The fake's `_fault_behind_stale_data`, held open until the test answers it."""

    def __init__(self) -> None:
        self.asked = anyio.Event()
        self.answered = anyio.Event()
        self.cause: str | None = None

    async def __call__(self) -> str | None:
        self.asked.set()
        await self.answered.wait()
        return self.cause

    def answer(self, cause: str | None) -> None:
        self.cause = cause
        self.answered.set()


@contextlib.asynccontextmanager
async def wrench_lost_mid_motion(arm: Any, client: Client, monkeypatch: pytest.MonkeyPatch
                                 ) -> AsyncIterator[tuple[HeldDiagnosis, dict[str, Any]]]:
    """`execute_plan` runs; the wrench freezes mid-motion; the body runs while the backend is
    being asked whether it is the cause. After the block, the call's result is in `outcome["result"]`."""
    diagnosis = HeldDiagnosis()
    monkeypatch.setattr(arm.fake, "_fault_behind_stale_data", diagnosis)
    summary = await plan_down(client, z=0.40, status="ok")
    outcome: dict[str, Any] = {}

    async def run() -> None:
        outcome["result"] = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})

    async with anyio.create_task_group() as group:
        group.start_soon(run)
        await wait_until(lambda: arm.guard.motion_status().progress > 0.05, what="motion started")
        arm.fake.freeze_wrench = True
        with anyio.fail_after(10.0):
            await diagnosis.asked.wait()
        try:
            yield diagnosis, outcome
        finally:
            if not diagnosis.answered.is_set():
                diagnosis.answer(None)


def diagnosis_records(arm: Any) -> list[dict[str, Any]]:
    arm.audit.flush()
    return [r for r in records_of(arm.audit_path) if r["event"] == "wrench_loss_diagnosis"]


async def test_a_gripper_action_from_a_second_client_is_refused_while_the_backend_is_diagnosed(
        tmp_path, monkeypatch) -> None:
    async with (arm_harness(tmp_path, speedup=1.0) as arm, arm.client("legacy", approve()) as mover,
                arm.client("legacy", approve()) as other):
        async with wrench_lost_mid_motion(arm, mover, monkeypatch) as (diagnosis, _outcome):
            gripper = await other.call_tool("gripper_move", {"width_m": 0.02})
            diagnosis.answer(None)

        assert gripper.is_error and "[ESTOPPED]" in text_of(gripper), text_of(gripper)
        assert "gripper_move" not in arm.actuations, arm.actuations


async def test_while_the_backend_is_diagnosed_the_estop_holds_a_neutral_cause_not_a_force_violation(
        tmp_path, monkeypatch) -> None:
    async with arm_harness(tmp_path, speedup=1.0) as arm, arm.client("legacy", approve()) as client:
        async with wrench_lost_mid_motion(arm, client, monkeypatch) as (diagnosis, _outcome):
            status = (await client.call_tool("get_safety_status", {})).structured_content
            diagnosis.answer(None)

        assert status["estopped"] and not status["force_violation_latched"], status
        event = status["estop_event"]
        assert event["source"] == "wrench_lost", event
        assert "wrench stream was lost" in event["reason"] and "checking whether the backend failed" in event["reason"]
        assert "FORCE_LIMIT" not in event["reason"], event


async def test_a_backend_found_at_fault_is_answered_as_backend_fault_and_its_diagnosis_audited(
        tmp_path, monkeypatch) -> None:
    cause = "fake backend fault: the cell went silent"
    async with arm_harness(tmp_path, speedup=1.0) as arm, arm.client("legacy", approve()) as client:
        async with wrench_lost_mid_motion(arm, client, monkeypatch) as (diagnosis, outcome):
            diagnosis.answer(cause)

        text = text_of(outcome["result"])
        assert outcome["result"].is_error and "[BACKEND_FAULT]" in text and cause in text, text
        assert "FORCE_LIMIT" not in text, text
        assert arm.guard.latch.current_event is not None and arm.guard.latch.current_event.source == "backend_fault"
        assert not arm.guard.force_violation_latched
        [record] = diagnosis_records(arm)
        assert record["outcome"] == "backend_fault" and cause in record["detail"], record


async def test_a_wrench_lost_alone_is_answered_as_a_wrench_loss_and_its_diagnosis_audited(
        tmp_path, monkeypatch) -> None:
    async with arm_harness(tmp_path, speedup=1.0) as arm, arm.client("legacy", approve()) as client:
        async with wrench_lost_mid_motion(arm, client, monkeypatch) as (diagnosis, outcome):
            diagnosis.answer(None)

        text = text_of(outcome["result"])
        assert outcome["result"].is_error and "[FORCE_LIMIT]" in text and "BACKEND_FAULT" not in text, text
        assert "wrench stream was lost" in text, text
        status = (await client.call_tool("get_safety_status", {})).structured_content
        assert status["estopped"] and not status["force_violation_latched"] and status["faults"] == [], status
        [record] = diagnosis_records(arm)
        assert record["outcome"] == "wrench_only" and "wrench stream alone was lost" in record["detail"], record
