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
    backend._replies.arrivals.arrived(time.time())  # the bus's frames so far were handled on time
    arrived = time.time() - 0.200  # then a stalled servo thread left them in the socket
    for actuator in backend._actuators:
        backend._replies.on_frame(reply(backend, actuator, arrived))
    backend._publish()
    (kept,) = backend.joint_history.since_or_latest(float("-inf"))
    assert time.monotonic() - kept.stamp >= 0.200


def test_a_reply_without_a_timestamp_or_from_the_future_is_stamped_when_handled():
    clock = ArrivalClock()
    before = time.monotonic()
    assert clock.arrived(0.0) >= before
    assert clock.arrived(time.time() + 3600.0) >= before


def test_an_interface_clock_with_an_offset_of_its_own_gives_ages_not_offsets():
    clock, device_offset = ArrivalClock(), -12345.0  # a device clock mapped to the epoch, off by hours
    clock.arrived(time.time() + device_offset)  # a frame handled at once
    waited = clock.arrived(time.time() + device_offset - 0.150)
    assert 0.14 <= time.monotonic() - waited < 1.0  # its 150 ms wait, not the device's offset


def test_a_clock_step_beyond_any_wait_starts_the_floor_again():
    clock = ArrivalClock()
    clock.arrived(time.time())
    after_step = clock.arrived(time.time() - 3600.0)  # the wall clock stepped an hour forward
    assert time.monotonic() - after_step < 1.0


def test_an_actuators_reply_time_never_goes_back():
    backend = build(MIT_SIM)
    actuator = backend._actuators[0]
    backend._replies.on_frame(reply(backend, actuator, time.time()))
    first = actuator.reported_at
    backend._replies.on_frame(reply(backend, actuator, time.time() - 1.0))  # a clock step, an odd interface
    assert first is not None and actuator.reported_at == first
