"""End-to-end refusal scenarios through the official MCP SDK client, in both protocol modes.

Every scenario must be refused with an `isError` result that says why, and with zero actuation
commands reaching the backend (the harness's `CountingBackend` counts every actuating call).
Where a scenario needs one legitimate motion first (replay, stale plan, busy slot), the test
asserts that the refused call added nothing to the backend's record.
"""

from __future__ import annotations

import dataclasses
import math
import re
import threading
from typing import Any

import anyio
import numpy as np
import pytest

from armwarden.audit import read_tail, verify_file
from armwarden.safety.estop import REASON_LIMIT
from tests.helpers import HOME, text_of
from tests.server.harness import MODES, answer, approve, arm_harness, policy_with

FAST = 50.0  # fake backend time speed-up for scenarios that move once


# ---------------------------------------------------------------------------------------------- helpers
def assert_refused(result: Any, *codes: str) -> str:
    """isError, and the text names one of `codes` (the reason)."""
    text = text_of(result)
    assert result.is_error, f"expected a refusal, got: {text[:500]}"
    assert any(code in text for code in codes), f"expected one of {codes} in: {text[:500]}"
    return text


def joints(**deltas: float) -> list[float]:
    """The ready pose with joint offsets, e.g. joints(j2=1.4) adds 1.4 rad to fr3_joint2."""
    q = list(HOME)
    for name, delta in deltas.items():
        q[int(name[1:]) - 1] += delta
    return q


def violations(summary: dict) -> list[tuple[str, str, str]]:
    return [(v["code"], v["severity"], v["body"]) for v in summary["violations"]]


async def plan(client: Any, tool: str, arguments: dict) -> dict:
    result = await client.call_tool(tool, arguments)
    assert not result.is_error, text_of(result)
    return result.structured_content


async def plan_joints(client: Any, q: list[float], **extra: Any) -> dict:
    return await plan(client, "plan_to_joints", {"joint_positions": q, **extra})


async def refused_at_execution(arm: Any, client: Any, summary: dict, hard_code: str) -> str:
    """A rejected plan names `hard_code`; executing it is refused and moves nothing."""
    assert summary["status"] == "rejected", summary
    assert (hard_code, "hard") in [(c, s) for c, s, _ in violations(summary)], violations(summary)
    result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
    text = assert_refused(result, "REJECTED_PLAN")
    assert hard_code in text  # the refusal says which limit
    assert arm.actuations == []
    return text


def audit_records(arm: Any, n: int = 200) -> list[dict]:
    arm.audit.flush()  # read-only calls' records are group-committed
    return read_tail(arm.audit_path, n)


mode_param = pytest.mark.parametrize("mode", MODES)


# ---------------------------------------------------------------------------------------------- envelope
@pytest.mark.anyio
@mode_param
async def test_joint_target_past_a_limit_is_refused(tmp_path, mode) -> None:
    ask = approve()
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client(mode, ask) as client:
        summary = await plan_joints(client, joints(j4=-0.744))  # fr3_joint4 to -3.1 < -3.0421
        await refused_at_execution(arm, client, summary, "JOINT_LIMIT")
        assert ask.prompts == []
    assert verify_file(arm.audit_path).ok


