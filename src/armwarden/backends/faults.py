"""Faults a backend finds on its own thread, told to whoever listens (the Guard latches its e-stop).

The backend handles a fault first — the arm stopped or damped, the stop epoch bumped — and then
reports it with `_report_fault` from any thread, which latches the arm state `faulted` (until a
recovery) and tells the listener. A fault found while nobody listens yet (between
a servo thread's start and the Guard's building) is kept and told to the next listener, so none
is lost.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

from armwarden.backends.arm_state import ArmEvent, ArmState

logger = logging.getLogger(__name__)

#: told (from any thread) that the backend found a fault and has already stopped or damped the arm;
#: called with the fault's description, what it returns is ignored
FaultListener = Callable[[str], object]


class FaultReporting:
    """The listener a backend tells about its faults (a part of `Backend`)."""

    # provided by `Backend`
    name: str
    _closed: bool
    _arm_event: Callable[[ArmEvent], ArmState]

    def __init__(self) -> None:
        self._fault_listener: FaultListener | None = None
        self._fault_report_lock = threading.Lock()
        self._unheard_faults: list[str] = []  # reported while no listener was set, for the next one
        super().__init__()

    def set_fault_listener(self, listener: FaultListener | None) -> None:
        """Who to tell about a fault the backend finds on its own, outside any call (the Guard
        latches its e-stop). Called from the backend's thread: the listener must be thread-safe and
        quick, and must not wait for the event loop. Faults found while nobody listened (between
        the servo thread's start and the Guard's building) are told to the new listener at once,
        so none is lost: a fault at start-up latches the e-stop like any other."""
        with self._fault_report_lock:
            self._fault_listener = listener
            unheard, self._unheard_faults = self._unheard_faults, []
        if listener is not None:
            for reason in unheard:
                self._tell(listener, reason)

    def _report_fault(self, reason: str) -> None:
        """Any thread: the arm is already stopped or damped; latch the arm state `faulted` and tell
        the listener why (or keep it for the next listener)."""
        if not self._closed:  # (a closed backend stays closed: it commands nothing)
            self._arm_event(ArmEvent.FAULT)
        with self._fault_report_lock:
            listener = self._fault_listener
            if listener is None:
                self._unheard_faults.append(reason)
        if listener is None:
            logger.error("backend %s fault with no listener yet (kept for it): %s", self.name, reason)
            return
        self._tell(listener, reason)

    def _tell(self, listener: FaultListener, reason: str) -> None:
        try:
            listener(reason)
        except Exception:  # the backend has stopped the arm either way; the report must not kill its thread
            logger.exception("backend %s: fault listener failed for %r", self.name, reason)
