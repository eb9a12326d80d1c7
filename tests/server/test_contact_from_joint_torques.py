"""An arm without a force/torque sensor, through the whole server: the bundled policy monitors its
contact from the joint torques its motors measure; a push on the forearm mid-motion stops the arm,
latches the e-stop and is audited with the joint that saw it."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports]
import pytest

from tests.helpers import records_of, text_of
from tests.server.harness import HOME_TCP_X, ArmHarness, approve, arm_harness, policy_with, wait_until

pytestmark = pytest.mark.anyio

#: the forearm link (its frame sits at the wrist end, on joint 5's axis)
FOREARM = "fr3_link5"
PUSH_N = (0.0, 30.0, 0.0)  # sideways, base frame


async def plan_down(client: Any, z: float = 0.30) -> dict[str, Any]:
    result = await client.call_tool("plan_to_pose", {"position": {"x": HOME_TCP_X, "y": 0.0, "z": z}})
    assert not result.is_error, text_of(result)
    return result.structured_content


def push_once_past(arm: ArmHarness, fraction: float, link: str = FOREARM,
                   force_n: tuple[float, float, float] = PUSH_N) -> None:
    """Push on `link` from the first progress report past `fraction` of the motion on (the
    push stays: the monitor's last sample after the motion sees it even if the motion ended)."""
    fake = arm.fake
    execute = fake.execute
    pushed = False

    async def execute_and_push(trajectory: Any, progress: Callable[[float], None], **kwargs: Any) -> Any:
        def on_progress(done: float) -> None:
            nonlocal pushed
            if done >= fraction and not pushed:
                fake.push(link, force_n)
                pushed = True
            progress(done)
        return await execute(trajectory, on_progress, **kwargs)

    fake.execute = execute_and_push  # type: ignore[method-assign]


async def test_an_arm_without_a_sensor_is_monitored_through_its_joint_torques(tmp_path) -> None:
    async with arm_harness(tmp_path, wrench=False) as arm, arm.client("legacy", approve()) as client:
        summary = await plan_down(client)
        assert summary["force_monitoring"] is True, summary["notes"]

        done = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})

        assert not done.is_error, text_of(done)
        report = done.structured_content
        assert report["status"] == "succeeded"
        assert report["max_observed_force_n"] < 5.0  # nothing touched it: the estimate stays near zero
        assert len(report["max_external_torques_nm"]) == 7 and max(report["max_external_torques_nm"]) < 2.0


async def test_a_push_on_the_forearm_mid_motion_stops_the_arm_and_latches_the_estop(tmp_path) -> None:
    async with arm_harness(tmp_path, wrench=False) as arm, arm.client("legacy", approve()) as client:
        summary = await plan_down(client)
        push_once_past(arm, 0.3)

        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})

        assert result.is_error and "[FORCE_LIMIT]" in text_of(result), text_of(result)
        assert "estimated from the motors' torques" in text_of(result)
        event = arm.guard.latch.current_event
        assert event is not None and event.source == "force_monitor"
        assert event.force_violation is not None and event.force_violation["kind"] == "joint_torque_limit"
        refusals = [r for r in records_of(arm.audit_path) if r["event"] == "tool_call" and r["tool"] == "execute_plan"]
        assert "estimated from the motors' torques" in refusals[-1]["detail"]  # the audit says which joint, how much


