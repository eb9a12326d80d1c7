"""`AuditLog.submit`: records handed over from other threads without waiting (the stop channel's path)."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import pytest

from armwarden.audit import AuditLog, AuditWriteError, verify_file


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


def test_a_record_submitted_while_the_log_closes_is_refused_not_reordered_or_lost(tmp_path: Path, monkeypatch) -> None:
    audit = AuditLog(tmp_path / "audit.jsonl")
    release = threading.Event()
    append = audit._append

    def slow_first(entry, *, sync):
        if entry.event == "slow":
            release.wait(10)
        return append(entry, sync=sync)

    monkeypatch.setattr(audit, "_append", slow_first)
    audit.submit("slow")  # the writer thread is busy with it
    closer = threading.Thread(target=audit.close)
    closer.start()
    deadline = time.monotonic() + 10
    while audit._writer_thread is not None:  # close() has taken the writer and waits for it
        assert time.monotonic() < deadline
        time.sleep(0.001)
    with pytest.raises(AuditWriteError):
        audit.submit("estop", outcome="latched")
    release.set()
    closer.join(10)
    events = [record["event"] for record in log_records(tmp_path / "audit.jsonl")]
    assert events[-1] == "slow" and "estop" not in events
    assert not [t for t in threading.enumerate() if t.name == "armwarden-audit" and t.is_alive()]


def test_a_record_being_handed_over_when_the_log_closes_is_written_not_lost(tmp_path: Path, monkeypatch) -> None:
    """`close` cannot slip its stop marker in between the closing check and the queueing of a
    record another thread is handing over: the record lands before the marker and is written."""
    audit = AuditLog(tmp_path / "audit.jsonl")
    audit.submit("first")
    audit.flush()
    writer = audit._writer_thread
    assert writer is not None
    queueing, go_on = threading.Event(), threading.Event()
    put = writer.put

    def slow_put(job):
        if not queueing.is_set():
            queueing.set()
            go_on.wait(10)  # another thread closes the log meanwhile
        put(job)

    monkeypatch.setattr(writer, "put", slow_put)
    submitter = threading.Thread(target=audit.submit, args=("handed-over",))
    submitter.start()
    assert queueing.wait(10)
    closer = threading.Thread(target=audit.close)
    closer.start()
    closer.join(0.2)  # close waits for the hand-over in progress
    go_on.set()
    submitter.join(10)
    closer.join(10)
    assert not closer.is_alive()
    events = [record["event"] for record in log_records(tmp_path / "audit.jsonl")]
    assert events[-1] == "handed-over"
