"""The load run's verdict: what makes it fail, from its own counts (the run itself is exercised
end to end by the quick evaluation in test_eval_command.py)."""

from __future__ import annotations

import time
from typing import cast

import anyio
import pytest

from armwarden.evaluation import load
from armwarden.evaluation.load import LoadClient, LoadResult
from armwarden.stopchannel import client as stop_client


def answered_run(**changes: object) -> LoadResult:
    result = LoadResult(clients=16, duration_s=10.0, approvals=5, resets=1, actuations=4, executions=4, succeeded=3,
                        alive_at_end=True)
    result.estop_ms.append(12.0)
    result.per_tool["get_robot_state"].latencies_ms.extend([5.0, 7.0])
    for name, value in changes.items():
        setattr(result, name, value)
    return result


def test_a_run_with_every_call_answered_and_actuations_within_the_approvals_passes() -> None:
    result = answered_run()
    report = result.report()
    assert result.ok and report["passed"] and report["calls"] == 2 and report["throughput_per_s"] == 0.2
    assert report["per_tool"]["get_robot_state"]["p50_ms"] == 6.0


def test_an_actuation_beyond_the_executions_the_daemon_reported_fails_the_run() -> None:
    assert not answered_run(actuations=5).ok  # four executes reached the arm: four actuations at most


def test_executions_beyond_the_approvals_for_executes_fail_the_run() -> None:
    assert not answered_run(actuations=5, executions=5).ok  # five approvals, one of them a reset


def test_an_estop_left_latched_fails_the_run() -> None:
    assert not answered_run(resets=0, approvals=4).ok  # the work did not go on


def test_a_run_in_which_no_motion_succeeded_fails() -> None:
    assert not answered_run(succeeded=0).ok  # a daemon refusing everything proves nothing


def test_an_unanswered_estop_fails_the_run() -> None:
    assert not answered_run(estops_unanswered=1).ok


def test_a_call_that_got_no_answer_fails_the_run() -> None:
    result = answered_run()
    result.per_tool["plan_to_joints"].failed += 1
    assert not result.ok


def test_a_daemon_gone_at_the_end_fails_the_run() -> None:
    assert not answered_run(alive_at_end=False).ok


def test_a_run_without_an_estop_proves_nothing_about_stopping_and_fails() -> None:
    assert not answered_run(estop_ms=[]).ok


class Operator:
    """The operator who resets the e-stops: its sessions end at `deadline`."""

    def __init__(self, left_s: float) -> None:
        self.deadline = time.monotonic() + left_s
        self.calls: list[str] = []

    async def call(self, tool: str, arguments: dict[str, object]) -> dict[str, object]:
        self.calls.append(tool)
        return {}


def test_sessions_that_opened_late_still_get_their_estop_before_the_end(monkeypatch: pytest.MonkeyPatch) -> None:
    """16 sessions opening on a loaded machine left less of a short run than the e-stop period:
    the run then had no e-stop and failed for nothing (MuJoCo's quick evaluation, once)."""
    sent: list[str] = []
    monkeypatch.setattr(stop_client, "send_estop", lambda url, token, reason: sent.append(reason) or {"estopped": True})
    result, operator = LoadResult(clients=16, duration_s=10.0), Operator(left_s=2.6)

    anyio.run(load._estops, "http://127.0.0.1:1/estop", "token", result, cast("LoadClient", operator), 5.0)

    assert len(sent) == 1 and len(result.estop_ms) == 1 and result.estops_unanswered == 0
    assert operator.calls == ["reset_estop"] and result.resets == 1
