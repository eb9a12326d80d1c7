"""RobStride private protocol (RS00–RS06, 29-bit extended ids): its vocabulary, no frames built here.

The id is `(type << 24) | (data2 << 8) | dest`: bits 28–24 the communication type, 23–8 "data
area 2" (in requests normally the host id in bits 15–8; in the type-1 control frame the torque),
7–0 the destination (the motor in requests, the host in replies). Control (type 1) and feedback
(type 2) data are big-endian u16 values over the model's ranges; parameter frames (types 17/18)
are little-endian. This module holds what both ends share: the communication types, mode and
fault bits, the parameter table and its value codec, the id layout and the decoded messages.
The host builds and parses frames in `robstride_frames`; the emulated actuator answers with
`robstride_device`.
"""

from __future__ import annotations

import enum
import functools
import math
import struct
from dataclasses import dataclass

from armwarden.backends.can.errors import InvalidFrame
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
FOUR_U16_BE = struct.Struct(">HHHH")


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


def require_robstride(ranges: ModelRanges) -> None:
    """`ValueError` unless `ranges` is a RobStride model (its ranges would scale the frame wrongly)."""
    if ranges.protocol is not Protocol.ROBSTRIDE:
        raise ValueError(f"model {ranges.model} does not speak the RobStride protocol")


def checked_byte(name: str, value: int) -> int:
    """`value` if it fits an id's byte field; `ValueError` instead of a silently truncated id."""
    if not 0 <= value <= 0xFF:
        raise ValueError(f"{name} must fit in one byte, got {value}")
    return value


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


# ------------------------------------------------------------------ decoded messages
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


__all__ = [
    "CAN_TIMEOUT",
    "CAN_TIMEOUT_TICKS_PER_S",
    "DEVICE_ID_REPLY_DEST",
    "FOUR_U16_BE",
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
    "build_id",
    "can_timeout_seconds",
    "can_timeout_ticks",
    "checked_byte",
    "decode_value",
    "encode_value",
    "flag_names",
    "parameter_by_index",
    "require_robstride",
    "split_id",
]
