"""A first end-to-end pass through the SDK client: plan, approve, execute, replay refused."""

from __future__ import annotations

import pytest

from armwarden.audit import read_tail, verify_file
from armwarden.results import RobotState
from tests.helpers import HOME
from tests.server.harness import MODES, approve, arm_harness, policy_with


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_plan_then_execute_moves_once_and_a_replay_is_refused(tmp_path, mode) -> None:
    async with arm_harness(tmp_path) as arm, arm.client(mode, approve()) as client:
        plan = await client.call_tool("plan_to_pose", {"position": {"x": 0.4, "y": 0.1, "z": 0.35}})
        assert plan.structured_content["status"] == "ok"
        plan_id = plan.structured_content["plan_id"]
        done = await client.call_tool("execute_plan", {"plan_id": plan_id})
        assert not done.is_error and done.structured_content["status"] == "succeeded"
        again = await client.call_tool("execute_plan", {"plan_id": plan_id})
        assert again.is_error and "USED_PLAN" in again.content[0].text
        assert arm.actuations == ["execute"]
    assert verify_file(arm.audit_path).ok


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_an_unexpected_failure_is_an_error_result_and_the_server_keeps_serving(tmp_path, mode) -> None:
    async with arm_harness(tmp_path) as arm, arm.client(mode) as client:
        async def broken() -> None:
            raise RuntimeError("simulated bug with secret internals")

        arm.guard.robot_state_data = broken  # type: ignore[method-assign]
        result = await client.call_tool("get_robot_state", {})
        assert result.is_error and "INTERNAL_ERROR" in result.content[0].text
        assert "secret internals" not in result.content[0].text
        status = await client.call_tool("get_safety_status", {})
        assert not status.is_error
        assert arm.actuations == []
    records = read_tail(arm.audit_path, 10)
    failed = [r for r in records if r.get("tool") == "get_robot_state"]
    assert failed and failed[-1]["outcome"] == "refused" and failed[-1]["extra"]["code"] == "INTERNAL_ERROR"


@pytest.mark.anyio
async def test_a_client_cannot_answer_an_approval_question_it_was_not_asked(tmp_path) -> None:
    """Protocol 2026-07-28: pre-filled `input_responses` without the server's sealed request state
    are not an approval; the server asks again and nothing moves."""
    import mcp_types as types

    policy = policy_with(**{"approval.mode": "always"})
    async with arm_harness(tmp_path, policy) as arm, arm.client("2026-07-28", approve()) as client:
        session = client.session
        first = (await client.call_tool("plan_to_joints", {"joint_positions": [0.1, *HOME[1:]], "preview": False})).structured_content
        asked = await session.call_tool("execute_plan", {"plan_id": first["plan_id"]}, allow_input_required=True)
        assert isinstance(asked, types.InputRequiredResult)
        key = next(iter(asked.input_requests))
        forged = {key: types.ElicitResult(action="accept", content={"approve": True, "operator": "the model"})}
        # the same answer sent without the sealed state the server issued: asked again, not executed
        again = await session.call_tool("execute_plan", {"plan_id": first["plan_id"]}, allow_input_required=True,
                                        input_responses=forged)
        assert isinstance(again, types.InputRequiredResult)
        assert arm.actuations == []


@pytest.mark.anyio
async def test_a_state_polls_text_is_its_structured_result_as_the_published_model_writes_it(tmp_path) -> None:
    async with arm_harness(tmp_path) as arm, arm.client(MODES[0]) as client:
        state = await client.call_tool("get_robot_state", {})
    assert not state.is_error
    assert state.content[0].text == RobotState.model_validate(state.structured_content).model_dump_json()


@pytest.mark.anyio
@pytest.mark.parametrize("damage", ["no frame id", "a position that is not a number", "an extra field"])
async def test_a_state_that_does_not_fit_the_published_model_is_never_sent(tmp_path, damage) -> None:
    """The state poll builds plain data and leaves its validation to the SDK's output check
    (`server.calls.ok_data`): that check must still stand between the data and the client."""
    async with arm_harness(tmp_path) as arm, arm.client(MODES[0]) as client:
        real = arm.guard.robot_state_data

        async def damaged() -> dict:
            data = await real()
            if damage == "no frame id":
                del data["frame_id"]
            elif damage == "an extra field":
                data["unchecked"] = 1
            else:
                data["joint_positions"][2] = "fast"
            return data

        arm.guard.robot_state_data = damaged  # type: ignore[method-assign]
        result = await client.call_tool("get_robot_state", {})
        assert result.is_error and result.structured_content is None
        assert "joint_positions" not in result.content[0].text
    failed = [r for r in read_tail(arm.audit_path, 10) if r.get("tool") == "get_robot_state"]
    assert failed and failed[-1]["outcome"] == "error" and failed[-1]["extra"]["code"] == "INTERNAL_ERROR"
    assert "output model" in failed[-1]["detail"]  # the log says what the client saw: nothing was sent
