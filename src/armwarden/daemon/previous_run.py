"""How the previous run on this audit log ended, and the e-stop a start latches when it did not
end clean.

Why: a software latch lives in the daemon's memory. Without this, restarting the daemon would
release an e-stop nobody approved releasing (a force violation, a person in the cell), and a
daemon killed mid-motion (kill -9, a crash, a power loss, an out-of-memory kill) would come back
ready to move an arm it last saw moving: a ROS 2 controller may still be running the last goal,
CAN actuators have gone limp at their own timeout. Industrial controllers want an
acknowledgement after such an end; so does this daemon. A start therefore latches the e-stop
unless the log proves the previous run ended clean: its last record is a `shutdown` record that
says the arm was stopped and no e-stop was held (`shutdown_extra` writes those facts). A new log
has no previous run. Anything else — a run that died without its final record, a torn last
write, a shutdown whose stop failed, a record from a version that did not say — latches, and only
a human releases it (`reset_estop`, approved), as any other e-stop.
"""

from __future__ import annotations

import logging
from typing import Any

from armwarden.audit import AuditLog
from armwarden.guard import Guard
from armwarden.safety.estop import EStopLatch

logger = logging.getLogger("armwarden")

#: the final record of a run (`daemon.shutdown.close_assembly`)
SHUTDOWN_EVENT = "shutdown"
#: the source of the e-stop a start latches (on its event, in the state and the console)
PREVIOUS_RUN_SOURCE = "previous_run"


def shutdown_extra(latch: EStopLatch, arm_stopped: bool) -> dict[str, Any]:
    """What the `shutdown` record says for the next start: whether the arm was stopped, and the
    e-stops still held (number, source, reason; empty when none)."""
    held = [{"number": e.number, "source": e.source, "reason": e.reason} for e in latch.held_events]
    return {"arm_stopped": arm_stopped, "estops_held": held}


def unclean_end(audit: AuditLog) -> str | None:
    """None when the previous run on `audit` ended clean (or there was none); else why the start
    must latch the e-stop. Read on opening, before this run writes anything but a recovery."""
    records = audit.tail(1)
    if not records:
        return None
    last = records[-1]
    where = f"record #{last.get('seq')} ({last.get('event')}, {last.get('wall_time')})"
    if last.get("event") == "recovery":
        return (f"the previous run on this audit log was cut off mid-write (the torn line is recovered as {where}): "
                "it was killed or crashed, maybe mid-motion")
    if last.get("event") != SHUTDOWN_EVENT:
        return (f"the previous run on this audit log ended without its shutdown record (its last is {where}): "
                "it was killed or crashed, maybe mid-motion")
    extra = last.get("extra")
    if not isinstance(extra, dict) or "arm_stopped" not in extra or not isinstance(extra.get("estops_held"), list):
        return f"the previous run's shutdown ({where}) does not say whether the arm was stopped and no e-stop was held"
    if extra["arm_stopped"] is not True:
        return f"the previous run's shutdown ({where}) could not stop the arm"
    held = extra["estops_held"]
    if held:
        newest = held[-1] if isinstance(held[-1], dict) else {}
        return (f"the previous run ended with e-stop #{newest.get('number')} ({newest.get('source')}: "
                f"{newest.get('reason')}) latched and never released ({where})")
    return None


async def latch_at_start(guard: Guard, audit: AuditLog, why: str) -> int:
    """Latch the e-stop (the backend's e-stop stops whatever still moves), record it and say so on
    stderr; returns its number. Before anything is served."""
    reason = f"latched at start: {why}. Look at the arm before releasing it (reset_estop, approved by a human)"
    result = await guard.emergency_stop(reason, source=PREVIOUS_RUN_SOURCE)
    number = result.estop_event.number
    await audit.append_async("estop", outcome="latched", detail=f"e-stop #{number} {reason}",
                             extra={"estop_event": number, "source": PREVIOUS_RUN_SOURCE})
    logger.warning("e-stop #%d %s", number, reason)
    return number