@pytest.mark.anyio
@mode_param
async def test_joint_motion_sweeping_the_tcp_out_of_the_workspace_box_is_refused(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client(mode, approve()) as client:
        summary = await plan_joints(client, joints(j2=1.4, j6=0.7))  # TCP dives below the table top
        assert ("WORKSPACE", "hard", "fr3_hand_tcp") in violations(summary)
        await refused_at_execution(arm, client, summary, "WORKSPACE")


@pytest.mark.anyio
@mode_param
async def test_pose_target_inside_a_keep_out_zone_is_refused(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client(mode, approve()) as client:
        summary = await plan(client, "plan_to_pose", {"position": {"x": 0.5, "y": 0.42, "z": 0.40}})  # 'monitor'
        assert ("KEEP_OUT", "hard", "fr3_hand_tcp") in violations(summary)
        text = await refused_at_execution(arm, client, summary, "KEEP_OUT")
        assert "monitor" in text


@pytest.mark.anyio
@mode_param
async def test_cartesian_path_into_a_keep_out_zone_is_refused(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client(mode, approve()) as client:
        summary = await plan(client, "plan_cartesian_path", {"waypoints": [
            {"position": {"x": 0.45, "y": 0.25, "z": 0.40}},
            {"position": {"x": 0.50, "y": 0.42, "z": 0.40}},  # inside 'monitor'
        ]})
        assert ("KEEP_OUT", "hard", "fr3_hand_tcp") in violations(summary)
        await refused_at_execution(arm, client, summary, "KEEP_OUT")


@pytest.mark.anyio
@mode_param
async def test_elbow_sweeping_through_a_keep_out_zone_is_refused_although_the_tcp_stays_clear(tmp_path, mode) -> None:
    # joint 1 from 0 to -1.5 rad swings the elbow (link 4 origin ~(-0.165, 0, 0.615) at ready)
    # through rot_z(-1.2) @ that point; a 6 cm cube there is hit by the links, never by the TCP.
    theta = -1.2
    centre = np.array([-0.165 * math.cos(theta), -0.165 * math.sin(theta), 0.615])
    policy = policy_with(**{"workspace.keep_out": [
        {"name": "shelf", "min": (centre - 0.03).tolist(), "max": (centre + 0.03).tolist()},
    ]})

    async with arm_harness(tmp_path, policy, speedup=FAST) as arm, arm.client(mode, approve()) as client:
        summary = await plan_joints(client, joints(j1=-1.5))
        keep_out_bodies = {body for code, _, body in violations(summary) if code == "KEEP_OUT"}
        assert keep_out_bodies & {"fr3_link3", "fr3_link4"}, violations(summary)
        assert not any(body.startswith(("fr3_hand", "fr3_leftfinger", "fr3_rightfinger")) for body in keep_out_bodies)
        text = await refused_at_execution(arm, client, summary, "KEEP_OUT")
        assert "shelf" in text


@pytest.mark.anyio
@mode_param
async def test_joint_step_over_the_hard_cap_is_refused(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client(mode, approve()) as client:
        summary = await plan_joints(client, joints(j1=1.6))  # max_joint_step_rad 1.5
        assert violations(summary) == [("STEP_TOO_LARGE", "hard", "fr3_joint1")]
        await refused_at_execution(arm, client, summary, "STEP_TOO_LARGE")


@pytest.mark.anyio
@mode_param
async def test_cartesian_path_over_the_length_cap_is_refused(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client(mode, approve()) as client:
        zigzag = [{"position": {"x": 0.40, "y": y, "z": 0.45}} for y in (0.1, -0.1, 0.1, -0.1)]  # ~0.7 m > 0.5 m
        summary = await plan(client, "plan_cartesian_path", {"waypoints": zigzag})
        assert summary["tcp_path_length_m"] > 0.5
        await refused_at_execution(arm, client, summary, "CARTESIAN_STEP_TOO_LARGE")


# ---------------------------------------------------------------------------------------------- plans
@pytest.mark.anyio
@mode_param
async def test_unknown_plan_id_is_refused_without_asking_anyone(tmp_path, mode) -> None:
    ask = approve()
    async with arm_harness(tmp_path, policy_with(**{"approval.mode": "always"}), speedup=FAST) as arm, \
            arm.client(mode, ask) as client:
        for plan_id in ("plan_doesnotexist", "x" * 64, "../../etc/passwd", "plan_\u202e\n"):
            assert_refused(await client.call_tool("execute_plan", {"plan_id": plan_id}), "UNKNOWN_PLAN")
        assert ask.prompts == []
        assert arm.actuations == []
    assert verify_file(arm.audit_path).ok


@pytest.mark.anyio
@mode_param
async def test_replayed_plan_is_refused(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client(mode, approve()) as client:
        summary = await plan_joints(client, joints(j1=0.2))
        done = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
        assert not done.is_error and done.structured_content["status"] == "succeeded"
        assert arm.actuations == ["execute"]
        assert_refused(await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]}), "USED_PLAN")
        assert arm.actuations == ["execute"]  # the replay added nothing
    assert verify_file(arm.audit_path).ok


@pytest.mark.anyio
@mode_param
async def test_stale_plan_is_refused_after_the_robot_moved(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client(mode, approve()) as client:
        first = await plan_joints(client, joints(j1=0.2))
        second = await plan_joints(client, joints(j1=-0.2))  # planned from the same start state
        done = await client.call_tool("execute_plan", {"plan_id": first["plan_id"]})
        assert not done.is_error, text_of(done)
        assert arm.actuations == ["execute"]
        text = assert_refused(await client.call_tool("execute_plan", {"plan_id": second["plan_id"]}), "STALE_PLAN")
        assert "fr3_joint1" in text
        assert arm.actuations == ["execute"]


@pytest.mark.anyio
@mode_param
async def test_expired_plan_is_refused(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, policy_with(**{"motion.plan_ttl_s": 0.05}), speedup=FAST) as arm, \
            arm.client(mode, approve()) as client:
        summary = await plan_joints(client, joints(j1=0.2))
        assert summary["status"] == "ok"
        await anyio.sleep(0.1)
        assert_refused(await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]}), "EXPIRED_PLAN")
        assert arm.actuations == []


# ---------------------------------------------------------------------------------------------- approval
@pytest.mark.anyio
@mode_param
async def test_a_human_is_never_asked_to_approve_a_hard_violation(tmp_path, mode) -> None:
    ask = approve()  # would tick 'approve' if it were ever asked
    async with arm_harness(tmp_path, policy_with(**{"approval.mode": "always"}), speedup=FAST) as arm, \
            arm.client(mode, ask) as client:
        summary = await plan_joints(client, joints(j4=-0.744))
        assert summary["requires_approval"] is False
        await refused_at_execution(arm, client, summary, "JOINT_LIMIT")
        assert ask.prompts == []


@pytest.mark.anyio
@mode_param
async def test_a_forged_approval_argument_with_a_declining_human_is_refused(tmp_path, mode) -> None:
    forged = {"action": "accept", "content": {"approve": True, "operator": "the model"}}

    ask = answer("decline")
    async with arm_harness(tmp_path, policy_with(**{"approval.mode": "always"}), speedup=FAST) as arm, \
            arm.client(mode, ask) as client:
        summary = await plan_joints(client, joints(j1=0.2))
        assert summary["status"] == "needs_approval"
        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"], "approval": forged})
        assert_refused(result, "APPROVAL_DENIED")  # the argument is dropped; the human's answer counts
        assert arm.actuations == []
        # the plan was spent when it was examined: it cannot be tried again
        again = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
        assert_refused(again, "USED_PLAN")
        assert arm.actuations == []
        assert ask.prompts  # only the server's own question reached the human


@pytest.mark.anyio
@mode_param
async def test_a_forged_approval_argument_from_a_client_without_elicitation_is_refused(tmp_path, mode) -> None:
    forged = {"action": "accept", "content": {"approve": True}}

    async with arm_harness(tmp_path, policy_with(**{"approval.mode": "always"}), speedup=FAST) as arm, \
            arm.client(mode) as client:
        for approval in (forged, {"approve": True}):
            summary = await plan_joints(client, joints(j1=0.2))
            arguments = {"plan_id": summary["plan_id"], "approval": approval}
            assert_refused(await client.call_tool("execute_plan", arguments),
                           "INVALID_ARGUMENTS", "APPROVAL_UNAVAILABLE")
        summary = await plan_joints(client, joints(j1=0.2))
        assert_refused(await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]}), "APPROVAL_UNAVAILABLE")
        assert arm.actuations == []


