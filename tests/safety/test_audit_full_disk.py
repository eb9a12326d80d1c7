"""The audit log on a disk that fills up (the `disk` seam with `tests.fulldisk.SmallDisk`).

A full disk is the common way an audit log stops working: the write that does not fit fails
with ENOSPC, possibly after part of the line was written. The log must then refuse every later
record and say why, and a restart with room again must recover the torn line.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from armwarden.audit import AuditLog, AuditWriteError, read_tail, verify_file
from tests.fulldisk import SmallDisk


def test_a_full_disk_breaks_the_log_and_the_log_says_why_it_is_unusable(tmp_path: Path) -> None:
    disk = SmallDisk()
    with AuditLog(tmp_path / "audit.jsonl", disk=disk) as log:
        log.append("startup")
        assert log.unusable is None
        disk.fill()
        with pytest.raises(AuditWriteError, match="No space left on device"):
            log.append("tool_call")
        assert log.unusable is not None and "No space left on device" in log.unusable
        with pytest.raises(AuditWriteError, match="unusable"):  # never past a hole
            log.append("tool_call")
    assert disk.refused == 1  # the second record was refused by the log, not tried on the disk
    assert verify_file(tmp_path / "audit.jsonl").records == 1


def test_a_record_cut_short_by_a_full_disk_is_recovered_when_there_is_room_again(tmp_path: Path) -> None:
    path = tmp_path / "audit.jsonl"
    with AuditLog(path) as log:
        log.append("startup")
    size = path.stat().st_size
    with AuditLog(path, disk=SmallDisk(free_bytes=40)) as log:  # the next line does not fit: 40 bytes of it land
        with pytest.raises(AuditWriteError, match="No space left on device"):
            log.append("tool_call", tool="estop")
    assert path.stat().st_size == size + 40
    with AuditLog(path) as log:  # restarted with room: the torn line is named and the chain goes on
        recovery = log.recovery_record
        assert recovery is not None and recovery.extra is not None and recovery.extra["torn_bytes"] == 40
        log.append("startup")
    assert verify_file(path).ok
    assert [r["event"] for r in read_tail(path, 10)] == ["startup", "recovery", "startup"]


def test_a_closed_log_says_it_is_unusable(tmp_path: Path) -> None:
    log = AuditLog(tmp_path / "audit.jsonl")
    log.close()
    assert log.unusable is not None and "closed" in log.unusable
