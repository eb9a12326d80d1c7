"""RobStride private-protocol frames (RS00–RS06, 29-bit extended ids): pure functions, no I/O.

The id is `(type << 24) | (data2 << 8) | dest`: bits 28–24 the communication type, 23–8 "data
area 2" (in requests normally the host id in bits 15–8; in the type-1 control frame the torque),
7–0 the destination (the motor in requests, the host in replies). Control (type 1) and feedback
(type 2) data are big-endian u16 values over the model's ranges; parameter frames (types 17/18)
are little-endian. Host-side parsers refuse anything that is not the frame they read (wrong
type, wrong length, addressed to another host, undefined mode) with `InvalidFrame`.
"""

from __future__ import annotations

import enum
import functools
import math
import struct
from dataclasses import dataclass

from armwarden.backends.can.command import MotorCommand
from armwarden.backends.can.errors import InvalidFrame
from armwarden.backends.can.mapping import decode, encode
from armwarden.backends.can.ranges import ModelRanges, Protocol

#: largest extended (29-bit) CAN id
MAX_EXTENDED_ID = (1 << 29) - 1
#: the destination byte of a type-0 (get id) reply
DEVICE_ID_REPLY_DEST = 0xFE
#: canTimeout (0x7028) counts in these units per second (20000 = 1 s; 0 disables it)
CAN_TIMEOUT_TICKS_PER_S = 20000


class CommType(enum.IntEnum):
    """Communication types (id bits 28–24)."""

    GET_ID = 0
    CONTROL = 1  # operation control (MIT-style impedance command)
    FEEDBACK = 2
    ENABLE = 3
    STOP = 4
    SET_ZERO = 6
    SET_ID = 7
    READ_PARAMETER = 17
    WRITE_PARAMETER = 18
    FAULT = 21
    SAVE_PARAMETERS = 22
    ACTIVE_REPORT = 24


class MotorMode(enum.IntEnum):
    """Mode bits 23–22 of a feedback id."""

    RESET = 0
    CALIBRATION = 1
    RUN = 2


class FeedbackFault(enum.IntFlag):
    """Fault bits 21–16 of a feedback id (bit 16 is the lowest flag)."""

    UNDER_VOLTAGE = 1 << 0
    OVER_CURRENT = 1 << 1
    OVER_TEMPERATURE = 1 << 2
    MAGNETIC_ENCODER = 1 << 3
    STALL_OVERLOAD = 1 << 4
    UNCALIBRATED = 1 << 5


class FaultFlag(enum.IntFlag):
    """Fault bits of a type-21 fault frame (bytes 0–3)."""

    OVER_TEMPERATURE = 1 << 0
    UNDER_VOLTAGE = 1 << 2
    OVER_VOLTAGE = 1 << 3
    PHASE_B_OVER_CURRENT = 1 << 4
    PHASE_C_OVER_CURRENT = 1 << 5
    ENCODER_UNCALIBRATED = 1 << 7
    STALL_OVERLOAD = 1 << 14
    PHASE_A_OVER_CURRENT = 1 << 16


_KNOWN_FAULT_BITS = sum(flag.value for flag in FaultFlag)


@functools.lru_cache(maxsize=1024, typed=True)  # typed: FeedbackFault(1) == FaultFlag(1) as integers
def flag_names(flags: enum.Flag) -> tuple[str, ...]:
    """The names of the flags set in `flags` (for messages: "OVER_TEMPERATURE, STALL_OVERLOAD");
    cached, as the reader thread asks for every feedback frame."""
    return tuple(member.name for member in type(flags) if member.name and member in flags)


class RunMode(enum.IntEnum):
    """Values of the run_mode parameter (0x7005)."""

    OPERATION = 0  # MIT-style operation control (type 1 frames)
    POSITION_PP = 1
    VELOCITY = 2
    CURRENT = 3
    POSITION_CSP = 5


class ParamType(enum.Enum):
    U8 = "u8"
    U32 = "u32"
    F32 = "f32"


@dataclass(frozen=True)
class Parameter:
    """One parameter: its index, the name the manual uses, how its value is encoded."""

    index: int
    name: str
    type: ParamType


