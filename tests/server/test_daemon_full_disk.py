"""`armwarden serve` over stdio whose audit log meets a real limit of the kernel (issue 24, item 2).

The daemon runs with RLIMIT_FSIZE set to 192 KiB (`setrlimit`, no root needed, every Linux CI
runner has it): the kernel takes the audit log's last write up to the limit and then refuses
every byte more (EFBIG), as a full 192 KiB tmpfs would with ENOSPC — a torn line included. The
log starts a few KiB short of the limit, so the first calls fill it. Then an e-stop still latches
and answers success with the warning, a reset is refused and leaves the e-stop latched, the
safety status says the log is unusable, and a restart with room recovers the torn tail.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, cast

import anyio
import pytest
from mcp import Client, StdioServerParameters

import armwarden
from armwarden.safety.audit import AuditLog, verify_file
from tests.helpers import REPO, text_of
from tests.server.harness import MODES, approve

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
    assert audit.stat().st_size == LIMIT_BYTES  # the kernel took bytes up to its limit: a torn last line

    with AuditLog(audit) as log:  # restarted with room: the torn tail is named, the chain goes on
        assert log.recovery_record is not None
    assert verify_file(audit).ok
    assert b"estop_release" not in audit.read_bytes()
