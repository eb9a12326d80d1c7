"""`armwarden audit tail` filters (--tool, --principal, --status, --since): the last records that
match every filter given, so an operator finds what they look for without writing a script."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from armwarden.audit import AuditLog, RecordFilter, parse_since
from armwarden.cli import main


@pytest.fixture
def log(tmp_path: Path) -> Path:
    path = tmp_path / "audit.jsonl"
    with AuditLog(path) as audit:
        audit.append("startup", outcome="ok")
        audit.append("tool_call", tool="plan_to_pose", principal="alice", outcome="ok",
                      extra={"result": {"plan_id": "plan_1", "status": "rejected"}})
        audit.append("tool_call", tool="plan_to_pose", principal="bob", outcome="ok",
                      extra={"result": {"plan_id": "plan_2", "status": "ok"}})
        audit.append("tool_call", tool="execute_plan", principal="bob", outcome="ok",
                      extra={"result": {"plan_id": "plan_2", "status": "succeeded"}})
        audit.append("tool_call", tool="execute_plan", principal="alice", outcome="refused", extra={"code": "UNKNOWN_PLAN"})
    return path


def tail(capsys: pytest.CaptureFixture[str], log: Path, *filters: str) -> tuple[int, list[dict[str, Any]]]:
    code = main(["audit", "tail", str(log), *filters])
    out = capsys.readouterr().out
    decoder, records, at = json.JSONDecoder(), [], 0
    while at < len(out.strip()):  # the records are printed one after another, indented
        record, at = decoder.raw_decode(out, at)
        records.append(record)
        while at < len(out) and out[at].isspace():
            at += 1
    return code, records


def test_tool_filter_keeps_only_that_tools_calls(log, capsys) -> None:
    code, records = tail(capsys, log, "--tool", "execute_plan")
    assert code == 0
    assert [r["seq"] for r in records] == [4, 5]


def test_principal_filter_keeps_only_that_tokens_calls(log, capsys) -> None:
    _, records = tail(capsys, log, "--principal", "alice")
    assert [r["seq"] for r in records] == [2, 5]


def test_status_filter_matches_the_result_status_of_plans_and_executions(log, capsys) -> None:
    _, rejected = tail(capsys, log, "--status", "rejected")
    _, succeeded = tail(capsys, log, "--status", "succeeded")
    assert [r["seq"] for r in rejected] == [2]
    assert [r["seq"] for r in succeeded] == [4]


def test_status_filter_matches_the_outcome_of_a_call(log, capsys) -> None:
    _, records = tail(capsys, log, "--status", "refused")
    assert [r["seq"] for r in records] == [5]


def test_filters_combine_and_n_keeps_the_last_matches(log, capsys) -> None:
    _, both = tail(capsys, log, "--tool", "plan_to_pose", "--principal", "bob")
    _, last = tail(capsys, log, "--tool", "plan_to_pose", "-n", "1")
    assert [r["seq"] for r in both] == [3]
    assert [r["seq"] for r in last] == [3]


def test_since_keeps_records_written_at_or_after_the_time(log, capsys) -> None:
    _, future = tail(capsys, log, "--since", "2999-01-01")
    _, past = tail(capsys, log, "--since", "2000-01-01T00:00:00Z")
    assert future == []
    assert [r["seq"] for r in past] == [1, 2, 3, 4, 5]


def test_a_malformed_since_exits_2(log, capsys) -> None:
    assert main(["audit", "tail", str(log), "--since", "yesterday"]) == 2
    assert "ISO 8601" in capsys.readouterr().err


def test_since_without_a_zone_is_utc_and_a_zone_is_honoured() -> None:
    assert parse_since("2026-11-24T04:00") == parse_since("2026-11-24T06:00+02:00")
    record = {"wall_time": "2026-11-24T04:00:00.000001Z"}
    assert RecordFilter(since=parse_since("2026-11-24T04:00Z")).matches(record)
    assert not RecordFilter(since=parse_since("2026-11-24T04:00:01Z")).matches(record)


def test_a_record_with_a_lone_surrogate_is_printed_as_its_escape_not_a_traceback(tmp_path: Path) -> None:
    """Only a damaged or forged file holds one (the writer replaces them); tail must still print."""
    import subprocess
    import sys

    from tests.helpers import REPO, child_env

    path = tmp_path / "forged.jsonl"
    path.write_text('{"seq":1,"tool":"\\ud800","outcome":"ok"}\n', encoding="ascii")
    shown = subprocess.run([sys.executable, "-m", "armwarden.cli", "audit", "tail", str(path)], capture_output=True,
                           cwd=REPO, env=child_env(), timeout=60)
    assert shown.returncode == 0, shown.stderr.decode()
    assert json.loads(shown.stdout)["tool"] == "\ud800"  # the escape it was read from, read back the same