RUN_MODE = Parameter(0x7005, "run_mode", ParamType.U8)
LIMIT_TORQUE = Parameter(0x700B, "limit_torque", ParamType.F32)  # [N·m]
LIMIT_SPD = Parameter(0x7017, "limit_spd", ParamType.F32)  # [rad/s]
LIMIT_CUR = Parameter(0x7018, "limit_cur", ParamType.F32)  # [A]
MECH_POS = Parameter(0x7019, "mechPos", ParamType.F32)  # [rad], read-only
MECH_VEL = Parameter(0x701B, "mechVel", ParamType.F32)  # [rad/s], read-only
VBUS = Parameter(0x701C, "VBUS", ParamType.F32)  # [V], read-only
CAN_TIMEOUT = Parameter(0x7028, "canTimeout", ParamType.U32)  # CAN_TIMEOUT_TICKS_PER_S per second
PARAMETERS: tuple[Parameter, ...] = (RUN_MODE, LIMIT_TORQUE, LIMIT_SPD, LIMIT_CUR, MECH_POS, MECH_VEL, VBUS, CAN_TIMEOUT)
_BY_INDEX = {p.index: p for p in PARAMETERS}


def parameter_by_index(index: int) -> Parameter:
    """The known parameter at `index`; `InvalidFrame` if there is none."""
    try:
        return _BY_INDEX[index]
    except KeyError:
        raise InvalidFrame(f"unknown RobStride parameter index 0x{index:04X}") from None


def can_timeout_ticks(seconds: float) -> int:
    """The canTimeout value for a timeout of `seconds` (0 disables; refused if negative or not finite)."""
    if not (math.isfinite(seconds) and seconds >= 0):
        raise ValueError(f"CAN timeout must be a finite, non-negative number of seconds, got {seconds!r}")
    ticks = round(seconds * CAN_TIMEOUT_TICKS_PER_S)
    if ticks > 0xFFFFFFFF:
        raise ValueError(f"CAN timeout {seconds} s does not fit the canTimeout parameter")
    return ticks


def can_timeout_seconds(ticks: int) -> float:
    """The timeout [s] a canTimeout value stands for (0 = disabled)."""
    return ticks / CAN_TIMEOUT_TICKS_PER_S


#: control and feedback data: four big-endian u16 values
_FOUR_U16_BE = struct.Struct(">HHHH")
_MOTOR_MODES = {int(mode): mode for mode in MotorMode}
_FEEDBACK_FAULTS = tuple(FeedbackFault(bits) for bits in range(64))  # every value of the 6 fault bits


# ------------------------------------------------------------------ ids and frames
@dataclass(frozen=True)
class ExtId:
    """The three fields of an extended id."""

    comm_type: int
    data2: int
    dest: int


@dataclass(frozen=True)
class Frame:
    """An extended-id frame: `arbitration_id` (29 bits) and up to 8 data bytes."""

    arbitration_id: int
    data: bytes


def build_id(comm_type: int, data2: int, dest: int) -> int:
    """The 29-bit id of the fields; `ValueError` if one does not fit."""
    if 0 <= comm_type < 32 and 0 <= data2 <= 0xFFFF and 0 <= dest <= 0xFF:
        return (int(comm_type) << 24) | (data2 << 8) | dest
    for name, value, bits in (("communication type", comm_type, 5), ("data area 2", data2, 16), ("destination", dest, 8)):
        if not 0 <= value < (1 << bits):
            raise ValueError(f"{name} {value} does not fit in {bits} bits")
    return (int(comm_type) << 24) | (data2 << 8) | dest


def split_id(arbitration_id: int) -> ExtId:
    """The fields of a 29-bit id; `InvalidFrame` if it is wider."""
    if not 0 <= arbitration_id <= MAX_EXTENDED_ID:
        raise InvalidFrame(f"id 0x{arbitration_id:X} is not a 29-bit extended id")
    return ExtId(arbitration_id >> 24, (arbitration_id >> 8) & 0xFFFF, arbitration_id & 0xFF)


def _require_robstride(ranges: ModelRanges) -> None:
    if ranges.protocol is not Protocol.ROBSTRIDE:
        raise ValueError(f"model {ranges.model} does not speak the RobStride protocol")


def _byte(name: str, value: int) -> int:
    if not 0 <= value <= 0xFF:
        raise ValueError(f"{name} must fit in one byte, got {value}")
    return value


def _request(comm_type: CommType, motor_id: int, host_id: int, data: bytes = bytes(8)) -> Frame:
    return Frame(build_id(comm_type, _byte("host_id", host_id), _byte("motor_id", motor_id)), data)


