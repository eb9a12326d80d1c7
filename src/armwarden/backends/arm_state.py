"""The arm's state, explicit: one enum, the transitions it allows as data, and a thread-safe holder.

Before this, what the actuators were doing hid in flags spread over each backend (open/closed,
a servo loop that is busy or not, a fault reported once). `ArmState` names it, `TRANSITIONS`
says which event may move it where, and `ArmStateMachine` keeps it for one backend: events come
from the event loop (open, execute, close), from the servo thread (a trajectory finished) and
from any thread (a stop, a fault), so every change is taken under one lock and stamped.

Stops, damping, faults and close are legal in every state: a stop must never be refused because
of bookkeeping. Anything else the table does not allow is a bug in the code that reported it: it
raises `ArmStateError` (a `BackendError`, so the caller's fail-closed path handles it) after
logging it — never ignored.
"""

from __future__ import annotations

import enum
import logging
import threading
import time
from collections.abc import Callable, Collection, Mapping
from types import MappingProxyType

from armwarden.core.errors import BackendError

logger = logging.getLogger(__name__)


class ArmState(enum.Enum):
    """What the arm's actuators are doing, as far as the backend commands them."""

    #: the backend is not open (not yet, or any more): it commands nothing
    CLOSED = "closed"
    #: open and ready; no trajectory runs. The actuators hold where the last motion ended
    IDLE = "idle"
    #: the actuators follow a trajectory, setpoint by setpoint
    MOVING = "moving"
    #: a stop ended motion: a stiff hold at the setpoint the stop commanded (zero velocity)
    HELD = "held"
    #: the drives only damp (no position hold: the arm may sag); after an e-stop or a fault's
    #: reaction, until a recovery admits motion again
    DAMPED = "damped"
    #: a fault the backend found is latched (the arm was stopped or damped first); nothing may
    #: move until a recovery (or a restart, when the fault is a dead thread)
    FAULTED = "faulted"


class ArmEvent(enum.Enum):
    """What happened to the arm; the machine moves by `TRANSITIONS[(state, event)]`."""

    OPEN = "open"  # the backend opened
    EXECUTE = "execute"  # a trajectory was handed to the actuators
    FINISH = "finish"  # the trajectory's last setpoint was commanded
    STOP = "stop"  # a stop commanded a hold (any path, any thread)
    DAMP = "damp"  # the drives were switched to damping
    FAULT = "fault"  # the backend found a fault (already stopped or damped)
    RECOVER = "recover"  # a recovery cleared what latched
    CLOSE = "close"  # the backend closed


_S, _E = ArmState, ArmEvent
_OPEN_STATES = (_S.IDLE, _S.MOVING, _S.HELD, _S.DAMPED)


def _build() -> dict[tuple[ArmState, ArmEvent], ArmState]:
    table: dict[tuple[ArmState, ArmEvent], ArmState] = {
        (_S.CLOSED, _E.OPEN): _S.IDLE,
        (_S.FAULTED, _E.OPEN): _S.FAULTED,  # a fault found while opening stays latched
        (_S.IDLE, _E.EXECUTE): _S.MOVING,
        (_S.HELD, _E.EXECUTE): _S.MOVING,
        (_S.MOVING, _E.FINISH): _S.IDLE,
        (_S.DAMPED, _E.FINISH): _S.DAMPED,  # damping came first (another thread): it stays
        (_S.FAULTED, _E.FINISH): _S.FAULTED,  # likewise a fault
        (_S.IDLE, _E.RECOVER): _S.IDLE,
        (_S.HELD, _E.RECOVER): _S.IDLE,
        (_S.DAMPED, _E.RECOVER): _S.IDLE,
        (_S.FAULTED, _E.RECOVER): _S.IDLE,
        (_S.MOVING, _E.RECOVER): _S.MOVING,  # a recovery beside a run does not end it
        (_S.CLOSED, _E.STOP): _S.CLOSED,
        (_S.DAMPED, _E.STOP): _S.DAMPED,  # a hold does not stiffen damped drives
        (_S.FAULTED, _E.STOP): _S.FAULTED,
        (_S.CLOSED, _E.DAMP): _S.CLOSED,
        (_S.FAULTED, _E.DAMP): _S.FAULTED,
        (_S.CLOSED, _E.FAULT): _S.FAULTED,  # found while opening (the servo thread runs already)
    }
    for state in (_S.IDLE, _S.MOVING, _S.HELD):
        table[(state, _E.STOP)] = _S.HELD
    for state in _OPEN_STATES:
        table[(state, _E.DAMP)] = _S.DAMPED
    for state in (*_OPEN_STATES, _S.FAULTED):
        table[(state, _E.FAULT)] = _S.FAULTED
    for state in ArmState:
        table[(state, _E.CLOSE)] = _S.CLOSED
    return table


