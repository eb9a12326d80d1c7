"""kill -9 of a real `armwarden serve` (stdio) right after a reply: the records that must be on
disk before their reply are in the file, and the chain verifies; read-only records get there
within their group-commit window, or with the next record that must be on disk."""

from __future__ import annotations

import signal
import subprocess
import time
from pathlib import Path
from typing import Any

from armwarden.audit import verify_file
from tests.helpers import records_of
from tests.server.test_daemon_stdio import RawStdio, start_raw_daemon


def call(rpc: RawStdio, tool: str, arguments: dict[str, Any]) -> dict[str, Any]:
    answer = rpc.request("tools/call", {"name": tool, "arguments": arguments})
    assert "result" in answer, answer
    return answer["result"]


def kill_at_once(process: subprocess.Popen) -> None:
    """SIGKILL: no shutdown record, no flush, no goodbye."""
    process.send_signal(signal.SIGKILL)
    process.wait(timeout=20)
    assert process.stdout is not None
    process.stdout.close()
    if process.stdin is not None:
        process.stdin.close()


def tool_records(path: Path) -> list[dict[str, Any]]:
    report = verify_file(path)
    assert report.ok, f"chain broken at line {report.first_bad_line}: {report.reason}"
    records = records_of(path)
    assert records[-1]["event"] != "shutdown"  # it really died without a goodbye
    return [r for r in records if r["event"] == "tool_call"]


def test_an_estop_answered_is_on_record_after_a_kill_right_after_the_reply(tmp_path) -> None:
    process, rpc, audit = start_raw_daemon(tmp_path, speedup=10.0)
    try:
        assert not call(rpc, "estop", {"reason": "kill test"}).get("isError")
    finally:
        kill_at_once(process)
    last = tool_records(audit)[-1]
    assert (last["tool"], last["outcome"]) == ("estop", "ok")


def test_an_executed_move_is_on_record_after_a_kill_right_after_the_reply(tmp_path) -> None:
    process, rpc, audit = start_raw_daemon(tmp_path, speedup=10.0)
    try:
        plan = call(rpc, "plan_to_pose", {"position": {"x": 0.3069, "y": 0.0, "z": 0.45}})["structuredContent"]
        assert plan["status"] == "ok", plan
        done = call(rpc, "execute_plan", {"plan_id": plan["plan_id"]})
        assert done["structuredContent"]["status"] == "succeeded", done
    finally:
        kill_at_once(process)
    records = tool_records(audit)
    assert [r["tool"] for r in records[-2:]] == ["plan_to_pose", "execute_plan"]  # the plan came along
    assert records[-1]["outcome"] == "ok"


def test_a_refused_execute_is_on_record_after_a_kill_right_after_the_reply(tmp_path) -> None:
    process, rpc, audit = start_raw_daemon(tmp_path, speedup=10.0)
    try:
        assert call(rpc, "execute_plan", {"plan_id": "plan_nope"}).get("isError")
    finally:
        kill_at_once(process)
    last = tool_records(audit)[-1]
    assert (last["tool"], last["outcome"]) == ("execute_plan", "refused")


def test_read_only_records_before_an_estop_are_on_record_with_it_after_a_kill(tmp_path) -> None:
    process, rpc, audit = start_raw_daemon(tmp_path, speedup=10.0)
    try:
        for _ in range(3):
            call(rpc, "get_robot_state", {})
        call(rpc, "estop", {"reason": "kill test"})
    finally:
        kill_at_once(process)
    assert [r["tool"] for r in tool_records(audit)[-4:]] == ["get_robot_state"] * 3 + ["estop"]


def test_a_read_only_record_reaches_the_file_on_its_own_and_the_chain_verifies_after_a_kill(tmp_path) -> None:
    process, rpc, audit = start_raw_daemon(tmp_path, speedup=10.0)
    try:
        call(rpc, "get_safety_status", {})
        deadline = time.monotonic() + 20  # a bound on a hung test, not a timing threshold
        while not any(r.get("tool") == "get_safety_status" for r in records_of(audit)):
            assert time.monotonic() < deadline, "the read-only record never reached the file"
            time.sleep(0.005)
    finally:
        kill_at_once(process)
    assert tool_records(audit)[-1]["tool"] == "get_safety_status"
