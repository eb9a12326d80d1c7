"""The CAN backend's actuators: what each last reported, the frames sent to it, and the decoding
of its replies.

`Actuator` is written where frames are read (`ReplyDecoder.on_frame`: on python-can's Notifier
thread until the servo loop takes reading over, then in the servo tick's drain; see
`armwarden.backends.can.bus`) and read by the servo thread and the event loop, always under the
backend's state lock.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field

import can

from armwarden.backends.can import mit
from armwarden.backends.can import robstride as rs
from armwarden.backends.can import robstride_frames as rs_frames
from armwarden.backends.can.config import GripperConfig, JointConfig
from armwarden.backends.can.errors import InvalidFrame
from armwarden.backends.can.ranges import ModelRanges


@dataclass
class Actuator:
    """One actuator's configuration and what it last reported (written by the reader thread,
    read by the servo thread, both under the backend's state lock)."""

    index: int  # the joint's index; -1: the gripper
    joint: JointConfig | GripperConfig
    ranges: ModelRanges
    unwrapper: mit.PositionUnwrapper | None
    raw_position: float | None = None
    raw_velocity: float = 0.0
    #: the torque [N·m] its last feedback reported (RobStride type 2, MIT reply); None: none yet
    raw_torque: float | None = None
    reported_at: float | None = None  # monotonic time its last position arrived (on the bus, see `ArrivalClock`)
    temperature_c: float | None = None
    fault_bits: tuple[str, ...] = ()  # reported in the latest feedback (current)
    fault_frames: tuple[str, ...] = ()  # RobStride type-21 reports (latched until recovery)
    invalid_frames: int = 0  # malformed frames from it (latched until recovery)
    mode: rs.MotorMode | None = None  # RobStride only
    pinged: bool = False
    replies: int = 0
    parameters: dict[int, float] = field(default_factory=dict)
    unanswered_since: float | None = None  # monotonic time of the oldest frame not yet answered

    @property
    def label(self) -> str:
        what = "" if self.index < 0 else "joint "  # the gripper's name says what it is
        return f"{what}{self.joint.name} (can id {self.joint.can_id})"


@dataclass(frozen=True)
class OutFrame:
    """A frame to send to `actuator` (encoded before any frame of its batch is sent)."""

    actuator: Actuator
    arbitration_id: int
    data: bytes
    extended: bool


