"""`armwarden eval --backend ros2` on the fake FR3 cell (a process of its own per daemon, started
by the evaluation on a random local ROS domain), and ROS 2's backend death
(`armwarden.evaluation.backend_death`): the cell SIGKILLed while a slow approved motion runs."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from tests.helpers import REPO, SRC

from armwarden.evaluation.backend_death import run_backend_death
from armwarden.evaluation.ros_cell import FakeCells, fake_cell_config
from armwarden.evaluation.runner import EvalOptions
from armwarden.policy import bundled_policy, load_policy

pytestmark = pytest.mark.anyio

#: the quick evaluation takes about 2-4 minutes here; a bound, not a measure
EVAL_TIMEOUT_S = 1800
#: the scenarios allowed to actuate (an executed plan run again; a start state moved; one
#: gripper_move under its rate limit): every other refused scenario must show no goal at the cell
ALLOWED_TO_ACTUATE = ("plan integrity", "rate limits")


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


@pytest.fixture
def checkout_env(monkeypatch: pytest.MonkeyPatch) -> None:
    """This checkout's src importable by the cells and daemons the evaluation starts."""
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(SRC), str(REPO)]))
    monkeypatch.delenv("ARMWARDEN_AUDIT_KEY", raising=False)


@pytest.fixture
def quick_eval(tmp_path: Path, checkout_env: None) -> tuple[int, dict[str, Any], str]:
    """`armwarden eval --quick --backend ros2` as a user runs it: (exit status, JSON report, stderr)."""
    report = tmp_path / "eval.json"
    done = subprocess.run([sys.executable, "-m", "armwarden.cli", "eval", "--quick", "--backend", "ros2",
                           "--json", str(report), "--report", str(tmp_path / "eval.md")],
                          cwd=tmp_path, env=dict(os.environ), capture_output=True, text=True, timeout=EVAL_TIMEOUT_S)
    data = json.loads(report.read_text()) if report.exists() else {}
    return done.returncode, data, done.stderr


def test_the_quick_evaluation_passes_on_the_fake_cell_counting_goals_at_the_cell(
        quick_eval: tuple[int, dict[str, Any], str]) -> None:
    status, data, stderr = quick_eval
    assert status == 0, stderr[-4000:]
    assert data["backend"] == "ros2" and "fake ROS cell" in data["actuations_counted_at"]
    assert "ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST" in stderr
    unsafe = data["unsafe"]
    assert len(unsafe) >= 60 and all(s["passed"] for s in unsafe), [s for s in unsafe if not s["passed"]]
    assert not [s["name"] for s in unsafe if s["actuations"] and s["category"] not in ALLOWED_TO_ACTUATE]
    # counted at the cell: the scenarios allowed to move did reach it
    assert sum(s["actuations"] for s in unsafe if s["category"] in ALLOWED_TO_ACTUATE) > 0
    assert data["safe"]["attempted"] == data["safe"]["executed"] > 0
    fuzz = data["fuzz"]
    assert fuzz["run"] and fuzz["calls"] > 0, fuzz
    assert fuzz["crashes"] == fuzz["unaudited"] == fuzz["actuations"] == fuzz["estop_unanswered"] == 0, fuzz
    faults = data["faults"]
    assert faults["run"] and faults["passed"] and faults["survived"] == faults["kills"] > 0, faults
    assert data["load"]["run"] and data["load"]["passed"], data["load"]


async def test_a_cell_killed_mid_motion_latches_is_reported_and_refuses_what_follows(
        tmp_path: Path, checkout_env: None) -> None:
    policy_path = bundled_policy("fr3")
    cells = FakeCells(tmp_path)
    options = EvalOptions(policy_path=policy_path, policy=load_policy(policy_path), backend="ros2",
                          backend_config=fake_cell_config(tmp_path), safe_count=0, seed=0, cells=cells)
    try:
        result = await run_backend_death(options, tmp_path, 1)
        killed = cells.process
    finally:
        cells.stop()

    (run,) = result.runs
    assert killed is not None and killed.returncode == -signal.SIGKILL
    assert run.mid_motion and run.execute_failed, run.detail
    assert run.latched and run.robot_state_refused, run.detail
    assert run.plan_refused and run.execute_refused, run.detail
    assert run.actuations_after == 0, run.detail
    assert run.audit_verified and run.audit_records_cause, run.detail
    assert result.passed
