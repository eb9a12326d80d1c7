"""`armwarden serve` over stdio whose audit log meets a real limit of the kernel (issue 24, item 2).

The daemon runs with RLIMIT_FSIZE set to 192 KiB (`setrlimit`, no root needed, every Linux CI
runner has it): the kernel takes the audit log's last write up to the limit and then refuses
every byte more (EFBIG), as a full 192 KiB tmpfs would with ENOSPC — a torn line included. The
log starts a few KiB short of the limit, so the first calls fill it. Then an e-stop still latches
and answers success with the warning, a reset is refused and leaves the e-stop latched, the
safety status says the log is unusable, and a restart with room recovers the torn tail. At
shutdown the final record cannot be written either: the daemon stops the arm, closes the log,
says so and exits with `EXIT_AUDIT_INCOMPLETE` (not "refusing to start", status 2).
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any, cast

import anyio
import pytest
from mcp import Client, StdioServerParameters

import armwarden
from armwarden.audit import AuditLog, verify_file
from armwarden.daemon.shutdown import EXIT_AUDIT_INCOMPLETE, close_assembly
from armwarden.daemon.startup import Assembly
from tests.fulldisk import SmallDisk
from tests.helpers import REPO, stop_process, text_of
from tests.server.harness import MODES, approve, arm_harness

pytestmark = pytest.mark.anyio

LIMIT_BYTES = 192 * 1024
#: room left in the log when the daemon starts: its start-up records and a few calls fit
HEADROOM_BYTES = 6 * 1024
#: the daemon, started with the file size limit (kept across exec)
LIMITED_SERVE = (
    "import os, resource, sys; "
    f"resource.setrlimit(resource.RLIMIT_FSIZE, ({LIMIT_BYTES}, {LIMIT_BYTES})); "
    "os.execv(sys.executable, [sys.executable, '-m', 'armwarden.cli', 'serve', *sys.argv[1:]])"
)


def nearly_full_log(path: Path) -> None:
    """An intact audit log `HEADROOM_BYTES` short of the limit."""
    with AuditLog(path) as log:
        while path.stat().st_size < LIMIT_BYTES - HEADROOM_BYTES:
            log.append("padding", detail="x" * 400)


def limited_daemon(audit: Path, tmp_path: Path) -> StdioServerParameters:
    config = tmp_path / "fake.yaml"
    config.write_text("speedup: 20\n", encoding="utf-8")
    return StdioServerParameters(
        command=sys.executable,
        args=["-c", LIMITED_SERVE, "--audit-log", str(audit), "--backend-config", str(config), "--log-level", "ERROR"],
        env={"PYTHONPATH": str(Path(armwarden.__file__).parents[1])},  # the armwarden this test imports
        cwd=str(REPO),
    )


async def status(client: Client) -> dict[str, Any]:
    result = await client.call_tool("get_safety_status", {})
    assert not result.is_error, text_of(result)
    return result.structured_content


@pytest.mark.parametrize("mode", MODES)
async def test_a_daemon_whose_audit_log_hits_the_kernels_limit_keeps_the_estop_latched_and_says_so(tmp_path, mode) -> None:
    audit = tmp_path / "audit.jsonl"
    nearly_full_log(audit)
    human = approve("erin")
    with anyio.fail_after(60):
        async with Client(limited_daemon(audit, tmp_path), mode=mode, elicitation_callback=cast(Any, human)) as client:
            for _ in range(500):  # small records until the log is full (each ~0.4 KiB; 6 KiB of room)
                if not (await status(client))["audit_ok"]:
                    break
            else:
                pytest.fail("the audit log never filled up")
            estop = await client.call_tool("estop", {"reason": "the audit disk is full"})
            reset = await client.call_tool("reset_estop", {})
            after = await status(client)

    assert not estop.is_error, text_of(estop)
    assert estop.structured_content["estopped"] is True and "File too large" in estop.structured_content["audit_error"]
    assert "is latched and in force" in text_of(estop)
    assert reset.is_error and "AUDIT_UNAVAILABLE" in text_of(reset) and "stays latched" in text_of(reset)
    assert human.prompts == []  # type: ignore[attr-defined]  # a release that cannot be recorded is not asked for
    assert after["estopped"] is True and after["audit_ok"] is False
    assert after["estop_event"]["number"] == estop.structured_content["estop_event"]["number"]
    assert audit.stat().st_size == LIMIT_BYTES  # the kernel took bytes up to its limit
    # mostly mid-record (a torn last line); now and then a record ends exactly at the limit and the
    # next write is refused whole (CI saw it once): then there is nothing torn to recover
    torn = not audit.read_bytes().endswith(b"\n")

    with AuditLog(audit) as log:  # restarted with room: a torn tail is named, the chain goes on
        assert (log.recovery_record is not None) == torn
    assert verify_file(audit).ok
    assert b"estop_release" not in audit.read_bytes()


class RawStdioClient:
    """The limited daemon on stdio, spoken to line by line (its exit status is the point)."""

    def __init__(self, audit: Path, tmp_path: Path) -> None:
        params = limited_daemon(audit, tmp_path)
        self.stderr_path = tmp_path / "stderr.log"  # a file: a pipe nobody reads while the log fills would block
        with open(self.stderr_path, "wb") as stderr:
            self.process = subprocess.Popen([params.command, *params.args], cwd=params.cwd, env=params.env,
                                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=stderr)
        self.next_id = 0
        self.call("initialize", {"protocolVersion": "2025-11-25", "capabilities": {},
                                 "clientInfo": {"name": "raw-full-disk-test", "version": "1"}})
        self.send({"jsonrpc": "2.0", "method": "notifications/initialized"})

    def send(self, message: dict[str, Any]) -> None:
        assert self.process.stdin is not None
        self.process.stdin.write(json.dumps(message).encode() + b"\n")
        self.process.stdin.flush()

    def call(self, method: str, params: dict[str, Any]) -> dict[str, Any]:
        """Send a request; its answer (notifications before it are skipped)."""
        assert self.process.stdout is not None
        self.next_id += 1
        self.send({"jsonrpc": "2.0", "id": self.next_id, "method": method, "params": params})
        while True:
            line = self.process.stdout.readline()
            assert line, "the daemon closed its stdout"
            message = json.loads(line)
            if message.get("id") == self.next_id:
                return message

    def fill_the_log(self) -> None:
        for _ in range(500):  # small records until the log is full (each ~0.4 KiB; 6 KiB of room)
            answer = self.call("tools/call", {"name": "get_safety_status", "arguments": {}})
            if not answer["result"]["structuredContent"]["audit_ok"]:
                return
        pytest.fail("the audit log never filled up")


@pytest.mark.parametrize("ending", ["end of stdin", "SIGTERM"])
def test_a_daemon_whose_final_record_cannot_be_written_stops_closes_the_log_and_says_so(tmp_path, ending) -> None:
    """Found by another engineer: the final record's failure escaped as "refusing to start: ...",
    exit status 2, and the log was left open."""
    audit = tmp_path / "audit.jsonl"
    nearly_full_log(audit)
    client = RawStdioClient(audit, tmp_path)
    try:
        client.fill_the_log()
        if ending == "SIGTERM":
            client.process.send_signal(signal.SIGTERM)
        client.process.communicate(timeout=60)  # closes its stdin: the end of the session either way
    finally:
        stop_process(client.process, 10)
    stderr = client.stderr_path.read_text(errors="replace")

    assert client.process.returncode == EXIT_AUDIT_INCOMPLETE, stderr[-2000:]
    assert "final audit record could not be written: " in stderr and "File too large" in stderr
    assert "the arm was stopped" in stderr
    assert "refusing to start" not in stderr
    with AuditLog(audit) as log:  # closed: a restart takes the log at once and recovers its torn tail
        assert log.recovery_record is not None


@pytest.mark.anyio
async def test_closing_the_assembly_on_a_full_disk_stops_the_arm_closes_the_log_and_says_why(tmp_path) -> None:
    disk = SmallDisk()
    async with arm_harness(tmp_path, audit_disk=disk) as arm:
        assembly = Assembly(arm.guard.policy, arm.backend, arm.audit, arm.guard, arm.server)
        disk.fill()

        lost = await close_assembly(assembly, "signal SIGTERM")

        assert lost is not None and "No space left on device" in lost
        assert arm.audit.closed
        assert arm.backend.stops == 1
        assert await close_assembly(assembly, "again") is None  # twice is safe: nothing more to say
