"""Real-time scheduling for a control thread (Linux SCHED_FIFO), asked for by configuration.

A servo loop at 1 kHz shares the machine with the server, planning and whatever else runs there;
under the default scheduler any of them can keep it off the CPU for milliseconds. SCHED_FIFO lets
the kernel run it the moment it wakes (the interpreter lock still has to be handed over; see
docs/benchmarks.md, "The CAN servo loop"). Asking for it and not getting it is an error: an
operator who configured a real-time loop must not silently get an ordinary one.
"""

from __future__ import annotations

import os

from armwarden.core.errors import BackendError

#: the SCHED_FIFO priorities Linux accepts
PRIORITY_RANGE = (1, 99)


def make_current_thread_realtime(priority: int) -> None:
    """Run the calling thread under SCHED_FIFO at `priority`; `BackendError` saying why not."""
    low, high = PRIORITY_RANGE
    if isinstance(priority, bool) or not isinstance(priority, int) or not low <= priority <= high:
        raise BackendError(f"real-time priority must be an integer in {low}..{high}, got {priority!r}")
    setter = getattr(os, "sched_setscheduler", None)
    policy = getattr(os, "SCHED_FIFO", None)
    if setter is None or policy is None:
        raise BackendError("real-time priority needs Linux SCHED_FIFO, which this platform does not have")
    try:
        setter(0, policy, os.sched_param(priority))  # pid 0: the calling thread
    except PermissionError as exc:
        raise BackendError(f"cannot run the control thread at SCHED_FIFO priority {priority}: {exc.strerror}; "
                           "it needs CAP_SYS_NICE or an rtprio limit (ulimit -r) of at least that") from exc
    except OSError as exc:
        raise BackendError(f"cannot run the control thread at SCHED_FIFO priority {priority}: {exc}") from exc


def current_thread_policy() -> tuple[int, int]:
    """(scheduling policy, priority) of the calling thread (for tests and reports)."""
    return os.sched_getscheduler(0), os.sched_getparam(0).sched_priority


__all__ = ["PRIORITY_RANGE", "current_thread_policy", "make_current_thread_realtime"]