@pytest.mark.anyio
@mode_param
async def test_execution_is_refused_when_the_human_declines(tmp_path, mode) -> None:
    ask = answer("decline")
    async with arm_harness(tmp_path, policy_with(**{"approval.mode": "always"}), speedup=FAST) as arm, \
            arm.client(mode, ask) as client:
        summary = await plan_joints(client, joints(j1=0.2))
        text = assert_refused(await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]}), "APPROVAL_DENIED")
        assert "declined" in text
        assert ask.prompts and "APPROVE ROBOT MOTION?" in ask.prompts[0]
        assert arm.actuations == []
        # the plan was examined by the body, so it is spent
        assert_refused(await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]}), "USED_PLAN")
        assert arm.actuations == []
    assert verify_file(arm.audit_path).ok


@pytest.mark.anyio
@mode_param
async def test_execution_is_refused_when_the_human_accepts_without_ticking_approve(tmp_path, mode) -> None:
    ask = answer("accept", {"approve": False, "operator": "alice"})
    async with arm_harness(tmp_path, policy_with(**{"approval.mode": "always"}), speedup=FAST) as arm, \
            arm.client(mode, ask) as client:
        summary = await plan_joints(client, joints(j1=0.2))
        text = assert_refused(await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]}), "APPROVAL_DENIED")
        assert "approve" in text
        assert ask.prompts
        assert arm.actuations == []


