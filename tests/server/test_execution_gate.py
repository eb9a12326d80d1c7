"""The last checks before the arm moves, each proven necessary end to end.

`execute_plan` re-checks at execution time what may have changed since planning or since the
human was asked: the plan against the envelope in force now, that the approved digest is the plan
about to run, that the arm is still where the plan starts, and that the caller is the one who
made the plan. Each scenario below is refused only by that one check (the plan passes every
earlier one), so deleting the check makes its test fail. Also: an interrupted execution reports
the time the arm actually moved.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator
from typing import Any

import anyio
import mcp_types as types
import pytest
from mcp.server.auth.middleware.auth_context import auth_context_var
from mcp.server.auth.middleware.bearer_auth import AuthenticatedUser
from mcp.server.auth.provider import AccessToken

from armwarden.preflight import load_runtime_model
from tests.helpers import text_of
from tests.server.harness import approve, arm_harness, plan_down, policy_with, wait_until


def approving_after(action: Any) -> Any:
    """An elicitation callback that runs `action` while the human is 'deciding', then approves."""
    async def callback(context: Any, params: types.ElicitRequestParams) -> types.ElicitResult:
        callback.prompts.append(params.message)  # type: ignore[attr-defined]
        await action()
        return types.ElicitResult(action="accept", content={"approve": True, "operator": "alice"})

    callback.prompts = []  # type: ignore[attr-defined]
    return callback


# ------------------------------------------------------------------ (a) re-validation against the envelope
@pytest.mark.anyio
@pytest.mark.parametrize("mode", ["legacy", "2026-07-28"])
async def test_a_plan_that_breaks_the_envelope_in_force_at_execution_is_refused(tmp_path, mode) -> None:
    """The plan was inside the envelope when made; by execution time the envelope has a new keep-out
    zone across its path. Only the re-validation right before moving can see that."""
    async with arm_harness(tmp_path) as arm, arm.client(mode, approve()) as client:
        summary = await plan_down(client, z=0.40)
        assert summary["status"] == "ok"
        fixture = {"name": "new_fixture", "min": [0.20, -0.10, 0.38], "max": [0.40, 0.10, 0.43]}
        stricter = policy_with(**{"workspace.keep_out": [fixture]})
        arm.guard.state.planning = dataclasses.replace(arm.guard.planning, envelope=load_runtime_model(stricter).envelope)

        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})

        assert result.is_error, text_of(result)
        assert "ENVELOPE" in text_of(result) and "new_fixture" in text_of(result)
        assert arm.actuations == []


# ------------------------------------------------------------------ (b) the approved digest is the plan that runs
@pytest.mark.anyio
async def test_an_approval_for_one_plan_never_runs_another_under_the_same_id(tmp_path) -> None:
    """While the human looks at plan A, the store's entry for A's id is replaced by plan B (as a
    store bug or a race would): the human approved A's digest, so B must not run."""
    holder: dict[str, Any] = {}

    async def swap_plans() -> None:
        store = arm.guard.plans._plans
        store[holder["a"]] = dataclasses.replace(store[holder["b"]], plan_id=holder["a"])

    asked = approving_after(swap_plans)
    policy = policy_with(**{"approval.mode": "always"})
    # legacy only: under 2026-07-28 the question is asked between two rounds and the second round
    # shows (and matches) what it finds then; the mismatch can only arise within one round
    async with arm_harness(tmp_path, policy) as arm, arm.client("legacy", asked) as client:
        holder["a"] = (await plan_down(client, z=0.40))["plan_id"]
        holder["b"] = (await plan_down(client, z=0.42))["plan_id"]

        result = await client.call_tool("execute_plan", {"plan_id": holder["a"]})

        assert len(asked.prompts) == 1 and holder["a"] in asked.prompts[0]
        assert result.is_error and "APPROVAL_MISMATCH" in text_of(result), text_of(result)
        assert arm.actuations == []


# ------------------------------------------------------------------ (c) the arm is still where the plan starts
@pytest.mark.anyio
async def test_an_arm_moved_by_another_client_while_the_human_decided_is_refused_stale(tmp_path) -> None:
    """Alice's plan starts at home; while her operator reads the prompt, Bob moves the arm away with
    a plan of his own. Alice's approved plan must not run from the wrong start."""
    policy = policy_with(**{"approval.mode": "always"})
    async with arm_harness(tmp_path, policy) as arm, arm.client("legacy", approve("bob-operator")) as bob:
        async def bob_moves_the_arm() -> None:
            moved = await plan_down(bob, z=0.44)
            done = await bob.call_tool("execute_plan", {"plan_id": moved["plan_id"]})
            assert not done.is_error and done.structured_content["status"] == "succeeded", text_of(done)

        asked = approving_after(bob_moves_the_arm)
        async with arm.client("legacy", asked) as alice:
            summary = await plan_down(alice, z=0.40)

            result = await alice.call_tool("execute_plan", {"plan_id": summary["plan_id"]})

            assert len(asked.prompts) == 1
            assert result.is_error and "STALE_PLAN" in text_of(result), text_of(result)
            assert arm.actuations == ["execute"]  # Bob's motion only


