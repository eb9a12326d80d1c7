"""The e-stops that come from outside the event loop (the stop channel, SIGUSR1, a transport that
has just read an `estop` request) call the backend's `emergency_stop_now`; a `stop_motion` request
read by a transport calls `stop_now`."""

from __future__ import annotations

from armwarden.approval.plans import PlanStore
from armwarden.backends.counting import CountingBackend
from armwarden.guard.stopping import Stopper
from armwarden.robots import load_profile
from armwarden.safety.estop import EStopLatch
from tests.backends.minimal_backend import MinimalBackend

_READY = load_profile("fr3").ready_joint_positions or {}
FR3_JOINT_NAMES, FR3_READY = tuple(_READY), tuple(_READY.values())


def stopper() -> tuple[Stopper, CountingBackend]:
    backend = CountingBackend(MinimalBackend(FR3_JOINT_NAMES, FR3_READY, start_tolerance_rad=0.01))
    return Stopper(backend, EStopLatch(), PlanStore(ttl_s=60.0, start_tolerance_rad=0.01)), backend


def test_latch_and_stop_uses_the_backends_emergency_stop():
    stop, backend = stopper()
    pending: list[object] = []
    event = stop.latch_and_stop("button", "stop_channel", pending.append)
    assert stop.latch.is_latched and event.source == "stop_channel"
    assert (backend.stops, backend.emergency_stops) == (1, 1)


def test_hold_now_for_an_estop_request_is_an_emergency_stop_and_for_a_stop_request_a_hold():
    stop, backend = stopper()
    assert stop.hold_now(emergency=True) is None
    assert stop.hold_now() is None
    assert (backend.stops, backend.emergency_stops) == (2, 1)
    assert not stop.latch.is_latched
