"""Shutdown: stop the arm and the gripper, close the backend, record the counts of refusals left
out, write the final audit record and close the log; and what `serve` says and returns when that
record could not be written."""

from __future__ import annotations

import logging

import anyio

from armwarden.audit import AuditWriteError
from armwarden.core.errors import ArmWardenError
from armwarden.daemon.startup import Assembly

logger = logging.getLogger("armwarden")

#: the daemon served, then stopped the arm and closed everything, but its final audit record
#: (`shutdown`) could not be written (e.g. the audit disk is full): the log ends without it
EXIT_AUDIT_INCOMPLETE = 3


#: after SIGTERM/SIGINT on stdio: time for cancelled calls to stop the arm and audit themselves [s]
SIGNAL_GRACE_S = 0.3


class FinalRecordLost(ArmWardenError):
    """The daemon shut down (arm stopped, backend and log closed) without its final audit record."""


def final_record_lost_message(why: str) -> str:
    """What `serve` says on stderr as it exits with `EXIT_AUDIT_INCOMPLETE`."""
    return (f"armwarden: final audit record could not be written: {why}; the backend and the audit log are "
            f"closed (exit status {EXIT_AUDIT_INCOMPLETE})")


async def close_assembly(assembly: Assembly, why: str) -> str | None:
    """Stop the arm and gripper, close the backend, record the counts of refusals left out, write
    the final record and close the log. Returns None, or why the final record could not be
    written and whether the arm was stopped (the log is closed all the same). Safe to call twice."""
    with anyio.CancelScope(shield=True):
        detail, stopped = why, "the arm was stopped"
        try:
            await assembly.backend.stop()
        except Exception as exc:  # the shutdown must go on; the record says the stop failed
            detail, stopped = f"{why}; stop failed: {exc}", f"the stop at shutdown FAILED: {exc}"
            logger.error("stop at shutdown failed: %s", exc)
        await assembly.backend.close()
        for reports in assembly.refusal_reports:  # handed to the writer before the final record
            reports.close()
        if assembly.audit.closed:
            return None
        try:
            await assembly.audit.append_async("shutdown", outcome="ok", detail=detail)
        except AuditWriteError as exc:  # the arm is stopped either way; the log must still be closed
            return f"{exc}; {stopped}"
        finally:
            assembly.audit.close()
        return None
