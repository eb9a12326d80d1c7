"""`AuditLog.submit`: records handed over from other threads without waiting (the stop channel's path)."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import pytest

from armwarden.safety.audit import AuditLog, AuditWriteError, verify_file


def test_a_record_submitted_from_another_thread_is_on_disk_after_close(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    log = AuditLog(path)
    thread = threading.Thread(target=log.submit, args=("estop",), kwargs={"outcome": "latched", "detail": "stop channel"})
    thread.start()
    thread.join()
    log.close()  # the writer thread drains what was queued before it stops
    records = [line for line in path.read_text().splitlines() if '"estop"' in line]
    assert len(records) == 1 and '"latched"' in records[0]
    assert verify_file(path).ok


@pytest.mark.anyio
async def test_submitted_and_awaited_records_share_one_chain_in_call_order(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    log = AuditLog(path)
    await log.append_async("first", outcome="ok")
    log.submit("second", outcome="ok")
    third = await log.append_async("third", outcome="ok")
    log.close()
    events = [record["event"] for record in log_records(path)]
    assert events[-3:] == ["first", "second", "third"]
    assert third.seq == log_records(path)[-1]["seq"]
    assert verify_file(path).ok


def test_submit_to_a_closed_log_is_refused(tmp_path: Path) -> None:
    log = AuditLog(tmp_path / "audit.jsonl")
    log.close()
    with pytest.raises(AuditWriteError):
        log.submit("estop", outcome="latched")


def log_records(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
