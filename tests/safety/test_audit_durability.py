"""The audit log's durability classes: read-only calls' records are group-committed within a
window nobody waits for; every other record is on disk before its caller is answered."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import pytest

from armwarden.audit import AuditLog, AuditWriteError, verify_file

#: how long a test waits for something the writer thread does on its own (not a timing threshold:
#: only a bound on a hung test)
PATIENCE_S = 10.0


class FsyncSpy:
    """Stands in for `os.fsync` in the audit log: records which records were in the file at each
    fsync, and can hold an fsync until released (a stalled disk)."""

    def __init__(self, path: Path, *, hold: bool = False) -> None:
        self.path = path
        self.synced: list[list[str]] = []
        self.entered = threading.Event()
        self.release = threading.Event()
        if not hold:
            self.release.set()

    def __call__(self, fd: int) -> None:
        self.entered.set()
        self.release.wait(PATIENCE_S)
        self.synced.append(events_in(self.path))


def events_in(path: Path) -> list[str]:
    return [json.loads(line)["event"] for line in path.read_text().splitlines() if line.strip()]


def wait_until(predicate) -> None:
    event = threading.Event()
    for _ in range(int(PATIENCE_S / 0.005)):
        if predicate():
            return
        event.wait(0.005)
    raise AssertionError("the writer thread did not get there")


def test_a_read_only_record_is_fsynced_within_the_window_without_any_later_record(tmp_path, monkeypatch) -> None:
    path = tmp_path / "audit.jsonl"
    spy = FsyncSpy(path)
    monkeypatch.setattr("armwarden.audit.log.os.fsync", spy)
    with AuditLog(path, commit_window_s=0.05) as log:
        log.append_soon("tool_call", tool="get_robot_state", outcome="ok")
        wait_until(lambda: any("tool_call" in synced for synced in spy.synced))
    assert verify_file(path).ok


def test_a_read_only_record_does_not_wait_for_a_stalled_disk(tmp_path, monkeypatch) -> None:
    path = tmp_path / "audit.jsonl"
    log = AuditLog(path, commit_window_s=0.001)
    spy = FsyncSpy(path, hold=True)
    monkeypatch.setattr("armwarden.audit.log.os.fsync", spy)
    log.append_soon("tool_call", tool="get_robot_state", outcome="ok")
    assert spy.entered.wait(PATIENCE_S)  # its fsync is under way and stuck
    log.append_soon("tool_call", tool="get_safety_status", outcome="ok")  # still accepted at once
    spy.release.set()
    log.close()
    assert events_in(path)[-2:] == ["tool_call", "tool_call"]
    assert verify_file(path).ok


@pytest.mark.anyio
async def test_a_record_that_must_be_on_disk_carries_the_read_only_records_before_it(tmp_path, monkeypatch) -> None:
    path = tmp_path / "audit.jsonl"
    spy = FsyncSpy(path)
    monkeypatch.setattr("armwarden.audit.log.os.fsync", spy)
    with AuditLog(path, commit_window_s=1.0) as log:  # a window long enough never to close by itself here
        log.append_soon("read", outcome="ok")
        await log.append_async("estop", outcome="latched")
        assert spy.synced and spy.synced[-1][-2:] == ["read", "estop"]
    assert verify_file(path).ok


def test_closing_the_log_fsyncs_the_records_of_an_open_window(tmp_path, monkeypatch) -> None:
    path = tmp_path / "audit.jsonl"
    spy = FsyncSpy(path)
    monkeypatch.setattr("armwarden.audit.log.os.fsync", spy)
    log = AuditLog(path, commit_window_s=1.0)
    log.append_soon("read", outcome="ok")
    log.close()
    assert spy.synced and spy.synced[-1][-1] == "read"


def test_a_failed_fsync_of_a_window_breaks_the_log_and_the_next_record_is_refused(tmp_path, monkeypatch) -> None:
    path = tmp_path / "audit.jsonl"

    def broken_fsync(fd: int) -> None:
        raise OSError(5, "simulated I/O error")

    log = AuditLog(path, commit_window_s=0.001)
    monkeypatch.setattr("armwarden.audit.log.os.fsync", broken_fsync)
    log.append_soon("read", outcome="ok")
    wait_until(lambda: log.broken is not None)
    with pytest.raises(AuditWriteError):
        log.append_soon("read", outcome="ok")
    with pytest.raises(AuditWriteError):
        log.append("estop", outcome="latched")
    monkeypatch.undo()
    log.close()


@pytest.mark.anyio
async def test_the_tail_includes_a_read_only_record_handed_over_just_before(tmp_path) -> None:
    with AuditLog(tmp_path / "audit.jsonl", commit_window_s=1.0) as log:
        log.append_soon("tool_call", tool="get_robot_state", outcome="ok")
        tail = await log.tail_async(1)
    assert tail[-1]["tool"] == "get_robot_state"


def test_flush_puts_the_records_of_an_open_window_on_disk_at_once(tmp_path, monkeypatch) -> None:
    path = tmp_path / "audit.jsonl"
    spy = FsyncSpy(path)
    monkeypatch.setattr("armwarden.audit.log.os.fsync", spy)
    with AuditLog(path, commit_window_s=1.0) as log:
        log.append_soon("read", outcome="ok")
        log.flush()
        assert spy.synced and spy.synced[-1][-1] == "read"


def test_a_read_only_record_to_a_closed_log_is_refused(tmp_path) -> None:
    log = AuditLog(tmp_path / "audit.jsonl")
    log.close()
    with pytest.raises(AuditWriteError):
        log.append_soon("read", outcome="ok")


@pytest.mark.parametrize("window", [-0.001, 1.5, float("nan"), True, "0.02"])
def test_a_commit_window_outside_zero_to_one_second_is_refused(tmp_path, window) -> None:
    from armwarden.core.errors import ConfigurationError

    with pytest.raises(ConfigurationError, match="commit_window_s"):
        AuditLog(tmp_path / "audit.jsonl", commit_window_s=window)
    assert not (tmp_path / "audit.jsonl").exists()
