"""The link-level envelope holds on a generated arm as on the FR3: a middle link sweeping through a
keep-out zone is rejected although the TCP stays far from it, and executing that plan moves nothing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from armwarden.policy import parse_policy
from tests.helpers import text_of
from tests.onboarding.conftest import InitRun
from tests.onboarding.elbow_zone import find_elbow_zone_case
from tests.server.harness import approve, arm_harness

pytestmark = pytest.mark.anyio


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


async def test_an_elbow_through_a_zone_is_rejected_while_the_tcp_passes_far_from_it(
        six_joint_arm: InitRun, tmp_path: Path) -> None:
    case = find_elbow_zone_case(six_joint_arm.result.runtime)
    assert case is not None, "no elbow-through-zone motion found from home"
    document = yaml.safe_load(six_joint_arm.options.output.read_text(encoding="utf-8"))
    document["workspace"]["keep_out"] = [{"name": "shelf", "min": case.zone.lo.tolist(), "max": case.zone.hi.tolist()}]
    policy = parse_policy(document, base_dir=six_joint_arm.options.output.parent)
    async with arm_harness(tmp_path, policy) as arm, arm.client("legacy", approve()) as client:
        result = await client.call_tool("plan_to_joints", {"joint_positions": case.goal.tolist(), "preview": False})
        assert not result.is_error, text_of(result)
        summary = result.structured_content
        assert summary["status"] == "rejected", summary
        hits = {v["body"] for v in summary["violations"] if v["code"] == "KEEP_OUT" and v["severity"] == "hard"}
        assert case.link in hits, summary["violations"]
        refused = await client.call_tool("execute_plan", {"plan_id": summary["plan_id"]})
        assert refused.is_error and "REJECTED_PLAN" in text_of(refused)
        assert arm.actuations == []
        state = (await client.call_tool("get_robot_state", {})).structured_content
        assert state["joint_positions"] == pytest.approx(np.asarray(case.start).tolist(), abs=1e-6)
