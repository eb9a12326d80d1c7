"""The load run's verdict: what makes it fail, from its own counts (the run itself is exercised
end to end by the quick evaluation in test_eval_command.py)."""

from __future__ import annotations

from armwarden.evaluation.load import LoadResult


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
