"""Which replies wait for the audit record's fsync, through the real middleware (in memory): a
read-only call is answered while the disk is stalled; an e-stop, an actuating call's refusal
and a tool nobody knows are not answered before their record is on disk."""

from __future__ import annotations

import os
import stat
import threading
from pathlib import Path

import anyio
import pytest

from armwarden.audit import AuditLog
from tests.server.harness import arm_harness


class StalledDisk:
    """`os.fsync` of the audit log held until released; counts the fsyncs that completed."""

    def __init__(self) -> None:
        self.entered = threading.Event()
        self.release = threading.Event()
        self.completed = 0

    def __call__(self, fd: int) -> None:
        if not stat.S_ISREG(os.fstat(fd).st_mode):  # the directory, when the log file is created
            return
        self.entered.set()
        self.release.wait(30)
        self.completed += 1


@pytest.fixture
def stalled_disk(monkeypatch) -> StalledDisk:
    disk = StalledDisk()
    monkeypatch.setattr("armwarden.audit.log.os.fsync", disk)
    return disk


@pytest.mark.anyio
async def test_a_read_only_call_is_answered_while_the_disk_is_stalled(tmp_path: Path, stalled_disk: StalledDisk) -> None:
    async with arm_harness(tmp_path) as arm:
        async with arm.client() as client:
            with anyio.fail_after(20):
                first = await client.call_tool("get_robot_state", {})
                await anyio.to_thread.run_sync(stalled_disk.entered.wait, 20)  # its group commit is stuck
                second = await client.call_tool("get_safety_status", {})
            assert not first.is_error and not second.is_error
            assert stalled_disk.completed == 0
            stalled_disk.release.set()


async def answered_only_after_the_fsync(arm, tool: str, arguments: dict, disk: StalledDisk) -> None:
    async with arm.client() as client:
        async with anyio.create_task_group() as group:
            answers: list = []

            async def call() -> None:
                answers.append(await client.call_tool(tool, arguments))

            group.start_soon(call)
            await anyio.to_thread.run_sync(disk.entered.wait, 20)  # its record is written, its fsync stuck
            await anyio.sleep(0.05)  # give a reply that did not wait every chance to arrive
            assert answers == []
            disk.release.set()
        assert disk.completed >= 1 and len(answers) == 1


@pytest.mark.anyio
async def test_an_estop_is_answered_only_after_its_record_is_on_disk(tmp_path: Path, stalled_disk: StalledDisk) -> None:
    async with arm_harness(tmp_path) as arm:
        await answered_only_after_the_fsync(arm, "estop", {"reason": "test"}, stalled_disk)


@pytest.mark.anyio
async def test_a_refused_execute_is_answered_only_after_its_record_is_on_disk(tmp_path: Path, stalled_disk: StalledDisk) -> None:
    async with arm_harness(tmp_path) as arm:
        await answered_only_after_the_fsync(arm, "execute_plan", {"plan_id": "plan_nope"}, stalled_disk)


@pytest.mark.anyio
async def test_a_call_of_an_unknown_tool_is_answered_only_after_its_record_is_on_disk(tmp_path: Path, stalled_disk: StalledDisk) -> None:
    async with arm_harness(tmp_path) as arm:
        await answered_only_after_the_fsync(arm, "launch_rocket", {}, stalled_disk)


@pytest.mark.anyio
async def test_with_a_zero_window_a_read_only_call_waits_for_its_record_too(tmp_path: Path, monkeypatch) -> None:
    original = AuditLog.__init__

    def strict(self, path, **kwargs) -> None:
        original(self, path, **(kwargs | {"commit_window_s": 0.0}))

    monkeypatch.setattr(AuditLog, "__init__", strict)
    disk = StalledDisk()
    monkeypatch.setattr("armwarden.audit.log.os.fsync", disk)
    async with arm_harness(tmp_path) as arm:
        await answered_only_after_the_fsync(arm, "get_robot_state", {}, disk)