async def test_the_push_that_stops_the_arm_is_what_the_forearm_lever_predicts(tmp_path) -> None:
    """The joint the violation names carries the push's torque Jᵀ F (the observer is not guessing)."""
    async with arm_harness(tmp_path, wrench=False) as arm, arm.client("legacy", approve()) as client:
        summary = await plan_down(client)
        push_once_past(arm, 0.0)
        await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
        event = arm.guard.latch.current_event
        assert event is not None and event.force_violation is not None
        measured = np.array(event.force_violation["external_torques_nm"])
        model = arm.guard.robot.model
        data = model.createData()
        state = await arm.inner.read_joint_state()
        frame = model.getFrameId(FOREARM)
        jacobian = pin.computeFrameJacobian(model, data, state.positions, frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        expected = jacobian[:3].T @ np.array(PUSH_N)
        section = arm.guard.policy.force.joint_torques
        assert section is not None
        limits = np.array(list(section.max_external_torque_nm.values()))
        worst = int(np.argmax(np.abs(expected) / limits))
        assert np.sign(measured[worst]) == np.sign(expected[worst])
        assert abs(measured[worst]) > limits[worst]


async def test_an_estimated_tcp_force_over_its_own_limit_stops_below_the_sensors_limit(tmp_path) -> None:
    """25 N at the hand: under max_contact_force_n (30 N, a sensor's limit) but over the estimate's
    own max_tcp_force_n (20 N); the joints' limits are raised so only the TCP estimate can stop it."""
    policy = policy_with(**{"force.joint_torques.max_external_torque_nm": {f"fr3_joint{j}": 50.0 for j in range(1, 8)},
                            "force.joint_torques.max_tcp_force_n": 20.0})
    assert (policy.force.max_contact_force_n, policy.force.estimated_force_limit_n) == (30.0, 20.0)
    async with arm_harness(tmp_path, policy, wrench=False) as arm, arm.client("legacy", approve()) as client:
        summary = await plan_down(client)
        push_once_past(arm, 0.3, link=arm.guard.robot.tcp_frame, force_n=(0.0, 0.0, 25.0))

        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})

        assert result.is_error and "[FORCE_LIMIT]" in text_of(result), text_of(result)
        event = arm.guard.latch.current_event
        assert event is not None and event.force_violation is not None
        assert event.force_violation["kind"] == "force_limit"
        assert "estimated from the motors' torques" in event.force_violation["detail"]
        assert "the limit of 20 N" in event.force_violation["detail"]


async def test_the_operator_is_told_the_estimated_forces_own_limit(tmp_path) -> None:
    operator = approve()
    policy = policy_with(**{"approval.mode": "always", "force.joint_torques.max_tcp_force_n": 20.0})
    async with arm_harness(tmp_path, policy, wrench=False) as arm, arm.client("legacy", operator) as client:
        summary = await plan_down(client)
        done = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
        assert not done.is_error, text_of(done)
    prompts: list[str] = operator.prompts  # type: ignore[attr-defined]
    assert any("stops above 30 N" in p and "(20 N estimated from the joint torques)" in p for p in prompts), prompts


async def test_a_policy_without_joint_torque_limits_refuses_an_arm_without_a_sensor(tmp_path) -> None:
    policy = policy_with(**{"force.joint_torques": None})
    async with arm_harness(tmp_path, policy, wrench=False) as arm, arm.client("legacy", approve()) as client:
        summary = await plan_down(client)
        assert summary["force_monitoring"] is False

        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})

        assert result.is_error and "[NO_WRENCH]" in text_of(result)
        assert arm.actuations == []


async def test_torques_that_read_nan_before_the_motion_refuse_it_and_nothing_moves(tmp_path) -> None:
    async with arm_harness(tmp_path, wrench=False) as arm, arm.client("legacy", approve()) as client:
        summary = await plan_down(client)
        arm.fake.nan_joint_torques = True
        def nan_published() -> bool:
            efforts = arm.fake._latest_joint_state().efforts
            return efforts is not None and bool(np.isnan(efforts).any())

        await wait_until(nan_published, what="a published state with NaN torques")

        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})

        assert result.is_error and "[NO_WRENCH]" in text_of(result), text_of(result)
        assert arm.fake.actuation_commands == 0


async def test_torques_that_turn_nan_mid_motion_stop_the_arm_as_a_lost_wrench_does(tmp_path) -> None:
    async with arm_harness(tmp_path, wrench=False) as arm, arm.client("legacy", approve()) as client:
        summary = await plan_down(client)
        fake = arm.fake
        execute = fake.execute

        async def execute_then_lose_torques(trajectory: Any, progress: Callable[[float], None], **kwargs: Any) -> Any:
            def on_progress(done: float) -> None:
                if done >= 0.3:
                    fake.nan_joint_torques = True
                progress(done)
            return await execute(trajectory, on_progress, **kwargs)

        fake.execute = execute_then_lose_torques  # type: ignore[method-assign]
        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})

        assert result.is_error and "[FORCE_LIMIT]" in text_of(result), text_of(result)
        event = arm.guard.latch.current_event
        assert event is not None and event.source == "wrench_lost"  # no contact was measured: none is latched


async def test_a_free_motion_at_a_speedup_the_observer_cannot_follow_is_refused_before_it_moves(tmp_path) -> None:
    async with arm_harness(tmp_path, wrench=False, speedup=50.0) as arm, arm.client("legacy", approve()) as client:
        summary = await plan_down(client)
        assert summary["force_monitoring"] is False  # the plan says so before anyone approves it
        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
        assert result.is_error and "[NO_WRENCH]" in text_of(result), text_of(result)
        assert "at speedup 50" in text_of(result) and "lower the speedup" in text_of(result)
        assert arm.actuations == []
