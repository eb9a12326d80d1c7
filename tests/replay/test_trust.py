"""What the replay trusts: a log whose chain does not verify is refused (exit 1) unless
--allow-broken, which replays only the lines before the first bad one and says so; an unreadable
log exits 1, an invalid candidate policy 2; a plan record written before the replay data existed
is reported as not replayable, with the reason."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from armwarden.audit import AuditLog
from armwarden.cli import main
from armwarden.policy import bundled_policy
from tests.helpers import records_of
from tests.replay.session import SessionLog


def replay(capsys: pytest.CaptureFixture[str], log: Path, *extra: str) -> tuple[int, str, str]:
    code = main(["audit", "replay", str(log), "--policy", str(bundled_policy("fr3")), *extra])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def tampered_copy(session_log: SessionLog, tmp_path: Path, plan_id: str | None) -> tuple[Path, int]:
    """The session's log with one byte changed on the line of the plan call that answered `plan_id`;
    returns the copy and that line's number."""
    lines = session_log.path.read_bytes().split(b"\n")
    index = next(i for i, record in enumerate(records_of(session_log.path))
                 if record["event"] == "tool_call" and ((record["extra"] or {}).get("result") or {}).get("plan_id") == plan_id
                 and record["tool"].startswith("plan_"))
    at = lines[index].index(b'"tool":"') + len(b'"tool":"')
    edited = bytearray(lines[index])
    edited[at] = ord("X")
    lines[index] = bytes(edited)
    tampered = tmp_path / "tampered.jsonl"
    tampered.write_bytes(b"\n".join(lines))
    return tampered, index + 1


def test_a_tampered_log_is_refused(session_log, capsys, tmp_path) -> None:
    tampered, line = tampered_copy(session_log, tmp_path, session_log.plan_ids["fast"])

    code, out, err = replay(capsys, tampered)

    assert code == 1
    assert out == ""
    assert f"chain broken at line {line}" in err


def test_allow_broken_replays_only_the_lines_before_the_first_bad_one(session_log, capsys, tmp_path) -> None:
    tampered, line = tampered_copy(session_log, tmp_path, session_log.plan_ids["fast"])
    report = tmp_path / "report.json"

    code, out, _ = replay(capsys, tampered, "--allow-broken", "--json", str(report))

    assert code == 0
    assert f"chain broken at line {line}" in out and f"nothing from line {line} on is trusted" in out
    data = json.loads(report.read_text(encoding="utf-8"))
    assert data["log"]["first_untrusted_line"] == line and data["log"]["trusted_lines"] == line - 1
    assert data["plans"] and all(plan["line"] < line for plan in data["plans"])
    assert [plan["plan_id"] for plan in data["plans"]] == [
        session_log.plan_ids[step] for step in ("to_a", "back_home", "too_far", "big_step", "wrist_turn")]


def test_an_unreadable_log_exits_1(capsys, tmp_path) -> None:
    code, _, err = replay(capsys, tmp_path / "missing.jsonl")

    assert code == 1
    assert "cannot read" in err


def test_an_invalid_candidate_policy_exits_2(session_log, capsys, tmp_path) -> None:
    broken = tmp_path / "broken.yaml"
    broken.write_text("version: 1\nrobot: {}\n", encoding="utf-8")

    code = main(["audit", "replay", str(session_log.path), "--policy", str(broken)])

    assert code == 2
    assert "INVALID" in capsys.readouterr().err


def test_an_old_format_plan_record_is_reported_as_not_replayable_with_the_reason(capsys, tmp_path) -> None:
    path = tmp_path / "old.jsonl"
    with AuditLog(path) as log:  # what a daemon wrote before plan records carried replay data
        log.append("tool_call", tool="plan_to_pose", outcome="ok",
                   arguments={"position": {"x": 0.35, "y": 0.05, "z": 0.45}},
                   extra={"code": None, "result": {"plan_id": "plan_old", "status": "ok", "violations": []}})
        log.append("tool_call", tool="execute_plan", outcome="ok", arguments={"plan_id": "plan_old"},
                   extra={"result": {"plan_id": "plan_old", "status": "succeeded"}})
    report = tmp_path / "report.json"

    code, out, _ = replay(capsys, path, "--json", str(report))

    assert code == 0
    [plan] = json.loads(report.read_text(encoding="utf-8"))["plans"]
    assert plan["replayable"] is False
    assert "before the audit log carried replay data" in plan["reason"]
    assert "no start joint state" in plan["reason"]
    assert "1 executed motion(s) could not be replayed" in out
