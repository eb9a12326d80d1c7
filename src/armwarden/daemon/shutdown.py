"""Shutdown: on a signal, or when the client leaves, stop the arm and the gripper, close the
backend, record the counts of refusals left out, write the final audit record and close the log;
and what `serve` says and returns when that record could not be written."""

from __future__ import annotations

import logging
import os
import signal
import sys
from collections.abc import Callable

import anyio

from armwarden.audit import AuditWriteError
from armwarden.core.errors import ArmWardenError
from armwarden.daemon.options import Transport
from armwarden.daemon.previous_run import SHUTDOWN_EVENT, shutdown_extra
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
        detail, stopped, arm_stopped = why, "the arm was stopped", True
        try:
            await assembly.backend.stop()
        except Exception as exc:  # the shutdown must go on; the record says the stop failed
            detail, stopped = f"{why}; stop failed: {exc}", f"the stop at shutdown FAILED: {exc}"
            arm_stopped = False
            logger.error("stop at shutdown failed: %s", exc)
        await assembly.backend.close()
        for reports in assembly.refusal_reports:  # handed to the writer before the final record
            reports.close()
        if assembly.audit.closed:
            return None
        try:
            latch = assembly.guard.latch
            generation = latch.generation
            await assembly.audit.append_async(SHUTDOWN_EVENT, outcome="ok", detail=detail,
                                              extra=shutdown_extra(latch, arm_stopped))
            if latch.generation != generation:  # a stop (signal, stop channel) latched meanwhile
                await assembly.audit.append_async(
                    "estop", outcome="latched", detail=f"e-stop #{latch.generation} latched as the shutdown record "
                    "was written: the log no longer ends clean, so the next start latches")
        except AuditWriteError as exc:  # the arm is stopped either way; the log must still be closed
            return f"{exc}; {stopped}"
        finally:
            assembly.audit.close()
        return None


async def stop_on_signals(assembly: Assembly, transport: Transport, shutdown: anyio.Event,
                          serving: anyio.CancelScope, signalled: Callable[[str], None]) -> None:
    """On SIGTERM or SIGINT: stop the arm first, then end the serving. `signalled` gets why (for
    the final record) before anything else. HTTP: `shutdown` lets uvicorn drain and return (the
    run then closes the assembly). Stdio: the SDK reads stdin in a worker thread that cancellation
    cannot interrupt, so `serving` would not unwind until the client closes stdin; the cancelled
    calls get `SIGNAL_GRACE_S` to stop and record, then the assembly is closed here and the
    process exits (`EXIT_AUDIT_INCOMPLETE` without a final record)."""
    with anyio.open_signal_receiver(signal.SIGTERM, signal.SIGINT) as signals:
        async for signum in signals:
            why = f"signal {signal.Signals(signum).name}"
            signalled(why)
            with anyio.CancelScope(shield=True):  # the arm stops first, whatever follows
                try:
                    await assembly.backend.stop()
                except Exception as exc:
                    logger.error("stop on %s failed: %s", why, exc)
            if transport == "http":
                shutdown.set()  # uvicorn drains and returns; in-flight executions stop
                return
            serving.cancel()
            final_record_lost: str | None = None
            with anyio.CancelScope(shield=True):
                await anyio.sleep(SIGNAL_GRACE_S)
                final_record_lost = await close_assembly(assembly, why)
            if final_record_lost is not None:
                print(final_record_lost_message(final_record_lost), file=sys.stderr)
            logging.shutdown()
            sys.stderr.flush()
            os._exit(0 if final_record_lost is None else EXIT_AUDIT_INCOMPLETE)