@pytest.mark.anyio
@mode_param
async def test_execution_needing_approval_is_refused_for_a_client_without_elicitation(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, policy_with(**{"approval.mode": "always"}), speedup=FAST) as arm, \
            arm.client(mode) as client:  # no elicitation callback: the client cannot show a prompt
        summary = await plan_joints(client, joints(j1=0.2))
        text = assert_refused(await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]}),
                              "APPROVAL_UNAVAILABLE")
        assert "elicitation" in text
        assert arm.actuations == []


@pytest.mark.anyio
@mode_param
async def test_a_client_without_elicitation_may_run_when_the_policy_allows_it_and_the_result_says_so(tmp_path, mode) -> None:
    policy = policy_with(**{"approval.mode": "always", "approval.on_client_without_elicitation": "allow"})

    async with arm_harness(tmp_path, policy, speedup=FAST) as arm, arm.client(mode) as client:
        summary = await plan_joints(client, joints(j1=0.2))
        done = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
        assert not done.is_error, text_of(done)
        assert done.structured_content["status"] == "succeeded"
        assert done.structured_content["approval"]["via"] == "no_elicitation_client"
        assert arm.actuations == ["execute"]


@pytest.mark.anyio
@mode_param
async def test_reset_estop_always_needs_a_human_even_when_the_policy_allows_clients_without_elicitation(tmp_path, mode) -> None:
    policy = policy_with(**{"approval.on_client_without_elicitation": "allow"})

    async with arm_harness(tmp_path, policy, speedup=FAST) as arm, arm.client(mode) as client:
        assert not (await client.call_tool("estop", {"reason": "test"})).is_error
        assert_refused(await client.call_tool("reset_estop", {}), "APPROVAL_UNAVAILABLE")
        assert (await client.call_tool("get_safety_status", {})).structured_content["estopped"] is True


@pytest.mark.anyio
@mode_param
@pytest.mark.parametrize("content", [{"approve": "true"}, {"approve": "yes"}, {"approve": 1},
                                     {"approve": True, "also": "this"}], ids=["str_true", "str_yes", "int_1", "extra_field"])
async def test_an_approval_answer_that_is_not_exactly_a_boolean_true_does_not_approve(tmp_path, mode, content) -> None:
    async with arm_harness(tmp_path, policy_with(**{"approval.mode": "always"}), speedup=FAST) as arm, \
            arm.client(mode, answer("accept", content)) as client:
        summary = await plan_joints(client, joints(j1=0.2))
        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
        assert result.is_error
        assert arm.actuations == []


@pytest.mark.anyio
async def test_an_action_question_left_open_across_an_estop_and_its_reset_does_not_actuate(tmp_path) -> None:
    async with arm_harness(tmp_path, speedup=FAST) as arm:
        asked, answer_now = anyio.Event(), anyio.Event()

        async def slow_human(context: Any, params: Any) -> Any:
            import mcp_types as types

            asked.set()
            await answer_now.wait()
            return types.ElicitResult(action="accept", content={"approve": True, "operator": "alice"})

        outcome: dict[str, Any] = {}
        async with arm.client("legacy", slow_human) as first, arm.client("legacy", approve("bob")) as second:
            async def change_thresholds() -> None:
                outcome["result"] = await first.call_tool("set_collision_thresholds", {"force_n": 20.0, "torque_nm": 10.0})

            async with anyio.create_task_group() as group:
                group.start_soon(change_thresholds)
                await asked.wait()
                assert not (await second.call_tool("estop", {"reason": "collision"})).is_error
                assert not (await second.call_tool("reset_estop", {})).is_error
                answer_now.set()
        assert_refused(outcome["result"], "APPROVAL_MISMATCH")
        assert arm.actuations == []


