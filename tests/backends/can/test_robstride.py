"""RobStride frames: the golden vector, ids, byte orders, fault/mode bits, refusal of malformed frames."""

from __future__ import annotations

import math

import pytest

from armwarden.backends.can import robstride as rs
from armwarden.backends.can import robstride_device as rs_device
from armwarden.backends.can import robstride_frames as rs_frames
from armwarden.backends.can.command import MotorCommand
from armwarden.backends.can.errors import InvalidFrame
from armwarden.backends.can.mapping import lsb
from armwarden.backends.can.ranges import model_ranges

RS03 = model_ranges("RS03")
HOST = 0xFD


def test_control_frame_matches_the_golden_vector() -> None:
    frame = rs_frames.control_frame(1, MotorCommand(position=0.0, velocity=0.0, kp=50.0, kd=2.0, torque=0.0), RS03)
    assert frame.arbitration_id == 0x017FFF01
    assert frame.data == bytes.fromhex("7F FF 7F FF 02 8F 05 1E")


def test_control_frame_unpacks_on_the_motor_side_within_one_lsb() -> None:
    command = MotorCommand(position=1.25, velocity=-3.0, kp=120.0, kd=4.5, torque=-7.5)
    motor_id, unpacked = rs_device.unpack_control(*_fields(rs_frames.control_frame(9, command, RS03)), RS03)
    assert motor_id == 9
    assert unpacked.position == pytest.approx(1.25, abs=lsb(RS03.position, 16))
    assert unpacked.torque == pytest.approx(-7.5, abs=lsb(RS03.torque, 16))


def test_control_frame_refuses_out_of_range_torque() -> None:
    with pytest.raises(ValueError, match=r"torque = 61.0 is outside its range \[-60.0, 60.0\]"):
        rs_frames.control_frame(1, MotorCommand(0.0, 0.0, 0.0, 0.0, 61.0), RS03)


def test_id_fields_round_trip_and_oversized_fields_are_refused() -> None:
    arbitration_id = rs.build_id(rs.CommType.WRITE_PARAMETER, 0x00FD, 0x7F)
    assert arbitration_id == 0x1200FD7F
    assert rs.split_id(arbitration_id) == rs.ExtId(18, 0xFD, 0x7F)
    with pytest.raises(ValueError, match="destination 256 does not fit in 8 bits"):
        rs.build_id(1, 0, 256)
    with pytest.raises(InvalidFrame, match="29-bit"):
        rs.split_id(1 << 29)


def test_requests_carry_the_host_in_bits_15_to_8_and_the_motor_in_bits_7_to_0() -> None:
    assert rs_frames.enable_frame(5, HOST).arbitration_id == (3 << 24) | (HOST << 8) | 5
    assert rs_frames.get_id_frame(5, HOST) == rs.Frame((0 << 24) | (HOST << 8) | 5, bytes(8))


def test_stop_frame_clears_faults_only_when_asked() -> None:
    assert rs_frames.stop_frame(2, HOST).data == bytes(8)
    assert rs_frames.stop_frame(2, HOST, clear_faults=True).data == bytes((1, 0, 0, 0, 0, 0, 0, 0))
    assert rs.split_id(rs_frames.stop_frame(2, HOST).arbitration_id).comm_type == rs.CommType.STOP


def test_set_zero_and_active_report_frames() -> None:
    assert rs_frames.set_zero_frame(2, HOST).data[0] == 1
    assert rs.split_id(rs_frames.set_zero_frame(2, HOST).arbitration_id).comm_type == 6
    assert rs_frames.active_report_frame(2, HOST, on=True).data[6] == 1
    assert rs_frames.active_report_frame(2, HOST, on=False).data[6] == 0


def test_parameter_frames_are_little_endian() -> None:
    frame = rs_frames.write_parameter_frame(1, HOST, rs.CAN_TIMEOUT, rs.can_timeout_ticks(0.5))
    assert frame.arbitration_id >> 24 == 18
    assert frame.data == bytes.fromhex("2870 0000 1027 0000")  # index 0x7028, 10000 ticks
    assert rs_frames.read_parameter_frame(1, HOST, rs.RUN_MODE).data == bytes.fromhex("0570 0000 0000 0000")


def test_can_timeout_is_twenty_thousand_ticks_per_second() -> None:
    assert rs.can_timeout_ticks(1.0) == 20000
    assert rs.can_timeout_seconds(10000) == 0.5
    with pytest.raises(ValueError, match="non-negative"):
        rs.can_timeout_ticks(-0.1)


def test_integer_parameters_refuse_fractions_and_overflow() -> None:
    with pytest.raises(ValueError, match="integer parameter"):
        rs_frames.write_parameter_frame(1, HOST, rs.RUN_MODE, 1.5)
    with pytest.raises(ValueError, match=r"run_mode = 256 is outside \[0, 255\]"):
        rs_frames.write_parameter_frame(1, HOST, rs.RUN_MODE, 256)
    with pytest.raises(ValueError, match="limit_torque must be a finite number"):
        rs_frames.write_parameter_frame(1, HOST, rs.LIMIT_TORQUE, math.inf)


