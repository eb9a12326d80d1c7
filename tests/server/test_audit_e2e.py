"""The audit log after a real session: the chain verifies with the real CLI, a one-byte edit is
caught and located, approvals (question, answer, operator) are on record, and bulky arguments
(image bytes, huge strings) are redacted or truncated."""

from __future__ import annotations

import base64
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from mcp import MCPError

from tests.helpers import REPO, records_of
from tests.server.harness import MODES, answer, approve, arm_harness, policy_with

IMAGE_BYTES = os.urandom(6000)
HUGE = "A" * 50_000


def audit_cli(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(REPO / "src")}
    env.pop("ARMWARDEN_AUDIT_KEY", None)
    return subprocess.run([sys.executable, "-m", "armwarden.cli", "audit", *args], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=60)


async def run_session(tmp_path: Path, mode: str) -> tuple[Path, list[str], list[str]]:
    """Calls, refusals, an approval granted and one declined, an e-stop and an approved reset."""
    policy = policy_with(**{"approval.mode": "always"})
    alice, declined, bob = approve("alice"), answer("decline"), approve("bob")
    async with arm_harness(tmp_path, policy) as arm:
        async with arm.client(mode, alice) as client:
            assert not (await client.call_tool("get_robot_state", {})).is_error
            # refusals: bad arguments (before any tool body), an unknown plan, a rejected plan
            assert (await client.call_tool("plan_to_joints", {"joint_positions": [0.0, 1.0]})).is_error
            assert (await client.call_tool("execute_plan", {"plan_id": "plan_nope"})).is_error
            rejected = await client.call_tool("plan_to_pose", {"position": {"x": 2.0, "y": 0.0, "z": 0.3}})
            assert rejected.structured_content["status"] == "rejected"
            # approved motion
            plan = await client.call_tool("plan_to_pose", {"position": {"x": 0.35, "y": 0.05, "z": 0.45}})
            done = await client.call_tool("execute_plan", {"plan_id": plan.structured_content["plan_id"]})
            assert done.structured_content["status"] == "succeeded"
        async with arm.client(mode, declined) as client:
            plan = await client.call_tool("plan_to_pose", {"position": {"x": 0.35, "y": -0.05, "z": 0.45}})
            denied = await client.call_tool("execute_plan", {"plan_id": plan.structured_content["plan_id"]})
            assert denied.is_error and "APPROVAL_DENIED" in denied.content[0].text
            # an e-stop whose reason carries an image and a huge string
            image = {"type": "image", "mimeType": "image/png", "data": base64.b64encode(IMAGE_BYTES).decode()}
            stop = await client.call_tool("estop", {"reason": {"note": HUGE, "snapshot": image}})
            assert not stop.is_error
            # ignored extra argument with raw image data (recorded, but not verbatim)
            await client.call_tool("get_safety_status", {"image_base64": base64.b64encode(IMAGE_BYTES).decode()})
            assert (await client.call_tool("plan_to_pose", {"position": {"x": 0.35, "y": 0.0, "z": 0.45}})).is_error
        async with arm.client(mode, bob) as client:
            reset = await client.call_tool("reset_estop", {})
            assert not reset.is_error, reset.content[0].text
            assert reset.structured_content["estopped"] is False
    return arm.audit_path, alice.prompts + bob.prompts, declined.prompts


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_audit_chain_of_a_real_session_verifies_and_a_one_byte_edit_is_located(tmp_path, mode) -> None:
    path, _, _ = await run_session(tmp_path, mode)
    verdict = audit_cli("verify", str(path))
    assert verdict.returncode == 0, verdict.stdout + verdict.stderr
    assert verdict.stdout.startswith("OK:")

    lines = path.read_bytes().split(b"\n")
    assert lines[-1] == b""
    middle = len(lines[:-1]) // 2  # 0-based index; the CLI counts lines from 1
    at = lines[middle].index(b'"event":"') + len(b'"event":"')
    edited = bytearray(lines[middle])
    edited[at] = ord("X") if edited[at] != ord("X") else ord("Y")  # one byte, still valid JSON
    lines[middle] = bytes(edited)
    tampered = tmp_path / "tampered.jsonl"
    tampered.write_bytes(b"\n".join(lines))

    verdict = audit_cli("verify", str(tampered))
    assert verdict.returncode != 0
    assert f"line {middle + 1}" in verdict.stdout, verdict.stdout


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_every_approval_question_and_answer_is_on_record_with_the_operator(tmp_path, mode) -> None:
    path, approved_prompts, declined_prompts = await run_session(tmp_path, mode)
    records = records_of(path)
    calls = [r for r in records if r["event"] == "tool_call"]

    def on_record(prompt: str) -> bool:
        head = prompt[:300]
        return any(head in (r["detail"] or "") or head in ((r["extra"] or {}).get("approval_prompt") or "")
                   for r in calls)

    assert len(approved_prompts) == 2 and len(declined_prompts) == 1
    for prompt in approved_prompts + declined_prompts:
        assert on_record(prompt), prompt[:120]

    executed = [r for r in calls if r["tool"] == "execute_plan" and r["outcome"] == "ok"]
    assert len(executed) == 1
    assert executed[0]["operator"] == "alice"
    assert executed[0]["extra"]["approval"]["via"] == "elicitation"

    denied = [r for r in calls if r["tool"] == "execute_plan" and r["outcome"] == "refused"
              and (r["extra"] or {}).get("code") == "APPROVAL_DENIED"]
    assert len(denied) == 1 and "declined" in denied[0]["detail"]

    reset = [r for r in calls if r["tool"] == "reset_estop" and r["outcome"] == "ok"]
    assert len(reset) == 1 and reset[0]["operator"] == "bob"
    assert "RELEASE THE SOFTWARE E-STOP" in json.dumps(reset[0]["extra"]) or any(
        "RELEASE THE SOFTWARE E-STOP" in (r["detail"] or "") for r in calls if r["tool"] == "reset_estop")

    # refusals before any body ran are recorded too
    assert any(r["tool"] == "plan_to_joints" and r["outcome"] == "invalid" for r in calls)
    assert any(r["tool"] == "execute_plan" and (r["extra"] or {}).get("code") == "UNKNOWN_PLAN" for r in calls)
    assert any(r["tool"] == "plan_to_pose" and (r["extra"] or {}).get("code") == "ESTOPPED" for r in calls)


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_image_bytes_and_huge_strings_in_arguments_are_redacted_and_truncated(tmp_path, mode) -> None:
    path, _, _ = await run_session(tmp_path, mode)
    text = path.read_text(encoding="utf-8")
    encoded = base64.b64encode(IMAGE_BYTES).decode()
    assert encoded[:200] not in text  # no image payload, in arguments or anywhere else
    assert HUGE[:1000] not in text  # no huge string verbatim
    records = records_of(path)
    estop = next(r for r in records if r["event"] == "tool_call" and r["tool"] == "estop")
    reason = estop["arguments"]["reason"]
    assert reason["snapshot"]["data"].startswith("<redacted")
    assert "truncated" in reason["note"] and len(reason["note"]) < 1000
    status = next(r for r in records if r["tool"] == "get_safety_status")
    assert status["arguments"]["image_base64"].startswith("<redacted")
    assert max(len(line) for line in text.splitlines()) < 64_000


