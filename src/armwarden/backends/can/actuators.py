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
    reported_at: float | None = None  # monotonic time its last position arrived (on the bus, see `arrived_at`)
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
    arrivals: ArrivalClock = field(default_factory=lambda: ArrivalClock())

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


__all__ = ["Actuator", "ArrivalClock", "OutFrame", "ReplyDecoder"]


class ArrivalClock:
    """When each frame arrived, on the monotonic clock, from the receive timestamp python-can gives it.

    Not when it is handled: after a stalled servo tick the replies that waited in the socket are
    drained late, and stamped when handled they passed for fresh — the Guard's stale check could
    not see their age, and a catch-up drain that handled two replies of an actuator in one tick
    gave the contact observer two ticks of motion over one tick of stamps.

    Interfaces stamp on clocks of their own: SocketCAN the kernel's wall clock, the virtual bus the
    sender's, others a device clock mapped to the epoch with an offset and a drift. So a stamp is
    never compared with the wall clock directly: the clock keeps the smallest lag seen (wall time
    when handled minus the stamp, i.e. the lag of a frame handled at once), lets it creep up by
    `DRIFT_S_PER_S` to follow a drifting device clock, and a frame's age is its lag beyond that. A
    lag more than `STEP_S` beyond it is a clock step (a stall that long has long been an RX timeout
    fault), and starts the floor again. A frame without a stamp is taken as handled at once."""

    #: how fast the lag floor may rise [s/s]: 100 ppm, above a crystal's drift
    DRIFT_S_PER_S = 1e-4
    #: a lag this far above the floor is a clock step, not a frame that waited [s]
    STEP_S = 2.0

    def __init__(self) -> None:
        self._floor: float | None = None
        self._floor_at = 0.0
        self._lock = threading.Lock()  # one reader thread in the backend; tests call it from theirs

    def arrived(self, stamp: object) -> float:
        now = time.monotonic()
        if not (isinstance(stamp, (int, float)) and math.isfinite(stamp) and stamp > 0):
            return now
        lag = time.time() - float(stamp)
        with self._lock:
            floor = lag if self._floor is None else min(lag, self._floor + self.DRIFT_S_PER_S * (now - self._floor_at))
            if lag - floor > self.STEP_S:
                floor = lag
            self._floor, self._floor_at = floor, now
        return now - (lag - floor)


def _later(previous: float | None, arrived: float) -> float:
    """`arrived`, never before `previous`: an actuator's reply time only grows (a frame stamped
    before one already handled, or the floor of `ArrivalClock` falling)."""
    return arrived if previous is None else max(previous, arrived)