def test_parameter_reply_is_parsed_with_its_type() -> None:
    frame = rs_device.parameter_reply_frame(rs.ParameterValue(4, rs.VBUS, 24.5), host_id=HOST)
    value = rs_frames.parse_parameter(*_fields(frame), host_id=HOST)
    assert (value.motor_id, value.parameter, value.value) == (4, rs.VBUS, 24.5)


def test_parameter_reply_with_an_unknown_index_is_an_invalid_frame() -> None:
    with pytest.raises(InvalidFrame, match="unknown RobStride parameter index 0x1234"):
        rs_frames.parse_parameter(rs.build_id(17, 4, HOST), bytes.fromhex("3412 0000 0000 0000"), host_id=HOST)


def test_feedback_carries_mode_and_fault_bits_in_the_id() -> None:
    feedback = rs.Feedback(
        motor_id=7, mode=rs.MotorMode.RUN, faults=rs.FeedbackFault.OVER_TEMPERATURE | rs.FeedbackFault.UNDER_VOLTAGE,
        position=-1.0, velocity=2.0, torque=3.0, temperature_c=45.3,
    )
    frame = rs_device.feedback_frame(feedback, RS03, host_id=HOST)
    assert frame.arbitration_id == (2 << 24) | (2 << 22) | (0b101 << 16) | (7 << 8) | HOST
    parsed = rs_frames.parse_feedback(*_fields(frame), RS03, host_id=HOST)
    assert parsed.faults == rs.FeedbackFault.OVER_TEMPERATURE | rs.FeedbackFault.UNDER_VOLTAGE
    assert (parsed.motor_id, parsed.mode, parsed.temperature_c) == (7, rs.MotorMode.RUN, 45.3)
    assert parsed.position == pytest.approx(-1.0, abs=lsb(RS03.position, 16))


def test_feedback_data_is_big_endian() -> None:
    frame = rs_device.feedback_frame(rs.Feedback(1, rs.MotorMode.RESET, rs.FeedbackFault(0), 0.0, 0.0, 0.0, 25.0), RS03, host_id=0)
    assert frame.data == bytes.fromhex("7FFF 7FFF 7FFF 00FA")


def test_feedback_addressed_to_another_host_is_an_invalid_frame() -> None:
    frame = rs_device.feedback_frame(rs.Feedback(1, rs.MotorMode.RUN, rs.FeedbackFault(0), 0.0, 0.0, 0.0, 25.0), RS03, host_id=0x10)
    with pytest.raises(InvalidFrame, match="addressed to 0x10, expected 0xFD"):
        rs_frames.parse_feedback(*_fields(frame), RS03, host_id=HOST)


def test_feedback_of_the_wrong_type_or_length_is_an_invalid_frame() -> None:
    with pytest.raises(InvalidFrame, match="expected a RobStride feedback frame"):
        rs_frames.parse_feedback(rs.build_id(17, 1, HOST), bytes(8), RS03, host_id=HOST)
    with pytest.raises(InvalidFrame, match="8 data bytes, got 6"):
        rs_frames.parse_feedback(rs.build_id(2, 1, HOST), bytes(6), RS03, host_id=HOST)


def test_feedback_with_undefined_mode_is_an_invalid_frame() -> None:
    with pytest.raises(InvalidFrame, match="undefined mode 3"):
        rs_frames.parse_feedback(rs.build_id(2, (3 << 14) | 1, HOST), bytes(8), RS03, host_id=HOST)


def test_fault_frame_names_its_bits_and_keeps_undocumented_ones() -> None:
    report = rs.FaultReport(3, rs.FaultFlag.STALL_OVERLOAD | rs.FaultFlag.PHASE_A_OVER_CURRENT, unknown_bits=1 << 30, warnings=1)
    parsed = rs_frames.parse_fault(*_fields(rs_device.fault_frame(report, host_id=HOST)), host_id=HOST)
    assert parsed == report
    assert rs.flag_names(parsed.faults) == ("STALL_OVERLOAD", "PHASE_A_OVER_CURRENT")


def test_ping_reply_carries_the_uid() -> None:
    frame = rs_device.device_id_reply_frame(12, bytes(range(8)))
    assert rs.split_id(frame.arbitration_id).dest == 0xFE
    assert rs_frames.parse_device_id(*_fields(frame)) == rs.DeviceId(12, bytes(range(8)))


def _fields(frame: rs.Frame) -> tuple[int, bytes]:
    return frame.arbitration_id, frame.data


def test_flag_names_tell_apart_flags_of_two_types_with_the_same_value() -> None:
    # the names are cached: FeedbackFault(1) == FaultFlag(1) as integers, yet they name different faults
    assert rs.flag_names(rs.FeedbackFault(1)) == ("UNDER_VOLTAGE",)
    assert rs.flag_names(rs.FaultFlag(1)) == ("OVER_TEMPERATURE",)
    assert rs.flag_names(rs.FeedbackFault(0)) == ()