def get_id_frame(motor_id: int, host_id: int) -> Frame:
    """Type 0: ask the motor for its 64-bit MCU id (a ping)."""
    return _request(CommType.GET_ID, motor_id, host_id)


def control_frame(motor_id: int, command: MotorCommand, ranges: ModelRanges) -> Frame:
    """Type 1: the impedance command; torque rides in the id, the rest big-endian in the data.
    `ValueError` if any value is non-finite or out of the model's range."""
    _require_robstride(ranges)
    torque = encode(command.torque, ranges.torque, 16, "torque")
    data = _FOUR_U16_BE.pack(
        encode(command.position, ranges.position, 16, "position"),
        encode(command.velocity, ranges.velocity, 16, "velocity"),
        encode(command.kp, ranges.kp, 16, "kp"),
        encode(command.kd, ranges.kd, 16, "kd"),
    )
    return Frame(build_id(CommType.CONTROL, torque, _byte("motor_id", motor_id)), data)


def enable_frame(motor_id: int, host_id: int) -> Frame:
    """Type 3: enter run mode (the motor answers with feedback)."""
    return _request(CommType.ENABLE, motor_id, host_id)


def stop_frame(motor_id: int, host_id: int, *, clear_faults: bool = False) -> Frame:
    """Type 4: stop (reset mode, no torque); `clear_faults` also clears latched faults."""
    return _request(CommType.STOP, motor_id, host_id, bytes((1 if clear_faults else 0, 0, 0, 0, 0, 0, 0, 0)))


def set_zero_frame(motor_id: int, host_id: int) -> Frame:
    """Type 6: take the current position as mechanical zero (maintenance only, never in motion)."""
    return _request(CommType.SET_ZERO, motor_id, host_id, bytes((1, 0, 0, 0, 0, 0, 0, 0)))


def read_parameter_frame(motor_id: int, host_id: int, parameter: Parameter) -> Frame:
    """Type 17: read one parameter (the motor answers with a type-17 frame carrying the value)."""
    return _request(CommType.READ_PARAMETER, motor_id, host_id, struct.pack("<HHI", parameter.index, 0, 0))


def write_parameter_frame(motor_id: int, host_id: int, parameter: Parameter, value: float) -> Frame:
    """Type 18: write one parameter (little-endian); `ValueError` if `value` does not fit its type."""
    return _request(CommType.WRITE_PARAMETER, motor_id, host_id, struct.pack("<HH", parameter.index, 0) + encode_value(parameter, value))


def active_report_frame(motor_id: int, host_id: int, *, on: bool) -> Frame:
    """Type 24: switch the motor's periodic feedback reporting on or off."""
    return _request(CommType.ACTIVE_REPORT, motor_id, host_id, bytes((1, 2, 3, 4, 5, 6, 1 if on else 0, 0)))


def encode_value(parameter: Parameter, value: float) -> bytes:
    """The 4 little-endian value bytes of a parameter frame."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{parameter.name} must be a finite number, got {value!r}")
    if parameter.type is ParamType.F32:
        return struct.pack("<f", value)
    if value != int(value):
        raise ValueError(f"{parameter.name} is an integer parameter, got {value}")
    limit = 0xFF if parameter.type is ParamType.U8 else 0xFFFFFFFF
    if not 0 <= value <= limit:
        raise ValueError(f"{parameter.name} = {value} is outside [0, {limit}]")
    return struct.pack("<I", int(value))


def decode_value(parameter: Parameter, raw: bytes) -> float | int:
    """The value in the 4 little-endian value bytes of a parameter frame; `InvalidFrame` if it
    is not a value of the parameter's type (a non-finite float, a u8 wider than a byte)."""
    if parameter.type is ParamType.F32:
        value = struct.unpack("<f", raw)[0]
        if not math.isfinite(value):
            raise InvalidFrame(f"{parameter.name} value is not finite")
        return value
    number = struct.unpack("<I", raw)[0]
    if parameter.type is ParamType.U8 and number > 0xFF:
        raise InvalidFrame(f"{parameter.name} value {number} does not fit in one byte")
    return number


