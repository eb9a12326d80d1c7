"""The Guard's flows refuse in the order `guard/order.py` states: for every combination of broken
gates, the refusal is the first broken gate's, and nothing moves unless no gate is broken. The
call is answered as a tool's is (`ToolBuilder.answer`: the rate limit, then the flow), without MCP."""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import pytest
from mcp.server.mcpserver import AcceptedElicitation, DeclinedElicitation
from mcp_types import CallToolResult

from armwarden.approval.decision import ApprovalForm
from armwarden.core.errors import RefusalCode
from armwarden.guard import order
from armwarden.guard.actions import ControlActions
from armwarden.guard.gripper import GripperFlow
from armwarden.server.calls import ok
from armwarden.server.registration import ToolBuilder
from armwarden.tools import names
from tests.guard.states import with_broken_log
from tests.helpers import text_of
from tests.server.harness import arm_harness, policy_with

pytestmark = pytest.mark.anyio



def refusal_code(result: CallToolResult) -> RefusalCode | None:
    """The code of a refused call's answer (`REFUSED [CODE]: ...`), None for an answer."""
    if not result.is_error:
        return None
    text = text_of(result)
    return RefusalCode(text[text.index("[") + 1:text.index("]")])


def assert_first_broken_gate_answered(result: CallToolResult, actuations: list[str], gates: tuple[order.Gate, ...],
                                      broken: set[order.Gate], actuation: str) -> None:
    """The first broken gate refused and nothing moved; with none broken, the call ran once."""
    first = order.first_refusal(gates, broken)
    if first is None:
        assert refusal_code(result) is None and actuations == [actuation], text_of(result)
    else:
        assert refusal_code(result) in first.refuses, text_of(result)
        assert actuations == []


def test_every_tool_that_changes_the_robot_has_its_gates_stated_and_the_rate_limit_first() -> None:
    changes = names(lambda spec: not spec.hints.read_only and not spec.stops_on_read) | names(lambda spec: spec.plan_kind)
    assert set(order.GATES) == changes
    assert all(gates[0] is order.RATE_LIMIT for gates in order.GATES.values())


GRIPPER_GATES = order.GATES["gripper_move"]


@pytest.mark.parametrize("broken", [set(c) for n in range(len(GRIPPER_GATES) + 1)
                                    for c in itertools.combinations(GRIPPER_GATES, n)],
                         ids=lambda broken: "+".join(sorted(g.name.split()[0] for g in broken)) or "none")
async def test_a_gripper_move_is_refused_by_its_first_broken_gate(tmp_path: Path, broken: set[order.Gate]) -> None:
    policy = policy_with(**{"rate_limits.per_tool": {"gripper_move": 1}})
    async with arm_harness(tmp_path, policy) as arm:
        state = arm.guard.state
        if order.RATE_LIMIT in broken:
            state.admit("gripper_move")  # its one token this minute
        if order.AUDIT_WRITABLE in broken:
            state = with_broken_log(state)
        if order.NOT_ESTOPPED in broken:
            arm.guard.latch.latch("test", "estop")
        flow = GripperFlow(state)
        flow.busy = order.ONE_GRIPPER_ACTION in broken
        width = 1.0 if order.GRIPPER_ARGUMENTS in broken else 0.04  # the hand opens 0..0.08 m

        async def move() -> CallToolResult:
            return ok(await flow.run("gripper_move", width, None, None, 0.005, 0.005))

        result = await ToolBuilder(arm.guard).answer("gripper_move", move)
        assert_first_broken_gate_answered(result, arm.actuations, GRIPPER_GATES, broken, "gripper_move")


ACTION_GATES = order.GATES["set_collision_thresholds"]


@pytest.mark.parametrize("broken", [set(c) for n in range(len(ACTION_GATES) + 1)
                                    for c in itertools.combinations(ACTION_GATES, n)],
                         ids=lambda broken: "+".join(sorted(g.name.split()[0] for g in broken)) or "none")
async def test_a_control_action_is_refused_by_its_first_broken_gate(tmp_path: Path, broken: set[order.Gate]) -> None:
    policy = policy_with(**{"rate_limits.per_tool": {"set_collision_thresholds": 1}, "approval.mode": "always"})
    async with arm_harness(tmp_path, policy) as arm:
        state = arm.guard.state
        if order.RATE_LIMIT in broken:
            state.admit("set_collision_thresholds")
        if order.AUDIT_WRITABLE in broken:
            state = with_broken_log(state)
        if order.NOT_ESTOPPED in broken:
            arm.guard.latch.latch("test", "estop")
        actions = ControlActions(state)
        arguments: dict[str, Any] = {"force_n": 500.0 if order.ACTION_ARGUMENTS in broken else 20.0, "torque_nm": 10.0}
        answer: Any = (DeclinedElicitation() if order.APPROVED in broken else
                       AcceptedElicitation[Any].model_construct(data=ApprovalForm(approve=True, operator="alice")))
        shown = "another request" if order.APPROVED_THIS_REQUEST in broken else \
            actions._bind("set_collision_thresholds", arguments).prompt().digest

        async def act() -> CallToolResult:
            return ok(await actions.run("set_collision_thresholds", answer, shown, arguments))

        result = await ToolBuilder(arm.guard).answer("set_collision_thresholds", act)
        assert_first_broken_gate_answered(result, arm.actuations, ACTION_GATES, broken, "set_collision_thresholds")
