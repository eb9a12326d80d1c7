"""A CAN reply is stamped with when it arrived on the bus, not when a servo tick got to it: replies
that waited in the socket behind a stalled tick are as old as they are, for the Guard's stale check
and for the contact observer's intervals."""

from __future__ import annotations

import time

import can

from armwarden.backends.can import mit
from armwarden.backends.can.actuators import ArrivalClock
from tests.backends.can.test_can_backend import MIT_SIM, build


def reply(backend, actuator, arrived_wall: float) -> can.Message:
    data = mit.pack_reply(mit.MitReply(actuator.joint.can_id, 0.1, 0.0, 0.5, 30, mit.MitError.NONE), actuator.ranges)
    return can.Message(arbitration_id=backend.config.mit_reply_id, data=data, is_extended_id=False,
                       timestamp=arrived_wall)


def test_replies_that_waited_200_ms_are_kept_as_200_ms_old():
    backend = build(MIT_SIM)
    assert backend._replies.arrivals.trusts_stamps  # the virtual bus stamps on this host's wall clock
    arrived = time.time() - 0.200  # then a stalled servo thread left them in the socket
    for actuator in backend._actuators:
        backend._replies.on_frame(reply(backend, actuator, arrived))
    backend._publish()
    (kept,) = backend.joint_history.since_or_latest(float("-inf"))
    assert time.monotonic() - kept.stamp >= 0.200


def test_a_reply_without_a_timestamp_or_from_the_future_is_stamped_when_handled():
    clock = ArrivalClock(trusts_stamps=True)
    before = time.monotonic()
    assert clock.arrived(0.0) >= before
    assert clock.arrived(time.time() + 3600.0) >= before


def test_a_reply_that_waited_seconds_is_as_old_as_it_waited():
    waited = ArrivalClock(trusts_stamps=True).arrived(time.time() - 5.0)  # a long stall: no clock step
    assert time.monotonic() - waited >= 5.0


def test_an_interface_stamping_on_a_device_clock_is_stamped_when_handled():
    clock = ArrivalClock.for_interface("pcan")  # a device clock mapped to the epoch: offset and drift
    before = time.monotonic()
    assert not clock.trusts_stamps and clock.arrived(time.time() - 12345.0) >= before
    assert ArrivalClock.for_interface("socketcan").trusts_stamps


def test_an_actuators_reply_time_never_goes_back():
    backend = build(MIT_SIM)
    actuator = backend._actuators[0]
    backend._replies.on_frame(reply(backend, actuator, time.time()))
    first = actuator.reported_at
    backend._replies.on_frame(reply(backend, actuator, time.time() - 1.0))  # a clock step, an odd interface
    assert first is not None and actuator.reported_at == first
