"""Detours through the MCP tools: the summary says so, and an e-stop during a long search is served at once."""

from __future__ import annotations

import time
from typing import Any

import anyio
import pytest

from tests.helpers import text_of
from tests.planning.scenarios import base_turn, hemmed_block, pillar_at, with_zones
from tests.server.harness import approve, arm_harness

FAST = 50.0


@pytest.mark.anyio
async def test_plan_to_joints_around_a_pillar_is_ok_and_its_notes_say_it_is_a_detour(tmp_path) -> None:
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client("legacy", approve("alice")) as client:
        # from the ready pose (where the fake starts) a base turn of 1 rad sweeps the hand through the pillar
        arm.guard.state.planning = with_zones(arm.guard.planning, pillar_at(arm.guard.planning, 0.5))
        result = await client.call_tool("plan_to_joints", {"joint_positions": list(base_turn(1.0)), "preview": False})
        summary = result.structured_content
        assert summary["status"] in ("ok", "needs_approval"), summary
        assert not [v for v in summary["violations"] if v["severity"] == "hard"]
        assert any("detour planned" in note for note in summary["notes"]), summary["notes"]


@pytest.mark.anyio
async def test_an_estop_during_a_long_detour_search_is_served_at_once_and_voids_the_plan(tmp_path) -> None:
    async with arm_harness(tmp_path, speedup=FAST) as arm, arm.client("legacy", approve("alice")) as client:
        # the arm rests where every motion sweeps the hand into a block: the search runs its whole 2 s budget
        budget_s = 2.0
        arm.guard.state.planning = with_zones(arm.guard.planning, hemmed_block(arm.guard.planning), budget_s=budget_s)
        outcome: dict[str, Any] = {}

        async def plan() -> None:
            outcome["plan"] = await client.call_tool("plan_to_joints", {"joint_positions": list(base_turn(0.6))})
            outcome["returned"] = time.monotonic()

        async with anyio.create_task_group() as group:
            group.start_soon(plan)
            await anyio.sleep(0.3)  # the planning thread is inside the search
            sent = time.monotonic()
            stopped = await client.call_tool("estop", {"reason": "person in the cell"})
        assert not stopped.is_error, text_of(stopped)
        # the e-stop was served while the search ran (a search holding it back would have ended at
        # its budget with a rejection, not ESTOPPED) and the search ended at it; how fast, under
        # load, is the benchmark's business, not a unit test's
        assert outcome["returned"] - sent < budget_s / 2
        assert outcome["plan"].is_error and "ESTOPPED" in text_of(outcome["plan"])
        assert arm.actuations == []