# ------------------------------------------------------------------ plans belong to the caller that made them
@pytest.mark.anyio
async def test_a_plan_made_by_one_client_cannot_be_executed_by_another(tmp_path) -> None:
    """Two connections: Bob learns Alice's plan id but is refused before anyone is asked, and the
    plan stays usable for Alice."""
    policy = policy_with(**{"approval.mode": "always"})
    alice_asked, bob_asked = approve("alice"), approve("bob")
    async with arm_harness(tmp_path, policy) as arm, arm.client("legacy", alice_asked) as alice, \
            arm.client("legacy", bob_asked) as bob:
        summary = await plan_down(alice, z=0.40)

        taken = await bob.call_tool("execute_plan", {"plan_id": summary["plan_id"]})

        assert taken.is_error and "NOT_PLAN_OWNER" in text_of(taken), text_of(taken)
        assert bob_asked.prompts == [] and arm.actuations == []
        done = await alice.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
        assert not done.is_error and done.structured_content["status"] == "succeeded", text_of(done)
        assert len(alice_asked.prompts) == 1 and arm.actuations == ["execute"]


@pytest.mark.anyio
async def test_a_sessionless_client_without_a_token_executes_its_own_plans(tmp_path) -> None:
    """Under 2026-07-28 each request is its own connection: without a token every such caller is
    the same one, so a client can still run what it planned."""
    async with arm_harness(tmp_path) as arm, arm.client("2026-07-28", approve()) as client:
        summary = await plan_down(client, z=0.40)
        done = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
        assert not done.is_error and done.structured_content["status"] == "succeeded", text_of(done)
        assert arm.actuations == ["execute"]


# ------------------------------------------------------------------ an interrupted execution reports how long it moved
@pytest.mark.anyio
async def test_a_cancelled_execution_reports_the_time_the_arm_moved(tmp_path) -> None:
    async with arm_harness(tmp_path, speedup=1.0) as arm, arm.client("legacy", approve()) as client:
        summary = await plan_down(client, z=0.30)
        with anyio.move_on_after(10):
            async with anyio.create_task_group() as group:
                group.start_soon(client.call_tool, "execute_plan", {"plan_id": summary["plan_id"]})
                await wait_until(lambda: arm.guard.motion_status().progress >= 0.3, what="30 % of the motion")
                group.cancel_scope.cancel()
        await wait_until(lambda: not arm.guard.motion_status().executing, what="execution ended")

        last = arm.guard.motion_status().last_result
        assert last is not None and last.status == "aborted" and "interrupted" in last.detail
        assert 0.0 < last.duration_s < summary["duration_s"]  # it moved, and stopped before the end


@contextlib.contextmanager
def bearer(name: str, fingerprint: str) -> Iterator[None]:
    """Calls made inside carry this operator token, as the HTTP transport's auth middleware sets it
    (in-memory 2026-07-28 calls run in the caller's context)."""
    user = AuthenticatedUser(AccessToken(token=f"redacted:{name}", client_id=name, subject=fingerprint,
                                         scopes=["operator"], claims={"armwarden_role": "operator"}))
    reset = auth_context_var.set(user)
    try:
        yield
    finally:
        auth_context_var.reset(reset)


@pytest.mark.anyio
async def test_a_token_owns_its_plans_across_connections_and_a_new_token_of_the_same_name_does_not(tmp_path) -> None:
    async with arm_harness(tmp_path) as arm, arm.client("2026-07-28", approve()) as first, \
            arm.client("2026-07-28", approve()) as second:
        with bearer("alice", "fingerprint-1"):
            summary = await plan_down(first, z=0.40)
        with bearer("alice", "fingerprint-2"):  # alice's token was revoked and a new one issued
            taken = await second.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
        assert taken.is_error and "NOT_PLAN_OWNER" in text_of(taken), text_of(taken)
        assert arm.actuations == []
        with bearer("alice", "fingerprint-1"):
            done = await second.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
        assert not done.is_error and done.structured_content["status"] == "succeeded", text_of(done)
