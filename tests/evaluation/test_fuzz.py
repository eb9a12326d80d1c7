"""`armwarden eval`'s fuzzing: a small run against the real daemon over stdio (no findings), and a
deliberately broken daemon caught; the audit and journal readers it counts with."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any, cast

import anyio
import pytest

from armwarden.evaluation.fuzz import (
    FuzzOptions,
    FuzzSession,
    TransportResult,
    as_sent,
    audit_calls,
    run_fuzz,
    short_repr,
    unaudited_calls,
)
from armwarden.evaluation.journal import JournalReader
from armwarden.evaluation.runner import EvalOptions
from armwarden.evaluation.schemas import conforms
from armwarden.policy import bundled_policy, load_policy
from tests.evaluation.unaudited_daemon import UNRECORDED_TOOL
from tests.helpers import REPO, SRC

#: a daemon start-up and ~100 calls on a loaded 2-core machine (no timing is asserted)
RUN_TIMEOUT_S = 900


def test_unaudited_calls_are_the_gaps_in_the_records() -> None:
    assert unaudited_calls(["a", "b", "a", "c"], ["a", "a", "c"]) == [1]
    assert unaudited_calls(["a", "b"], ["a", "b"]) == []
    assert unaudited_calls(["a", "b"], []) == [0, 1]


def test_audit_and_journal_lines_split_on_newlines_only(tmp_path) -> None:
    audit = tmp_path / "audit.jsonl"
    records = [{"event": "tool_call", "tool": "camera_snapshot", "arguments": {"camera": "a\u2028b\x85c\x1cd"}},
               {"event": "request_refused", "tool": "estop", "extra": {"not_reported_since_last": 2}},
               {"event": "startup", "tool": None}]
    audit.write_text("".join(json.dumps(r, ensure_ascii=False) + "\n" for r in records), encoding="utf-8")
    assert audit_calls(audit) == ["camera_snapshot", "estop", "estop", "estop"]
    journal = tmp_path / "journal.jsonl"
    reader = JournalReader(journal)
    journal.write_text('{"t": 1, "call": "execute", "kind": "actuation"}\n{"t": 2, "ca', encoding="utf-8")
    assert [e.call for e in reader.new_entries()] == ["execute"]
    with journal.open("a", encoding="utf-8") as handle:
        handle.write('ll": "stop", "kind": "stop"}\n')
    assert [e.call for e in reader.new_entries()] == ["stop"]


def test_a_finding_names_a_shortened_argument() -> None:
    text = short_repr({"plan_id": "x" * 1_000_000})
    assert len(text) < 200 and "chars)" in text


def _options() -> EvalOptions:
    policy = bundled_policy()
    return EvalOptions(policy_path=policy.resolve(), policy=load_policy(policy), backend="fake", backend_config=None,
                       safe_count=0, seed=0)


@pytest.fixture
def daemon_env(monkeypatch) -> None:
    """The daemon subprocess imports this checkout (and the tests package, for the broken daemon)."""
    monkeypatch.setenv("PYTHONPATH", f"{SRC}:{REPO}")
    monkeypatch.delenv("ARMWARDEN_AUDIT_KEY", raising=False)


@pytest.mark.timeout(RUN_TIMEOUT_S)
def test_a_small_stdio_fuzz_run_has_no_findings(tmp_path, daemon_env) -> None:
    fuzz = FuzzOptions(calls=100, seed=7, transports=("stdio",), estop_every=25, workdir=tmp_path)
    result = anyio.run(run_fuzz, _options(), fuzz)
    report = result.report()
    run = report["per_transport"]["stdio"]
    assert run["findings"] == [], run["findings"]
    assert (report["calls"], report["crashes"], report["unaudited"], report["actuations"],
            report["estop_unanswered"]) == (100, 0, 0, 0, 0)
    assert result.ok
    assert run["valid"] > 0 and run["invalid"] > 0
    assert run["estop_checks"] == 100 // 25 + 1  # every 25 calls and at the end
    assert run["audit_records"] == run["calls"] + run["harness_calls"]
    assert run["rss_start_mb"] > 0 and run["rss_end_mb"] > 0


@pytest.mark.timeout(RUN_TIMEOUT_S)
def test_a_daemon_that_skips_a_record_is_caught(tmp_path, daemon_env) -> None:
    broken = (sys.executable, "-m", "tests.evaluation.unaudited_daemon")
    fuzz = FuzzOptions(calls=20, seed=7, transports=("stdio",), estop_every=10, daemon_command=broken,
                       workdir=tmp_path)
    result = anyio.run(run_fuzz, _options(), fuzz)
    run = result.per_transport["stdio"]
    assert not result.ok
    assert run.unaudited >= 1
    assert {f.tool for f in run.findings if f.kind == "unaudited"} == {UNRECORDED_TOOL}
    assert result.report()["unaudited"] == run.unaudited


def _session(journal: Path) -> FuzzSession:
    return FuzzSession(cast("Any", None), TransportResult("stdio"), journal, None, FuzzOptions(calls=1, seed=0), 0.0)


def test_only_a_valid_gripper_call_may_actuate(tmp_path) -> None:
    journal = tmp_path / "journal.jsonl"
    session = _session(journal)

    def journal_line(call: str, kind: str = "actuation") -> None:
        with journal.open("a", encoding="utf-8") as handle:
            handle.write(json.dumps({"t": 0.0, "call": call, "kind": kind}) + "\n")

    journal_line("gripper_move")
    session._check_journal("gripper_move", {"width_m": 0.01}, True)  # allowed by the policy, no approval
    journal_line("stop", "stop")
    journal_line("emergency_stop", "estop")
    session._check_journal("estop", {}, False)  # stops are not actuations
    assert (session.result.allowed_gripper_actuations, session.result.actuations) == (1, 0)
    journal_line("gripper_move")
    session._check_journal("gripper_move", {"width_m": 1.0}, False)  # invalid arguments reached the backend
    journal_line("execute")
    session._check_journal("execute_plan", {"plan_id": "p"}, True)  # every approval is declined
    assert session.result.actuations == 2
    assert [(f.kind, f.tool) for f in session.result.findings] == [("actuation", "gripper_move"),
                                                                    ("actuation", "execute_plan")]


def test_a_non_finite_value_is_judged_as_the_client_sends_it() -> None:
    schema = {"type": "object", "required": ["width_m"], "properties": {
        "width_m": {"type": "number", "minimum": 0.0, "maximum": 0.08},
        "speed_mps": {"anyOf": [{"type": "number", "minimum": 0.001, "maximum": 0.1}, {"type": "null"}]}}}
    # NaN in an optional, nullable field reaches the daemon as null: a valid call that may move the fingers
    assert as_sent({"width_m": 0.01, "speed_mps": math.nan}) == {"width_m": 0.01, "speed_mps": None}
    assert conforms(schema, as_sent({"width_m": 0.01, "speed_mps": math.inf}))
    assert not conforms(schema, as_sent({"width_m": math.nan}))  # null where a number is required


def test_importing_the_broken_daemon_leaves_this_process_auditing() -> None:
    from armwarden.server.app import ArmWardenServer
    from tests.evaluation import unaudited_daemon

    assert ArmWardenServer._audit.__module__ == "armwarden.server.app"  # pyright: ignore[reportPrivateUsage]
    assert unaudited_daemon.UNRECORDED_TOOL == "get_robot_state"
