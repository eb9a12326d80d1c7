"""Review of F1 (bda5577), through the whole server: an arm without a sensor, its contact from
the joint torques, on a fake sped up 50 times (its config allows up to 1000)."""

from __future__ import annotations

import pytest

from tests.helpers import text_of
from tests.server.harness import approve, arm_harness
from tests.server.test_contact_from_joint_torques import plan_down

pytestmark = pytest.mark.anyio


async def test_a_free_motion_at_a_speedup_the_observer_cannot_follow_is_refused_before_it_moves(tmp_path) -> None:
    async with arm_harness(tmp_path, wrench=False, speedup=50.0) as arm, arm.client("legacy", approve()) as client:
        summary = await plan_down(client)
        assert summary["force_monitoring"] is False  # the plan says so before anyone approves it
        result = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
        assert result.is_error and "[NO_WRENCH]" in text_of(result), text_of(result)
        assert "at speedup 50" in text_of(result) and "lower the speedup" in text_of(result)
        assert arm.actuations == []