@pytest.mark.anyio
async def test_a_replayed_approval_round_does_not_run_an_action_twice(tmp_path) -> None:
    # 2026-07-28: the sealed request state and the human's answer, sent again, ask again instead of acting
    import mcp_types as types
    from mcp_types import InputRequiredResult

    arguments = {"force_n": 20.0, "torque_nm": 10.0}
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client("2026-07-28", answer("decline")) as client:
        first = await client.session.call_tool("set_collision_thresholds", arguments, allow_input_required=True)
        assert isinstance(first, InputRequiredResult)
        key = next(iter(first.input_requests))
        answers = {key: types.ElicitResult(action="accept", content={"approve": True, "operator": "alice"})}
        for attempt in range(3):
            result = await client.session.call_tool("set_collision_thresholds", arguments, input_responses=answers,
                                                    request_state=first.request_state, allow_input_required=True)
            if attempt == 0:
                assert not result.is_error, text_of(result)
            else:
                assert isinstance(result, InputRequiredResult) or result.is_error, result
        assert arm.actuations == ["set_collision_thresholds"]


# ---------------------------------------------------------------------------------------------- concurrency
@pytest.mark.anyio
@mode_param
async def test_two_concurrent_executions_one_runs_and_the_other_is_refused_busy(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, speedup=2.0) as arm, \
            arm.client(mode, approve()) as first, arm.client(mode, approve()) as second:
        a = await plan_joints(first, joints(j1=0.3))
        b = await plan_joints(second, joints(j1=-0.3))  # same start state
        results: dict[str, Any] = {}

        async def execute(name: str, client: Any, plan_id: str) -> None:
            results[name] = await client.call_tool("execute_plan", {"plan_id": plan_id})

        async with anyio.create_task_group() as group:
            group.start_soon(execute, "a", first, a["plan_id"])
            group.start_soon(execute, "b", second, b["plan_id"])
        ok = [name for name, r in results.items() if not r.is_error]
        busy = [name for name, r in results.items() if r.is_error]
        assert len(ok) == 1 and len(busy) == 1, {k: text_of(v)[:200] for k, v in results.items()}
        assert results[ok[0]].structured_content["status"] == "succeeded"
        assert_refused(results[busy[0]], "BUSY")
        assert arm.actuations == ["execute"]
        # BUSY left the other plan usable, but the arm has moved since: it is now stale, not used
        loser = {"a": (first, a), "b": (second, b)}[busy[0]]
        assert_refused(await loser[0].call_tool("execute_plan", {"plan_id": loser[1]["plan_id"]}), "STALE_PLAN")
        assert arm.actuations == ["execute"]
    assert verify_file(arm.audit_path).ok


# ---------------------------------------------------------------------------------------------- e-stop
ESTOPPED_CALLS: list[tuple[str, dict]] = [
    ("plan_to_joints", {"joint_positions": joints(j1=0.2)}),
    ("plan_to_pose", {"position": {"x": 0.4, "y": 0.1, "z": 0.35}}),
    ("plan_cartesian_path", {"waypoints": [{"position": {"x": 0.35, "y": 0.0, "z": 0.45}}]}),
    ("execute_plan", {}),  # plan_id filled in: a plan made before the e-stop
    ("gripper_move", {"width_m": 0.04}),
    ("gripper_grasp", {"width_m": 0.02, "force_n": 20.0}),
    ("gripper_home", {}),
    ("switch_controllers", {"activate": ["joint_impedance_controller"], "deactivate": ["fr3_arm_controller"]}),
    ("set_collision_thresholds", {"force_n": 20.0, "torque_nm": 5.0}),
    ("error_recovery", {}),
]


@pytest.mark.anyio
@mode_param
@pytest.mark.parametrize(("tool", "arguments"), ESTOPPED_CALLS, ids=[tool for tool, _ in ESTOPPED_CALLS])
async def test_motion_gripper_and_control_tools_are_refused_while_estopped(tmp_path, mode, tool, arguments) -> None:
    ask = approve()
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client(mode, ask) as client:
        before = await plan_joints(client, joints(j1=0.2))
        stopped = await client.call_tool("estop", {"reason": "person in the cell"})
        assert not stopped.is_error and stopped.structured_content["estopped"] is True
        call = dict(arguments, plan_id=before["plan_id"]) if tool == "execute_plan" else arguments
        result = await client.call_tool(tool, call)
        text = assert_refused(result, "ESTOPPED", "INVALIDATED_PLAN")
        assert "e-stop" in text
        assert ask.prompts == []  # nobody is asked to approve what the latch refuses
        assert arm.actuations == []
        status = await client.call_tool("get_safety_status", {})
        assert status.structured_content["estopped"] is True


