"""RobStride frames on the actuator's side: what the emulator reads from the host and answers with.

Only the emulator (and tests that play a motor) use these; a real host never builds a feedback
frame. Kept apart from `robstride_frames` so the host's code has no path that forges a reply.
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
    FaultReport,
    Feedback,
    Frame,
    Parameter,
    ParameterValue,
    build_id,
    checked_byte,
    encode_value,
    parameter_by_index,
    require_robstride,
    split_id,
)


def unpack_control(arbitration_id: int, data: bytes, ranges: ModelRanges) -> tuple[int, MotorCommand]:
    """The motor id and command of a type-1 frame."""
    require_robstride(ranges)
    fields = split_id(arbitration_id)
    if fields.comm_type != CommType.CONTROL or len(data) != 8:
        raise InvalidFrame(f"not a RobStride control frame: type {fields.comm_type}, {len(data)} data bytes")
    angle, velocity, kp, kd = FOUR_U16_BE.unpack(data)
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
    require_robstride(ranges)
    temperature = round(feedback.temperature_c * 10)
    if not 0 <= temperature <= 0xFFFF:
        raise ValueError(f"temperature {feedback.temperature_c} °C does not fit the feedback frame")
    data2 = (int(feedback.mode) << 14) | (int(feedback.faults) & 0x3F) << 8 | checked_byte("motor_id", feedback.motor_id)
    data = FOUR_U16_BE.pack(
        encode(feedback.position, ranges.position, 16, "position"),
        encode(feedback.velocity, ranges.velocity, 16, "velocity"),
        encode(feedback.torque, ranges.torque, 16, "torque"),
        temperature,
    )
    return Frame(build_id(CommType.FEEDBACK, data2, checked_byte("host_id", host_id)), data)


def fault_frame(report: FaultReport, *, host_id: int) -> Frame:
    """The type-21 frame a motor sends for `report`."""
    data = struct.pack("<II", int(report.faults) | report.unknown_bits, report.warnings)
    return Frame(build_id(CommType.FAULT, checked_byte("motor_id", report.motor_id), checked_byte("host_id", host_id)), data)


def parameter_reply_frame(value: ParameterValue, *, host_id: int) -> Frame:
    """The type-17 frame a motor sends with a parameter value."""
    data = struct.pack("<HH", value.parameter.index, 0) + encode_value(value.parameter, value.value)
    return Frame(build_id(CommType.READ_PARAMETER, checked_byte("motor_id", value.motor_id), checked_byte("host_id", host_id)), data)


def device_id_reply_frame(motor_id: int, uid: bytes) -> Frame:
    """The type-0 frame a motor answers a ping with."""
    if len(uid) != 8:
        raise ValueError(f"uid must be 8 bytes, got {len(uid)}")
    return Frame(build_id(CommType.GET_ID, checked_byte("motor_id", motor_id), DEVICE_ID_REPLY_DEST), bytes(uid))


__all__ = [
    "device_id_reply_frame",
    "fault_frame",
    "feedback_frame",
    "parameter_reply_frame",
    "unpack_control",
    "unpack_parameter_request",
]