#: every allowed transition: (state, event) -> next state; a pair not in it is refused
TRANSITIONS: Mapping[tuple[ArmState, ArmEvent], ArmState] = MappingProxyType(_build())
#: events legal in every state: nothing may refuse a stop, damping, a fault or a close
ALWAYS_ALLOWED = frozenset({_E.STOP, _E.DAMP, _E.FAULT, _E.CLOSE})


class ArmStateError(BackendError):
    """An internal error: code reported an event the arm's state does not allow (a bug, not a
    refusal of the caller's request). A `BackendError`, so the caller stops and fails closed."""


class ArmStateMachine:
    """One backend's arm state: changed only by `TRANSITIONS`, from any thread, stamped.

    `clock` gives the monotonic time of each change [s]; `name` prefixes errors. Legal changes
    are not logged: stops call this under the servo lock, where no I/O may block them (the
    events themselves are audited by the Guard, and the state is a metric).
    """

    def __init__(self, name: str, *, clock: Callable[[], float] = time.monotonic) -> None:
        self._name = name
        self._clock = clock
        self._lock = threading.Lock()
        self._state = ArmState.CLOSED
        self._changed_at = clock()

    @property
    def state(self) -> ArmState:
        return self._state

    @property
    def changed_at(self) -> float:
        """Monotonic time [s] of the last change of state (construction, if none yet)."""
        return self._changed_at

    def apply(self, event: ArmEvent) -> ArmState:
        """Move by `event` and return the new state; `ArmStateError` (logged) if the table forbids it."""
        return self.apply_if(event, ArmState)

    def apply_if(self, event: ArmEvent, when: Collection[ArmState]) -> ArmState:
        """Move by `event` only while the state is one of `when`, atomically (a stop from another
        thread may have moved it since the caller looked); return the state after. `ArmStateError`
        (logged) if the table forbids `event` in a state of `when`."""
        with self._lock:
            before = self._state
            if before not in when:
                return before
            after = TRANSITIONS.get((before, event))
            if after is not None and after is not before:
                self._state, self._changed_at = after, self._clock()
        if after is None:  # logged outside the lock: stops report under the servo lock
            message = f"{self._name}: internal error: arm event {event.value!r} is not allowed in state {before.value!r}"
            logger.error(message)
            raise ArmStateError(message)
        return after


class ArmStateReporting:
    """The arm state of a backend (a part of `Backend`). A backend whose loop or action client
    hands trajectories over under the lock its stop takes reports its own motion events
    (`reports_motion_events`: `ServoBackend`, the ROS 2 backend); for every other backend `Backend`
    reports them around `_execute` and the stop hooks, so it shows the state without code of its own."""

    # provided by `Backend`
    name: str

    def __init__(self) -> None:
        self._arm = ArmStateMachine(f"backend {self.name}")
        super().__init__()

    @property
    def arm_state(self) -> ArmState:
        """What the arm's actuators are doing now (read-only: only the backend's events move it)."""
        return self._arm.state

    @property
    def arm_state_since(self) -> float:
        """Monotonic time [s] at which `arm_state` last changed."""
        return self._arm.changed_at

    def _arm_event(self, event: ArmEvent) -> ArmState:
        """Report `event` (any thread); `ArmStateError` if the table forbids it."""
        return self._arm.apply(event)

    def _arm_event_if(self, event: ArmEvent, *when: ArmState) -> ArmState:
        """Report `event` only while the state is one of `when` (`ArmStateMachine.apply_if`)."""
        return self._arm.apply_if(event, when)


__all__ = ["ALWAYS_ALLOWED", "TRANSITIONS", "ArmEvent", "ArmState", "ArmStateError", "ArmStateMachine",
           "ArmStateReporting"]
