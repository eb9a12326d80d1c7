"""`armwarden audit replay` on a real recorded session (tests/replay/session.py): the same policy
changes nothing, a keep-out zone across one executed path lists exactly that execution, relaxed
caps list the plans they newly allow, and the report is byte-for-byte deterministic."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from armwarden.cli import main
from armwarden.policy import bundled_policy, load_policy, policy_digest
from tests.replay.session import SessionLog, candidate_policy, with_b_zone

STEPS_REPLAYED = ("to_a", "back_home", "too_far", "big_step", "wrist_turn", "fast", "sideways", "to_b")


def replay(capsys: pytest.CaptureFixture[str], log: Path, policy: Path, *extra: str) -> tuple[int, str]:
    code = main(["audit", "replay", str(log), "--policy", str(policy), *extra])
    return code, capsys.readouterr().out


def replay_data(capsys: pytest.CaptureFixture[str], tmp_path: Path, log: Path, policy: Path, *extra: str) -> dict[str, Any]:
    out = tmp_path / "report.json"
    code, _ = replay(capsys, log, policy, "--json", str(out), *extra)
    assert code == 0
    return json.loads(out.read_text(encoding="utf-8"))


def plan_of(data: dict[str, Any], plan_id: str | None) -> dict[str, Any]:
    return next(plan for plan in data["plans"] if plan["plan_id"] == plan_id)


def test_the_session_has_the_outcomes_the_replay_tests_rely_on(session_log: SessionLog) -> None:
    assert session_log.statuses == {
        "to_a": "ok", "back_home": "ok", "too_far": "rejected", "big_step": "rejected", "wrist_turn": "needs_approval",
        "fast": "ok", "sideways": "ok", "bad_args": "refused", "to_b": "ok"}


def test_replayed_under_the_same_policy_every_outcome_is_identical(session_log, capsys, tmp_path) -> None:
    data = replay_data(capsys, tmp_path, session_log.path, bundled_policy("fr3"))

    replayed = [plan for plan in data["plans"] if plan["replayable"]]
    assert [plan["plan_id"] for plan in replayed] == [session_log.plan_ids[step] for step in STEPS_REPLAYED]
    for plan in replayed:
        assert plan["change"] == "unchanged", plan
        assert (plan["candidate"]["status"], plan["candidate"]["codes"]) == (plan["original"]["status"], plan["original"]["codes"])
        assert plan["candidate"]["velocity_scaling"] == plan["original"]["velocity_scaling"]
    assert data["totals"] == {"newly_rejected": 0, "newly_allowed": 0, "newly_needs_approval": 0, "unchanged": 8,
                              "not_replayable": 1, "executed_newly_rejected": 0, "speed_changed": 0}
    assert data["executed_newly_rejected"] == []
    assert data["candidate_policy"]["digest"] in data["original"]["recorded_digests"]


def test_a_keep_out_zone_across_one_executed_path_lists_exactly_that_execution(session_log, capsys, tmp_path) -> None:
    data = replay_data(capsys, tmp_path, session_log.path, with_b_zone(tmp_path))

    [stopped] = data["executed_newly_rejected"]
    assert stopped["plan_id"] == session_log.plan_ids["to_b"]
    assert "KEEP_OUT" in stopped["codes_added"]
    assert stopped["candidate"]["status"] == "rejected"
    assert [plan["plan_id"] for plan in data["plans"] if plan["change"] == "newly_rejected"] == [session_log.plan_ids["to_b"]]


def test_the_markdown_report_lists_the_stopped_execution_first(session_log, capsys, tmp_path) -> None:
    code, report = replay(capsys, session_log.path, with_b_zone(tmp_path))

    assert code == 0
    sections = [line for line in report.splitlines() if line.startswith("## ")]
    assert sections[0] == "## Executed motions the candidate policy would reject"
    first_section = report.split("## ")[1]
    assert session_log.plan_ids["to_b"] in first_section and "KEEP_OUT" in first_section
    assert session_log.plan_ids["to_a"] not in first_section


def test_relaxed_step_caps_list_the_plans_they_newly_allow(session_log, capsys, tmp_path) -> None:
    relaxed = candidate_policy(tmp_path, "relaxed.yaml", **{"motion.max_joint_step_rad": 2.0, "motion.soft_joint_step_rad": 1.2})
    data = replay_data(capsys, tmp_path, session_log.path, relaxed)

    allowed = {plan["plan_id"]: plan for plan in data["plans"] if plan["change"] == "newly_allowed"}
    assert set(allowed) == {session_log.plan_ids["big_step"], session_log.plan_ids["wrist_turn"]}
    big_step = allowed[session_log.plan_ids["big_step"]]
    assert (big_step["original"]["status"], big_step["candidate"]["status"]) == ("rejected", "needs_approval")
    assert big_step["codes_removed"] == ["STEP_TOO_LARGE"] and big_step["codes_added"] == ["LARGE_MOTION"]
    assert allowed[session_log.plan_ids["wrist_turn"]]["candidate"]["status"] == "ok"
    assert data["totals"]["newly_allowed"] == 2 and data["totals"]["newly_rejected"] == 0


def test_a_relaxed_speed_cap_lists_the_plans_that_would_run_faster_and_rejects_nothing_new(session_log, capsys, tmp_path) -> None:
    faster = candidate_policy(tmp_path, "faster.yaml", **{"motion.max_velocity_scaling": 0.6})
    data = replay_data(capsys, tmp_path, session_log.path, faster)

    [changed] = [plan for plan in data["plans"] if plan["speed_changed"]]
    assert changed["plan_id"] == session_log.plan_ids["fast"]
    assert (changed["original"]["velocity_scaling"], changed["candidate"]["velocity_scaling"]) == ("0.300", "0.500")
    assert data["totals"]["unchanged"] == 8  # a scaling over the cap is clamped, never refused


def test_same_log_and_policy_give_byte_identical_reports(session_log, capsys, tmp_path) -> None:
    policy = with_b_zone(tmp_path)
    first_json, second_json = tmp_path / "first.json", tmp_path / "second.json"
    first = replay(capsys, session_log.path, policy, "--json", str(first_json))
    second = replay(capsys, session_log.path, policy, "--json", str(second_json))

    assert first == second
    assert first_json.read_bytes() == second_json.read_bytes()


def test_with_an_original_policy_both_sides_are_replanned_and_match_the_record(session_log, capsys, tmp_path) -> None:
    data = replay_data(capsys, tmp_path, session_log.path, with_b_zone(tmp_path), "--original", str(bundled_policy("fr3")))

    assert data["original"]["source"] == "policy"
    assert data["original"]["digest"] == policy_digest(load_policy(bundled_policy("fr3")))
    for plan in data["plans"]:
        if plan["replayable"]:
            assert (plan["original"]["status"], plan["original"]["codes"]) == (
                plan["recorded"]["status"], plan["recorded"]["codes"]), plan
    assert [run["plan_id"] for run in data["executed_newly_rejected"]] == [session_log.plan_ids["to_b"]]


def test_a_call_refused_before_planning_is_listed_as_not_replayable_with_why(session_log, capsys, tmp_path) -> None:
    data = replay_data(capsys, tmp_path, session_log.path, bundled_policy("fr3"))

    [skipped] = [plan for plan in data["plans"] if not plan["replayable"]]
    assert skipped["tool"] == "plan_to_joints" and skipped["recorded_refusal"] == "invalid (INVALID_ARGUMENTS)"
    assert "refused before anything was planned" in skipped["reason"]


def test_a_policy_without_the_motion_tools_rejects_every_plan_and_lists_every_execution(session_log, capsys, tmp_path) -> None:
    data = replay_data(capsys, tmp_path, session_log.path, bundled_policy("readonly"))

    assert {plan["candidate"]["codes"][0] for plan in data["plans"] if plan["replayable"]} == {"NOT_ALLOWED"}
    assert [run["plan_id"] for run in data["executed_newly_rejected"]] == [
        session_log.plan_ids[step] for step in ("to_a", "back_home", "to_b")]
