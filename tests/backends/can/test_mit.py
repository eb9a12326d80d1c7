"""MIT-mode frames: the golden vector, special frames, replies and position unwrapping."""

from __future__ import annotations

import math

import pytest

from armwarden.backends.can import mit
from armwarden.backends.can.command import MotorCommand
from armwarden.backends.can.errors import InvalidFrame
from armwarden.backends.can.mapping import lsb
from armwarden.backends.can.mit import MitError, MitReply, PositionUnwrapper, Special
from armwarden.backends.can.ranges import model_ranges

AK80_9 = model_ranges("AK80-9")


def test_command_packs_to_the_golden_vector() -> None:
    data = mit.pack_command(MotorCommand(position=1.0, velocity=0.0, kp=10.0, kd=0.5, torque=0.0), AK80_9)
    assert data == bytes.fromhex("8A 3C 7F F0 51 19 97 FF")


def test_golden_vector_unpacks_within_one_lsb_of_the_command() -> None:
    command = mit.unpack_command(bytes.fromhex("8A3C7FF0511997FF"), AK80_9)
    assert command.position == pytest.approx(1.0, abs=lsb(AK80_9.position, 16))
    assert command.kp == pytest.approx(10.0, abs=lsb(AK80_9.kp, 12))
    assert command.kd == pytest.approx(0.5, abs=lsb(AK80_9.kd, 12))


def test_command_out_of_the_model_range_is_refused() -> None:
    with pytest.raises(ValueError, match=r"torque = 20.0 is outside its range \[-18.0, 18.0\]"):
        mit.pack_command(MotorCommand(0.0, 0.0, 0.0, 1.0, 20.0), AK80_9)


def test_nan_gain_is_refused() -> None:
    with pytest.raises(ValueError, match="kd must be a finite number"):
        mit.pack_command(MotorCommand(0.0, 0.0, 0.0, math.nan, 0.0), AK80_9)


def test_command_for_a_robstride_model_is_refused() -> None:
    with pytest.raises(ValueError, match="does not speak MIT mode"):
        mit.pack_command(MotorCommand(0.0, 0.0, 0.0, 0.0, 0.0), model_ranges("RS03"))


def test_special_frames_are_recognised_and_are_not_commands() -> None:
    assert Special.ENTER_MOTOR_MODE.value.hex() == "fffffffffffffffc"
    assert mit.special_of(bytes.fromhex("fffffffffffffffd")) is Special.EXIT_MOTOR_MODE
    assert mit.special_of(bytes.fromhex("fffffffffffffffe")) is Special.SET_ZERO
    assert mit.special_of(bytes.fromhex("8A3C7FF0511997FF")) is None
    with pytest.raises(InvalidFrame, match="special"):
        mit.unpack_command(Special.SET_ZERO.value, AK80_9)


def test_eight_byte_reply_carries_temperature_and_error() -> None:
    reply = MitReply(motor_id=3, position=-2.0, velocity=1.5, torque=-4.0, temperature_c=41, error=MitError.OVER_CURRENT)
    parsed = mit.parse_reply(mit.pack_reply(reply, AK80_9), AK80_9, motor_id=3)
    assert (parsed.motor_id, parsed.temperature_c, parsed.error) == (3, 41, MitError.OVER_CURRENT)
    assert parsed.position == pytest.approx(-2.0, abs=lsb(AK80_9.position, 16))
    assert parsed.velocity == pytest.approx(1.5, abs=lsb(AK80_9.velocity, 12))
    assert parsed.torque == pytest.approx(-4.0, abs=lsb(AK80_9.torque, 12))


def test_six_byte_reply_has_no_temperature_or_error() -> None:
    data = mit.pack_reply(MitReply(motor_id=1, position=0.5, velocity=0.0, torque=0.0), AK80_9)
    assert len(data) == 6
    parsed = mit.parse_reply(data, AK80_9)
    assert (parsed.temperature_c, parsed.error) == (None, None)


@pytest.mark.parametrize("length", [0, 5, 7])
def test_reply_of_another_length_is_an_invalid_frame(length: int) -> None:
    with pytest.raises(InvalidFrame, match="6 or 8 data bytes"):
        mit.parse_reply(bytes(length), AK80_9)


def test_reply_from_another_motor_is_an_invalid_frame() -> None:
    data = mit.pack_reply(MitReply(motor_id=2, position=0.0, velocity=0.0, torque=0.0), AK80_9)
    with pytest.raises(InvalidFrame, match="from motor 2, expected motor 5"):
        mit.parse_reply(data, AK80_9, motor_id=5)


def test_unknown_error_code_is_an_invalid_frame() -> None:
    with pytest.raises(InvalidFrame, match="unknown error code 9"):
        mit.parse_reply(bytes((1, 0x80, 0, 0x7F, 0xF7, 0xFF, 30, 9)), AK80_9)


def test_unwrapper_keeps_position_continuous_across_the_wrap() -> None:
    unwrapper = PositionUnwrapper(-12.5, 12.5)
    assert unwrapper.position is None
    assert unwrapper.update(12.0) == 12.0
    assert unwrapper.update(-12.3) == pytest.approx(12.7)  # passed +12.5, reported from -12.5
    assert unwrapper.update(-11.0) == pytest.approx(14.0)
    assert unwrapper.update(12.4) == pytest.approx(12.4)  # back down across the wrap


def test_unwrapper_follows_ordinary_motion_unchanged() -> None:
    unwrapper = PositionUnwrapper(-12.5, 12.5)
    for raw in (0.0, 1.0, -3.0, 5.5):
        assert unwrapper.update(raw) == pytest.approx(raw)