# ------------------------------------------------------------------ replies (host side parses them)
@dataclass(frozen=True)
class Feedback:
    """A type-2 feedback frame: `position` [rad], `velocity` [rad/s], `torque` [N·m], `temperature_c`."""

    motor_id: int
    mode: MotorMode
    faults: FeedbackFault
    position: float
    velocity: float
    torque: float
    temperature_c: float


@dataclass(frozen=True)
class FaultReport:
    """A type-21 fault frame: the known fault flags, any undocumented bits, the warning word."""

    motor_id: int
    faults: FaultFlag
    unknown_bits: int
    warnings: int


@dataclass(frozen=True)
class ParameterValue:
    """A type-17 reply: the value of one parameter."""

    motor_id: int
    parameter: Parameter
    value: float | int


@dataclass(frozen=True)
class DeviceId:
    """A type-0 reply: the motor answered a ping with its 64-bit MCU id."""

    motor_id: int
    uid: bytes


def _expect(frame_id: int, data: bytes, comm_type: CommType, dest: int, what: str) -> ExtId:
    fields = split_id(frame_id)
    if fields.comm_type != comm_type:
        raise InvalidFrame(f"expected a RobStride {what} (type {int(comm_type)}), got type {fields.comm_type}")
    if len(data) != 8:
        raise InvalidFrame(f"RobStride {what} must have 8 data bytes, got {len(data)}")
    if fields.dest != dest:
        raise InvalidFrame(f"RobStride {what} addressed to 0x{fields.dest:02X}, expected 0x{dest:02X}")
    return fields


def parse_feedback(arbitration_id: int, data: bytes, ranges: ModelRanges, *, host_id: int) -> Feedback:
    """A type-2 feedback frame sent to `host_id`."""
    _require_robstride(ranges)
    fields = _expect(arbitration_id, data, CommType.FEEDBACK, host_id, "feedback frame")
    mode_bits = fields.data2 >> 14
    mode = _MOTOR_MODES.get(mode_bits)
    if mode is None:
        raise InvalidFrame(f"RobStride feedback from motor {fields.data2 & 0xFF} has undefined mode {mode_bits}")
    angle, velocity, torque, temperature = _FOUR_U16_BE.unpack(data)
    return Feedback(
        motor_id=fields.data2 & 0xFF,
        mode=mode,
        faults=_FEEDBACK_FAULTS[(fields.data2 >> 8) & 0x3F],
        position=decode(angle, ranges.position, 16),
        velocity=decode(velocity, ranges.velocity, 16),
        torque=decode(torque, ranges.torque, 16),
        temperature_c=temperature / 10.0,
    )


def parse_fault(arbitration_id: int, data: bytes, *, host_id: int) -> FaultReport:
    """A type-21 fault frame sent to `host_id` (fault and warning words little-endian, as the
    parameter frames; check against hardware before relying on individual bits)."""
    fields = _expect(arbitration_id, data, CommType.FAULT, host_id, "fault frame")
    faults, warnings = struct.unpack("<II", bytes(data))
    return FaultReport(fields.data2 & 0xFF, FaultFlag(faults & _KNOWN_FAULT_BITS), faults & ~_KNOWN_FAULT_BITS, warnings)


def parse_parameter(arbitration_id: int, data: bytes, *, host_id: int) -> ParameterValue:
    """A type-17 reply carrying a parameter value, sent to `host_id`."""
    fields = _expect(arbitration_id, data, CommType.READ_PARAMETER, host_id, "parameter reply")
    index = struct.unpack_from("<H", bytes(data))[0]
    parameter = parameter_by_index(index)
    return ParameterValue(fields.data2 & 0xFF, parameter, decode_value(parameter, bytes(data[4:8])))


def parse_device_id(arbitration_id: int, data: bytes) -> DeviceId:
    """A type-0 reply (a ping answered)."""
    fields = _expect(arbitration_id, data, CommType.GET_ID, DEVICE_ID_REPLY_DEST, "device id reply")
    return DeviceId(fields.data2 & 0xFF, bytes(data))