@pytest.mark.anyio
async def test_each_connection_has_its_own_session_name_and_sessionless_calls_are_named_by_their_client(tmp_path) -> None:
    async with arm_harness(tmp_path) as arm:
        for mode in ("legacy", "legacy", "2026-07-28"):
            async with arm.client(mode) as client:
                for _ in range(2):
                    assert not (await client.call_tool("get_robot_state", {})).is_error
        arm.audit.flush()
        names = [r["session"] for r in records_of(arm.audit_path) if r.get("tool") == "get_robot_state"]
    first, second, sessionless = names[0:2], names[2:4], names[4:6]
    assert first[0] == first[1] and second[0] == second[1]  # one name per connection ...
    client = first[0].split("#")[0]
    assert first[0] != second[0] and second[0].startswith(client + "#")  # ... of the same client software
    # a 2026-07-28 call has no connection beyond itself: its client's name, not a new random one per call
    assert sessionless == [f"{client} (sessionless)"] * 2


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_a_call_ended_by_an_unexpected_exception_is_recorded_as_an_error(tmp_path, mode) -> None:
    """Fail closed: whatever exception reaches the audit layer, the call is on record (found by
    another engineer: only protocol errors were, so a ValidationError left no trace)."""

    async def broken(ctx: Any, call_next: Any) -> Any:  # a layer below the audit that fails
        if ctx.method == "tools/call":
            raise RuntimeError("a layer below the audit broke")
        return await call_next(ctx)

    async with arm_harness(tmp_path) as arm:
        arm.server.mcp.middleware.append(broken)
        async with arm.client(mode) as client:
            with pytest.raises(MCPError):
                await client.call_tool("set_collision_thresholds", {"force_n": 20.0, "torque_nm": 10.0})
        arm.audit.flush()
        [record] = [r for r in records_of(arm.audit_path) if r["event"] == "tool_call"]

    assert (record["tool"], record["outcome"]) == ("set_collision_thresholds", "error")
    assert "RuntimeError: a layer below the audit broke" in record["detail"]
    assert arm.actuations == []