@dataclass(frozen=True)
class ReplyDecoder:
    """Each frame from the bus into the actuator that sent it, by protocol: RobStride frames by the
    motor id in their extended id, MIT replies (standard id `mit_reply_id`) by their first byte."""

    robstride: dict[int, Actuator]
    mit: dict[int, Actuator]
    lock: threading.Lock  # the backend's state lock
    host_id: int
    mit_reply_id: int
    #: when each frame arrived on the bus
    arrivals: ArrivalClock = field(default_factory=lambda: ArrivalClock(trusts_stamps=False))

    def on_frame(self, msg: can.Message) -> None:
        """Reader thread: one received frame into the actuator that sent it (`InvalidFrame` if none did,
        or if it is malformed: counted against that actuator until recovery)."""
        data = bytes(msg.data)
        arrived = self.arrivals.arrived(msg.timestamp)
        if msg.is_extended_id:
            fields = rs.split_id(msg.arbitration_id)
            motor = fields.data2 & 0xFF
            a = self.robstride.get(motor)
            if a is None:
                raise InvalidFrame(f"frame 0x{msg.arbitration_id:X} from unknown RobStride motor {motor}")
            with self.lock:
                try:
                    self._on_robstride(a, fields.comm_type, msg.arbitration_id, data, arrived)
                except InvalidFrame:
                    a.invalid_frames += 1
                    raise
                a.replies += 1
                a.unanswered_since = None
            return
        if msg.arbitration_id != self.mit_reply_id or not data:
            raise InvalidFrame(f"unexpected standard frame 0x{msg.arbitration_id:X}")
        a = self.mit.get(data[0])
        if a is None:
            raise InvalidFrame(f"MIT reply from unknown motor {data[0]}")
        with self.lock:
            try:
                reply = mit.parse_reply(data, a.ranges, motor_id=a.joint.can_id)
            except InvalidFrame:
                a.invalid_frames += 1
                raise
            assert a.unwrapper is not None
            a.raw_position = a.unwrapper.update(reply.position)
            a.raw_velocity = reply.velocity
            a.raw_torque = reply.torque
            a.reported_at = _later(a.reported_at, arrived)
            if reply.temperature_c is not None:
                a.temperature_c = float(reply.temperature_c)
            a.fault_bits = () if reply.error in (None, mit.MitError.NONE) else (reply.error.name,)
            a.pinged = True
            a.replies += 1
            a.unanswered_since = None

    def _on_robstride(self, a: Actuator, comm_type: int, arbitration_id: int, data: bytes, arrived: float) -> None:
        host = self.host_id
        if comm_type == rs.CommType.FEEDBACK:
            feedback = rs_frames.parse_feedback(arbitration_id, data, a.ranges, host_id=host)
            a.raw_position, a.raw_velocity = feedback.position, feedback.velocity
            a.raw_torque = feedback.torque
            a.reported_at = _later(a.reported_at, arrived)
            a.temperature_c, a.mode = feedback.temperature_c, feedback.mode
            a.fault_bits = rs.flag_names(feedback.faults)
        elif comm_type == rs.CommType.FAULT:
            report = rs_frames.parse_fault(arbitration_id, data, host_id=host)
            names = rs.flag_names(report.faults) + ((f"0x{report.unknown_bits:X}",) if report.unknown_bits else ())
            if names:
                a.fault_frames = tuple(dict.fromkeys(a.fault_frames + names))
        elif comm_type == rs.CommType.GET_ID:
            rs_frames.parse_device_id(arbitration_id, data)
            a.pinged = True
        elif comm_type == rs.CommType.READ_PARAMETER:
            value = rs_frames.parse_parameter(arbitration_id, data, host_id=host)
            a.parameters[value.parameter.index] = float(value.value)
        else:
            raise InvalidFrame(f"unexpected RobStride frame type {comm_type} from motor {a.joint.can_id}")


__all__ = ["WALL_CLOCK_STAMPS", "Actuator", "ArrivalClock", "OutFrame", "ReplyDecoder"]


#: python-can interfaces whose receive stamps are on this host's wall clock: the kernel's
#: (SocketCAN) and the sender's `time.time()` (the virtual bus, in this process)
WALL_CLOCK_STAMPS = frozenset({"socketcan", "virtual"})


@dataclass(frozen=True)
class ArrivalClock:
    """When each frame arrived, on the monotonic clock.

    Not when it is handled: after a stalled servo tick the replies that waited in the socket are
    drained late, and stamped when handled they passed for fresh — the Guard's stale check could
    not see their age, and a catch-up drain that handled two replies of an actuator in one tick
    gave the contact observer two ticks of motion over one tick of stamps. So on an interface
    that stamps frames on this host's wall clock (`WALL_CLOCK_STAMPS`) a frame is as old as its
    stamp says, in full (a wait of any length counts, nothing is taken for a clock step). Other
    interfaces stamp on a device clock mapped to the epoch, with an offset and a drift a lag
    cannot tell from a wait: their frames are stamped when handled, as before. A stamp missing, or
    from the future (a wall-clock step between stamp and handling), is taken as handled now."""

    trusts_stamps: bool

    @classmethod
    def for_interface(cls, interface: str) -> ArrivalClock:
        return cls(interface in WALL_CLOCK_STAMPS)

    def arrived(self, stamp: object) -> float:
        now = time.monotonic()
        if not self.trusts_stamps or not (isinstance(stamp, (int, float)) and math.isfinite(stamp) and stamp > 0):
            return now
        return now - max(0.0, time.time() - float(stamp))


def _later(previous: float | None, arrived: float) -> float:
    """`arrived`, never before `previous`: an actuator's reply time only grows (a frame stamped
    before one already handled, or a wall-clock step)."""
    return arrived if previous is None else max(previous, arrived)