# ------------------------------------------------------------------ the actuator's side (emulator)
def unpack_control(arbitration_id: int, data: bytes, ranges: ModelRanges) -> tuple[int, MotorCommand]:
    """The motor id and command of a type-1 frame."""
    _require_robstride(ranges)
    fields = split_id(arbitration_id)
    if fields.comm_type != CommType.CONTROL or len(data) != 8:
        raise InvalidFrame(f"not a RobStride control frame: type {fields.comm_type}, {len(data)} data bytes")
    angle, velocity, kp, kd = _FOUR_U16_BE.unpack(data)
    return fields.dest, MotorCommand(
        position=decode(angle, ranges.position, 16),
        velocity=decode(velocity, ranges.velocity, 16),
        kp=decode(kp, ranges.kp, 16),
        kd=decode(kd, ranges.kd, 16),
        torque=decode(fields.data2, ranges.torque, 16),
    )


def unpack_parameter_request(data: bytes) -> tuple[Parameter, bytes]:
    """The parameter and the 4 raw value bytes of a type-17/18 request."""
    if len(data) != 8:
        raise InvalidFrame(f"RobStride parameter request must have 8 data bytes, got {len(data)}")
    return parameter_by_index(struct.unpack_from("<H", bytes(data))[0]), bytes(data[4:8])


def feedback_frame(feedback: Feedback, ranges: ModelRanges, *, host_id: int) -> Frame:
    """The type-2 frame a motor sends for `feedback`."""
    _require_robstride(ranges)
    temperature = round(feedback.temperature_c * 10)
    if not 0 <= temperature <= 0xFFFF:
        raise ValueError(f"temperature {feedback.temperature_c} °C does not fit the feedback frame")
    data2 = (int(feedback.mode) << 14) | (int(feedback.faults) & 0x3F) << 8 | _byte("motor_id", feedback.motor_id)
    data = _FOUR_U16_BE.pack(
        encode(feedback.position, ranges.position, 16, "position"),
        encode(feedback.velocity, ranges.velocity, 16, "velocity"),
        encode(feedback.torque, ranges.torque, 16, "torque"),
        temperature,
    )
    return Frame(build_id(CommType.FEEDBACK, data2, _byte("host_id", host_id)), data)


def fault_frame(report: FaultReport, *, host_id: int) -> Frame:
    """The type-21 frame a motor sends for `report`."""
    data = struct.pack("<II", int(report.faults) | report.unknown_bits, report.warnings)
    return Frame(build_id(CommType.FAULT, _byte("motor_id", report.motor_id), _byte("host_id", host_id)), data)


def parameter_reply_frame(value: ParameterValue, *, host_id: int) -> Frame:
    """The type-17 frame a motor sends with a parameter value."""
    data = struct.pack("<HH", value.parameter.index, 0) + encode_value(value.parameter, value.value)
    return Frame(build_id(CommType.READ_PARAMETER, _byte("motor_id", value.motor_id), _byte("host_id", host_id)), data)


def device_id_reply_frame(motor_id: int, uid: bytes) -> Frame:
    """The type-0 frame a motor answers a ping with."""
    if len(uid) != 8:
        raise ValueError(f"uid must be 8 bytes, got {len(uid)}")
    return Frame(build_id(CommType.GET_ID, _byte("motor_id", motor_id), DEVICE_ID_REPLY_DEST), bytes(uid))


__all__ = [
    "CAN_TIMEOUT",
    "CAN_TIMEOUT_TICKS_PER_S",
    "DEVICE_ID_REPLY_DEST",
    "LIMIT_CUR",
    "LIMIT_SPD",
    "LIMIT_TORQUE",
    "MAX_EXTENDED_ID",
    "MECH_POS",
    "MECH_VEL",
    "PARAMETERS",
    "RUN_MODE",
    "VBUS",
    "CommType",
    "DeviceId",
    "ExtId",
    "FaultFlag",
    "FaultReport",
    "Feedback",
    "FeedbackFault",
    "Frame",
    "MotorMode",
    "ParamType",
    "Parameter",
    "ParameterValue",
    "RunMode",
    "active_report_frame",
    "build_id",
    "can_timeout_seconds",
    "can_timeout_ticks",
    "control_frame",
    "decode_value",
    "device_id_reply_frame",
    "enable_frame",
    "encode_value",
    "fault_frame",
    "feedback_frame",
    "flag_names",
    "get_id_frame",
    "parameter_by_index",
    "parameter_reply_frame",
    "parse_device_id",
    "parse_fault",
    "parse_feedback",
    "parse_parameter",
    "read_parameter_frame",
    "set_zero_frame",
    "split_id",
    "stop_frame",
    "unpack_control",
    "unpack_parameter_request",
    "write_parameter_frame",
]
