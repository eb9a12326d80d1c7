"""The steps scenarios are written in: planning, moving in the background, reading what the arm
did (joint state, e-stop) and what the audit log recorded. Everything goes through the SDK client
except the audit log, which is read from disk after the call (the middleware writes a call's
record before its answer goes out)."""

from __future__ import annotations

import contextlib
import json
from collections.abc import AsyncIterator, Callable
from typing import Any

import anyio
import pytest
from mcp import Client

from tests.server.harness import ArmHarness

READY = [0.0, -0.785398, 0.0, -2.356194, 0.0, 1.570796, 0.785398]  # the bundled policy's home pose [rad]
#: scalings for a motion long enough to interrupt (~6 s of trajectory; the harness runs it faster)
SLOW = {"velocity_scaling": 0.02, "acceleration_scaling": 0.02}


def offset(q: list[float], **deltas: float) -> list[float]:
    """`q` with joint offsets [rad], e.g. `offset(q, j1=0.2)` adds 0.2 rad to the first joint."""
    q = list(q)
    for name, delta in deltas.items():
        q[int(name[1:]) - 1] += delta
    return q


def joints(**deltas: float) -> list[float]:
    """The ready pose with joint offsets [rad], e.g. `joints(j1=0.2)`."""
    return offset(READY, **deltas)


def text_of(result: Any) -> str:
    return " ".join(getattr(block, "text", "") for block in result.content)


# ------------------------------------------------------------------ planning
async def plan(client: Client, tool: str, arguments: dict[str, Any]) -> dict[str, Any]:
    """A plan summary (planning never moves the arm); asserts the call itself succeeded."""
    result = await client.call_tool(tool, {**arguments, "preview": False})
    assert not result.is_error, text_of(result)
    return result.structured_content


async def plan_joints(client: Client, q_goal: list[float], **scaling: float) -> dict[str, Any]:
    summary = await plan(client, "plan_to_joints", {"joint_positions": q_goal, **scaling})
    assert summary["status"] in ("ok", "needs_approval"), summary
    return summary


async def execute(client: Client, plan_id: str) -> Any:
    return await client.call_tool("execute_plan", {"plan_id": plan_id})


# ------------------------------------------------------------------ motion in the background
async def wait_until(predicate: Callable[[], bool], timeout_s: float = 10.0) -> None:
    with anyio.fail_after(timeout_s):
        while not predicate():  # noqa: ASYNC110 (the Guard's motion status and the audit file have no event to wait on)
            await anyio.sleep(0.002)


@contextlib.asynccontextmanager
async def executing(arm: ArmHarness, client: Client, plan_id: str, past: float = 0.1) -> AsyncIterator[dict[str, Any]]:
    """`execute_plan(plan_id)` in the background; the body runs once the arm is `past` that fraction
    of the motion; after the block the call's result is in `outcome["result"]`."""
    outcome: dict[str, Any] = {}

    async def run() -> None:
        outcome["result"] = await execute(client, plan_id)

    async with anyio.create_task_group() as group:
        group.start_soon(run)
        await wait_until(lambda: arm.guard.motion_status().progress > past)
        yield outcome


# ------------------------------------------------------------------ what the robot did
async def joint_positions(client: Client) -> list[float]:
    return (await client.call_tool("get_robot_state", {})).structured_content["joint_positions"]


async def assert_still(arm: ArmHarness, client: Client) -> list[float]:
    """The arm comes to rest (every joint speed within the backend's `rest_speed_rad_s`) and two
    reads 50 ms apart agree within its `hold_accuracy_rad` (exactly, on a kinematic backend)."""
    backend = arm.inner

    async def state() -> dict[str, Any]:
        return (await client.call_tool("get_robot_state", {})).structured_content

    def at_rest(sample: dict[str, Any]) -> bool:
        return all(abs(v) <= backend.rest_speed_rad_s for v in sample["joint_velocities"])

    with anyio.fail_after(10.0):
        while not at_rest(first := await state()):  # noqa: ASYNC110 - the arm's speed, read through the tools
            await anyio.sleep(0.01)
    await anyio.sleep(0.05)
    second = await state()
    assert second["joint_positions"] == pytest.approx(first["joint_positions"], abs=max(backend.hold_accuracy_rad, 1e-12))
    assert at_rest(second), second["joint_velocities"]
    return second["joint_positions"]


async def safety(client: Client) -> dict[str, Any]:
    return (await client.call_tool("get_safety_status", {})).structured_content


async def last_result(client: Client) -> dict[str, Any]:
    status = (await client.call_tool("get_motion_status", {})).structured_content
    assert status["executing"] is False
    return status["last_result"]


# ------------------------------------------------------------------ what the audit log recorded
def audit_records(arm: ArmHarness) -> list[dict[str, Any]]:
    """Every record so far: read-only calls' records are group-committed, so flush them first."""
    arm.audit.flush()
    return [json.loads(line) for line in arm.audit_path.read_text(encoding="utf-8").splitlines() if line.strip()]


def calls(arm: ArmHarness, tool: str) -> list[dict[str, Any]]:
    """The audit records of every call of `tool`, oldest first."""
    return [r for r in audit_records(arm) if r["event"] == "tool_call" and r["tool"] == tool]


def events(arm: ArmHarness, event: str) -> list[dict[str, Any]]:
    return [r for r in audit_records(arm) if r["event"] == event]


def assert_refused(arm: ArmHarness, result: Any, code: str, tool: str = "execute_plan",
                   moved_before: tuple[str, ...] = ()) -> dict[str, Any]:
    """Refused with `code` on the wire and in the call's audit record; the backend received no
    actuation beyond `moved_before` (what the scenario legitimately ran first)."""
    text = text_of(result)
    assert result.is_error and f"REFUSED [{code}]" in text, text[:500]
    record = calls(arm, tool)[-1]
    assert (record["outcome"], (record["extra"] or {}).get("code")) == ("refused", code), record
    assert arm.actuations == list(moved_before)
    if arm.motions_below is not None:  # counted below the backend too (CAN frames, ROS goals): nothing beyond what ran first
        assert arm.motions_below <= moved_before.count("execute")
    return record


def assert_invalid(arm: ArmHarness, result: Any, tool: str) -> dict[str, Any]:
    """Refused by argument validation (before the tool body ran); audited as such; nothing actuated."""
    assert result.is_error, text_of(result)[:500]
    record = calls(arm, tool)[-1]
    assert (record["outcome"], record["extra"]["code"]) == ("invalid", "INVALID_ARGUMENTS"), record
    assert arm.actuations == []
    assert arm.motions_below in (None, 0)
    return record

