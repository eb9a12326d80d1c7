"""RobStride frames on the host's side: the requests it sends and the replies it parses; no I/O.

Host-side parsers refuse anything that is not the frame they read (wrong type, wrong length,
addressed to another host, undefined mode) with `InvalidFrame`. The id layout, parameter table and
message records are in `robstride`.
"""

from __future__ import annotations

import struct

from armwarden.backends.can.command import MotorCommand
from armwarden.backends.can.errors import InvalidFrame
from armwarden.backends.can.mapping import decode, encode
from armwarden.backends.can.ranges import ModelRanges
from armwarden.backends.can.robstride import (
    DEVICE_ID_REPLY_DEST,
    FOUR_U16_BE,
    CommType,
    DeviceId,
    ExtId,
    FaultFlag,
    FaultReport,
    Feedback,
    FeedbackFault,
    Frame,
    MotorMode,
    Parameter,
    ParameterValue,
    build_id,
    checked_byte,
    decode_value,
    encode_value,
    parameter_by_index,
    require_robstride,
    split_id,
)

_KNOWN_FAULT_BITS = sum(flag.value for flag in FaultFlag)
_MOTOR_MODES = {int(mode): mode for mode in MotorMode}
_FEEDBACK_FAULTS = tuple(FeedbackFault(bits) for bits in range(64))  # every value of the 6 fault bits


# ------------------------------------------------------------------ requests (host side builds them)
def _request(comm_type: CommType, motor_id: int, host_id: int, data: bytes = bytes(8)) -> Frame:
    return Frame(build_id(comm_type, checked_byte("host_id", host_id), checked_byte("motor_id", motor_id)), data)


def get_id_frame(motor_id: int, host_id: int) -> Frame:
    """Type 0: ask the motor for its 64-bit MCU id (a ping)."""
    return _request(CommType.GET_ID, motor_id, host_id)


def control_frame(motor_id: int, command: MotorCommand, ranges: ModelRanges) -> Frame:
    """Type 1: the impedance command; torque rides in the id, the rest big-endian in the data.
    `ValueError` if any value is non-finite or out of the model's range."""
    require_robstride(ranges)
    torque = encode(command.torque, ranges.torque, 16, "torque")
    data = FOUR_U16_BE.pack(
        encode(command.position, ranges.position, 16, "position"),
        encode(command.velocity, ranges.velocity, 16, "velocity"),
        encode(command.kp, ranges.kp, 16, "kp"),
        encode(command.kd, ranges.kd, 16, "kd"),
    )
    return Frame(build_id(CommType.CONTROL, torque, checked_byte("motor_id", motor_id)), data)


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


# ------------------------------------------------------------------ replies (host side parses them)
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
    require_robstride(ranges)
    fields = _expect(arbitration_id, data, CommType.FEEDBACK, host_id, "feedback frame")
    mode_bits = fields.data2 >> 14
    mode = _MOTOR_MODES.get(mode_bits)
    if mode is None:
        raise InvalidFrame(f"RobStride feedback from motor {fields.data2 & 0xFF} has undefined mode {mode_bits}")
    angle, velocity, torque, temperature = FOUR_U16_BE.unpack(data)
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


__all__ = [
    "active_report_frame",
    "control_frame",
    "enable_frame",
    "get_id_frame",
    "parse_device_id",
    "parse_fault",
    "parse_feedback",
    "parse_parameter",
    "read_parameter_frame",
    "set_zero_frame",
    "stop_frame",
    "write_parameter_frame",
]
