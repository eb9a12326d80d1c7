"""A deliberately broken `armwarden` command line for the fuzz tests: the real daemon, but the
server writes no tool-call record for `get_robot_state` (patched in this process only).

Test-only on purpose: nothing in the shipped daemon can switch auditing off, so the fuzz's
unaudited-call check is shown to catch a missing record through this module, which the test
passes as `FuzzOptions.daemon_command` (`python -m tests.evaluation.unaudited_daemon serve ...`).
"""

from __future__ import annotations

import sys
from typing import Any

from armwarden.cli import main
from armwarden.server.app import ArmWardenServer

#: the tool whose calls go unrecorded (the fuzz harness's first call is always one)
UNRECORDED_TOOL = "get_robot_state"

def break_auditing() -> None:
    """Patch this process's server to skip the records of `UNRECORDED_TOOL`. Called only when run
    as the daemon: importing this module (for `UNRECORDED_TOOL`) must not break the importing
    test process's auditing (it once did, and every later server test in that worker lost its
    `get_robot_state` records)."""
    audit = ArmWardenServer._audit

    async def audit_all_but_one(self: ArmWardenServer, record: Any) -> None:
        if record.tool == UNRECORDED_TOOL:
            return
        await audit(self, record)

    ArmWardenServer._audit = audit_all_but_one  # type: ignore[method-assign]


if __name__ == "__main__":
    break_auditing()
    sys.exit(main())
