"""The Guard's flows run their gates in a fixed order over one state record (`guard/gates.py`),
tested here without MCP: each flow is built on a copy of the state with one thing broken, and the
first gate in its order says no, with nothing moved."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from armwarden.core.errors import RefusalCode, SafetyRefusal
from armwarden.guard.actions import ControlActions
from armwarden.guard.gripper import GripperFlow
from armwarden.guard.planning import PlanningFlow
from armwarden.policy import RATE_LIMIT_EXEMPT_TOOLS
from tests.guard.states import with_broken_log
from tests.server.harness import arm_harness, policy_with

pytestmark = pytest.mark.anyio

async def test_a_gripper_action_is_refused_for_the_log_before_the_latch_is_looked_at(tmp_path: Path) -> None:
    async with arm_harness(tmp_path) as arm:
        arm.guard.latch.latch("test", "estop")
        flow = GripperFlow(with_broken_log(arm.guard.state))
        with pytest.raises(SafetyRefusal) as refused:
            await flow.run("gripper_move", 0.04, None, None, 0.005, 0.005)
    assert refused.value.code is RefusalCode.AUDIT_UNAVAILABLE
    assert arm.actuations == []


async def test_a_gripper_action_with_good_arguments_is_refused_while_the_estop_is_latched(tmp_path: Path) -> None:
    async with arm_harness(tmp_path) as arm:
        arm.guard.latch.latch("test", "estop")
        with pytest.raises(SafetyRefusal) as refused:
            await GripperFlow(arm.guard.state).run("gripper_move", 0.04, None, None, 0.005, 0.005)
    assert refused.value.code is RefusalCode.ESTOPPED
    assert arm.actuations == []


async def test_a_gripper_action_is_refused_for_the_latch_before_its_arguments_are_read(tmp_path: Path) -> None:
    async with arm_harness(tmp_path) as arm:
        arm.guard.latch.latch("test", "estop")
        with pytest.raises(SafetyRefusal) as refused:
            await GripperFlow(arm.guard.state).run("gripper_grasp", 0.04, 500.0, None, 0.005, 0.005)
    assert refused.value.code is RefusalCode.ESTOPPED


async def test_a_control_action_outside_the_policy_is_refused_for_its_arguments_before_the_log_is_asked(
        tmp_path: Path) -> None:
    async with arm_harness(tmp_path, policy_with(**{"approval.mode": "never"})) as arm:
        actions = ControlActions(with_broken_log(arm.guard.state))
        with pytest.raises(SafetyRefusal) as refused:
            await actions.run("set_collision_thresholds", None, None, {"force_n": 500.0, "torque_nm": 5.0})
    assert refused.value.code is RefusalCode.OUT_OF_RANGE
    assert arm.actuations == []


async def test_a_control_action_within_the_policy_is_refused_when_it_could_not_be_recorded(tmp_path: Path) -> None:
    async with arm_harness(tmp_path, policy_with(**{"approval.mode": "never"})) as arm:
        actions = ControlActions(with_broken_log(arm.guard.state))
        with pytest.raises(SafetyRefusal) as refused:
            await actions.run("set_collision_thresholds", None, None, {"force_n": 20.0, "torque_nm": 5.0})
    assert refused.value.code is RefusalCode.AUDIT_UNAVAILABLE
    assert arm.actuations == []


async def test_planning_is_refused_while_the_estop_is_latched_and_stores_no_plan(tmp_path: Path) -> None:
    async with arm_harness(tmp_path) as arm:
        arm.guard.latch.latch("test", "estop")
        home = np.asarray(arm.guard.policy.robot.home_joint_positions, dtype=float)
        with pytest.raises(SafetyRefusal) as refused:
            await PlanningFlow(arm.guard.state, None).plan("joints", {"joint_positions": home})
        stored = len(arm.guard.plans)
    assert refused.value.code is RefusalCode.ESTOPPED
    assert stored == 0


async def test_a_plan_with_a_hard_finding_is_the_last_violation_the_status_reports(tmp_path: Path) -> None:
    async with arm_harness(tmp_path) as arm:
        beyond = np.asarray(arm.guard.policy.robot.home_joint_positions, dtype=float)
        beyond[0] += 1.6  # more than the policy's 1.5 rad step
        summary, _ = await arm.guard.plan("joints", {"joint_positions": beyond})
        status = arm.guard.safety_status()
    assert summary.status == "rejected"
    assert status.last_violation is not None and status.last_violation.code == summary.violations[0].code


async def test_a_flooded_tool_is_rate_limited_but_the_stopping_tools_never_are(tmp_path: Path) -> None:
    async with arm_harness(tmp_path, policy_with(**{"rate_limits.per_tool": {"plan_to_joints": 2}})) as arm:
        state = arm.guard.state
        state.admit("plan_to_joints")
        state.admit("plan_to_joints")
        with pytest.raises(SafetyRefusal) as refused:
            state.admit("plan_to_joints")
        for _ in range(500):  # far past the global limit too
            for tool in RATE_LIMIT_EXEMPT_TOOLS:
                state.admit(tool)
    assert refused.value.code is RefusalCode.RATE_LIMITED