@pytest.mark.anyio
@mode_param
async def test_state_and_safety_status_still_work_while_estopped(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client(mode, approve()) as client:
        await client.call_tool("estop", {"reason": "test"})
        state = await client.call_tool("get_robot_state", {})
        assert not state.is_error and len(state.structured_content["joint_positions"]) == 7
        status = await client.call_tool("get_safety_status", {})
        assert not status.is_error and status.structured_content["estopped"] is True
        assert status.structured_content["estop_event"]["number"] == 1
        assert arm.actuations == []


@pytest.mark.anyio
@mode_param
async def test_reset_is_refused_when_the_human_declines(tmp_path, mode) -> None:
    ask = answer("decline")
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client(mode, ask) as client:
        await client.call_tool("estop", {"reason": "test"})
        assert_refused(await client.call_tool("reset_estop", {}), "APPROVAL_DENIED")
        assert ask.prompts and "#1" in ask.prompts[0]
        status = await client.call_tool("get_safety_status", {})
        assert status.structured_content["estopped"] is True
        assert arm.actuations == []
    assert verify_file(arm.audit_path).ok


@pytest.mark.anyio
@mode_param
async def test_reset_approved_for_an_older_event_while_a_newer_latch_exists_is_refused(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client(mode) as other:
        prompts: list[str] = []

        async def human(context: Any, params: Any) -> Any:
            import mcp_types as types

            prompts.append(params.message)
            if len(prompts) == 1:  # while the human reads about #1, someone else hits e-stop again
                newer = await other.call_tool("estop", {"reason": "second person in the cell"})
                assert newer.structured_content["estop_event"]["number"] == 2
            # this human approves only the event they first looked at (#1), not a question about #2
            approve_it = re.search(r"E-stop event\s*: #1\b", params.message) is not None
            return types.ElicitResult(action="accept" if approve_it else "decline",
                                      content={"approve": approve_it, "operator": "bob"})

        async with arm.client(mode, human) as client:
            await client.call_tool("estop", {"reason": "first"})
            result = await client.call_tool("reset_estop", {})
            assert_refused(result, "RESET_REFUSED", "APPROVAL_DENIED")
            assert "#1" in prompts[0]
            status = await client.call_tool("get_safety_status", {})
            assert status.structured_content["estopped"] is True
            assert status.structured_content["estop_event"]["number"] == 2
        assert arm.actuations == []


class _HeldPlanner:
    """The planning thread's planner, held at the start of `plan_to_pose` until `gate` opens."""

    def __init__(self, planner: Any, gate: threading.Event) -> None:
        self._planner, self._gate = planner, gate

    def __getattr__(self, name: str) -> Any:
        return getattr(self._planner, name)

    def plan_to_pose(self, *args: Any, **kwargs: Any) -> Any:
        self._gate.wait(5.0)
        return self._planner.plan_to_pose(*args, **kwargs)


@pytest.mark.anyio
@mode_param
async def test_a_plan_being_made_when_the_estop_latches_is_discarded_and_cannot_run_after_the_reset(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client(mode, approve("alice")) as client:
        gate = threading.Event()
        arm.guard.state.planning = dataclasses.replace(arm.guard.planning, planner=_HeldPlanner(arm.guard.planning.planner, gate))
        outcome: dict[str, Any] = {}

        async def plan() -> None:
            outcome["plan"] = await client.call_tool("plan_to_pose", {"position": {"x": 0.3069, "y": 0.0, "z": 0.40}})

        async with anyio.create_task_group() as group:
            group.start_soon(plan)
            await anyio.sleep(0.1)  # the planning thread is inside plan_to_pose
            assert not (await client.call_tool("estop", {"reason": "person in the cell"})).is_error
            gate.set()
        assert_refused(outcome["plan"], "ESTOPPED")
        assert not (await client.call_tool("reset_estop", {})).is_error
        assert arm.actuations == []


@pytest.mark.anyio
async def test_a_stored_plan_from_before_an_estop_is_refused_after_the_reset_even_if_it_escaped_invalidation(tmp_path) -> None:
    # belt and braces: the plan store itself refuses a plan made under an older e-stop generation
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client("legacy", approve("alice")) as client:
        summary = await plan_joints(client, joints(j1=0.1))
        stored = arm.guard.plans._plans[summary["plan_id"]]
        assert not (await client.call_tool("estop", {"reason": "test"})).is_error
        assert not (await client.call_tool("reset_estop", {})).is_error
        arm.guard.plans._plans[summary["plan_id"]] = stored  # as if invalidate_all had missed it
        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
        assert_refused(result, "INVALIDATED_PLAN")
        assert arm.actuations == []


MALFORMED_REASONS: list[Any] = [
    "x" * 200_000,
    "line one\nline two\r\n\tthree \u202e\u0000 end",
    42,
    -1e308,
    {"reason": {"nested": ["a", {"b": "c" * 10_000}]}, "n": 1},
    None,
    [[[[[[[[[["deep"]]]]]]]]], list(range(10_000))],
    True,
]


@pytest.mark.anyio
@mode_param
@pytest.mark.parametrize("reason", MALFORMED_REASONS, ids=["huge", "multiline", "int", "float", "dict", "null",
                                                           "nested_list", "bool"])
async def test_malformed_estop_input_still_stops(tmp_path, mode, reason) -> None:
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client(mode) as client:
        result = await client.call_tool("estop", {"reason": reason})
        assert not result.is_error, text_of(result)[:300]
        event = result.structured_content["estop_event"]
        assert "\n" not in event["reason"] and "\r" not in event["reason"]
        assert 0 < len(event["reason"]) <= REASON_LIMIT
        status = await client.call_tool("get_safety_status", {})
        assert status.structured_content["estopped"] is True
        assert status.structured_content["estop_event"]["reason"] == event["reason"]
        assert arm.backend.stops >= 1
        assert arm.actuations == []
    assert verify_file(arm.audit_path).ok


@pytest.mark.anyio
@mode_param
async def test_estop_with_no_or_unexpected_arguments_still_stops(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client(mode) as client:
        for number, arguments in enumerate(({}, {"why": "x"}, {"reason": "r", "severity": [1, 2]}), start=1):
            result = await client.call_tool("estop", arguments)
            assert not result.is_error, text_of(result)
            assert result.structured_content["estop_event"]["number"] == number
        stop = await client.call_tool("stop_motion", {"now": True})
        assert not stop.is_error
        assert arm.actuations == []


# ---------------------------------------------------------------------------------------------- gripper / control / camera
GRIPPER_OVER_LIMITS = [
    ("gripper_grasp", {"width_m": 0.02, "force_n": 80.0}, "force_n"),  # cap 70 N
    ("gripper_grasp", {"width_m": 0.2, "force_n": 20.0}, "width_m"),  # 0..0.08 m
    ("gripper_grasp", {"width_m": 0.02, "force_n": 20.0, "speed_mps": 0.5}, "speed_mps"),  # cap 0.1 m/s
    ("gripper_move", {"width_m": -0.01}, "width_m"),
    ("gripper_move", {"width_m": 0.04, "speed_mps": 1.0}, "speed_mps"),
]


@pytest.mark.anyio
@mode_param
@pytest.mark.parametrize(("tool", "arguments", "field"), GRIPPER_OVER_LIMITS,
                         ids=["grasp_force_over_cap", "grasp_width_out_of_range", "grasp_speed_over_cap",
                              "move_width_negative", "move_speed_over_cap"])
async def test_gripper_command_outside_the_policy_is_refused_and_audited(tmp_path, mode, tool, arguments, field) -> None:
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client(mode) as client:
        result = await client.call_tool(tool, arguments)
        assert result.is_error
        text = text_of(result)
        assert field in text and ("less than" in text or "greater than" in text), text
        assert arm.actuations == []
        # refused before the tool body ran, and still in the audit log
        record = [r for r in audit_records(arm) if r.get("tool") == tool][-1]
        assert record["outcome"] == "invalid"
        assert record["extra"]["code"] == "INVALID_ARGUMENTS"
    assert verify_file(arm.audit_path).ok


@pytest.mark.anyio
@mode_param
async def test_controller_outside_the_allowlist_is_refused_without_asking_anyone(tmp_path, mode) -> None:
    ask = approve()
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client(mode, ask) as client:
        for arguments in ({"activate": ["evil_torque_controller"]},
                          {"activate": ["joint_impedance_controller"], "deactivate": ["franka_robot_state_broadcaster"]}):
            text = assert_refused(await client.call_tool("switch_controllers", arguments), "NOT_ALLOWED")
            assert "allowlist" in text
        assert ask.prompts == []  # the human is never asked to approve what would be refused anyway
        assert arm.actuations == []


@pytest.mark.anyio
@mode_param
async def test_a_contradictory_or_repeated_controller_switch_is_refused_without_asking_anyone(tmp_path, mode) -> None:
    """Found by review: one controller in both lists, or twice in one, was put to a human (and
    only the backend refused it, after the approval)."""
    ask = approve()
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client(mode, ask) as client:
        both = await client.call_tool("switch_controllers", {"activate": ["fr3_arm_controller"],
                                                             "deactivate": ["fr3_arm_controller"]})
        twice = await client.call_tool("switch_controllers", {"activate": ["fr3_arm_controller", "fr3_arm_controller"]})
        assert "both activated and deactivated" in assert_refused(both, "INVALID")
        assert "named twice" in assert_refused(twice, "INVALID")
        assert ask.prompts == []
        assert arm.actuations == []


@pytest.mark.anyio
@mode_param
async def test_collision_thresholds_over_the_force_cap_are_refused(tmp_path, mode) -> None:
    ask = approve()
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client(mode, ask) as client:
        for arguments in ({"force_n": 100.0, "torque_nm": 5.0}, {"force_n": 20.0, "torque_nm": 50.0},
                          {"force_n": 0.0, "torque_nm": 5.0}):
            result = await client.call_tool("set_collision_thresholds", arguments)
            assert result.is_error
            assert "less than" in text_of(result) or "greater than" in text_of(result), text_of(result)
        assert ask.prompts == []
        assert arm.actuations == []
        record = [r for r in audit_records(arm) if r.get("tool") == "set_collision_thresholds"][-1]
        assert record["outcome"] == "invalid"


@pytest.mark.anyio
@mode_param
async def test_camera_outside_the_allowlist_is_refused(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client(mode) as client:
        for camera in ("basement", "../../etc/passwd", "wrist "):
            text = assert_refused(await client.call_tool("camera_snapshot", {"camera": camera}), "NOT_ALLOWED")
            assert "allowed" in text
        assert arm.actuations == []


# ---------------------------------------------------------------------------------------------- rate limits
@pytest.mark.anyio
@mode_param
async def test_a_flood_is_rate_limited_while_stop_estop_and_safety_status_are_still_served(tmp_path, mode) -> None:
    policy = policy_with(**{"rate_limits.global_per_minute": 8, "rate_limits.default_per_minute": 4,
                            "rate_limits.per_tool": {"execute_plan": 2}})

    async with arm_harness(tmp_path, policy, speedup=FAST) as arm, arm.client(mode, approve()) as client:
        flood = [await client.call_tool("get_robot_state", {}) for _ in range(10)]
        assert [r.is_error for r in flood[:4]] == [False] * 4
        for result in flood[4:]:
            assert_refused(result, "RATE_LIMITED")
        bogus = [await client.call_tool("execute_plan", {"plan_id": f"plan_{i}"}) for i in range(6)]
        assert any("RATE_LIMITED" in text_of(r) for r in bogus)
        assert all(r.is_error for r in bogus)
        for _ in range(20):  # exempt, however busy the client has been
            assert not (await client.call_tool("get_safety_status", {})).is_error
            assert not (await client.call_tool("stop_motion", {})).is_error
        stopped = await client.call_tool("estop", {"reason": "flood"})
        assert not stopped.is_error and stopped.structured_content["estopped"] is True
        assert arm.actuations == []
        assert any(r.get("extra", {}) and r["extra"].get("code") == "RATE_LIMITED" for r in audit_records(arm))
    assert verify_file(arm.audit_path).ok
