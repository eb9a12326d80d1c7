"""MIT-mode frames (Mini-Cheetah style, CubeMars AK in MIT mode): pure functions, no I/O.

Command: standard 11-bit id = motor id, 8 bytes, big-endian bit packing of position (16 bits),
velocity (12), kp (12), kd (12), feed-forward torque (12), each over the model's range. Three
special 8-byte frames enter/exit motor mode and set the current position as zero. The actuator
answers every frame (specials included) with a 6-byte reply (motor id, position, velocity,
torque) or an 8-byte one that adds temperature [°C] and an error code. The reported position
wraps at ±P_MAX: `PositionUnwrapper` keeps it continuous.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from armwarden.backends.can.command import MotorCommand
from armwarden.backends.can.errors import InvalidFrame
from armwarden.backends.can.mapping import decode, encode
from armwarden.backends.can.ranges import ModelRanges, Protocol

#: largest standard (11-bit) CAN id
MAX_STANDARD_ID = 0x7FF
_SPECIAL_PREFIX = b"\xff" * 7


class Special(enum.Enum):
    """The special MIT-mode frames, by their data bytes."""

    ENTER_MOTOR_MODE = _SPECIAL_PREFIX + b"\xfc"
    EXIT_MOTOR_MODE = _SPECIAL_PREFIX + b"\xfd"
    SET_ZERO = _SPECIAL_PREFIX + b"\xfe"  # the motor is silent for about a second afterwards


class MitError(enum.IntEnum):
    """The error code in byte 7 of an 8-byte CubeMars reply."""

    NONE = 0
    OVER_TEMPERATURE = 1
    OVER_CURRENT = 2
    OVER_VOLTAGE = 3
    UNDER_VOLTAGE = 4
    ENCODER = 5
    PHASE_CURRENT_UNBALANCE = 6


@dataclass(frozen=True)
class MitReply:
    """A parsed reply: `position` [rad] as reported (wrapped), `velocity` [rad/s], `torque` [N·m];
    `temperature_c` and `error` only in 8-byte replies (None in 6-byte ones)."""

    motor_id: int
    position: float
    velocity: float
    torque: float
    temperature_c: int | None = None
    error: MitError | None = None


def _require_mit(ranges: ModelRanges) -> None:
    if ranges.protocol is not Protocol.MIT:
        raise ValueError(f"model {ranges.model} does not speak MIT mode")


def pack_command(command: MotorCommand, ranges: ModelRanges) -> bytes:
    """The 8 data bytes of `command`; `ValueError` if any value is non-finite or out of range."""
    _require_mit(ranges)
    p = encode(command.position, ranges.position, 16, "position")
    v = encode(command.velocity, ranges.velocity, 12, "velocity")
    kp = encode(command.kp, ranges.kp, 12, "kp")
    kd = encode(command.kd, ranges.kd, 12, "kd")
    t = encode(command.torque, ranges.torque, 12, "torque")
    return bytes((
        p >> 8, p & 0xFF,
        v >> 4, ((v & 0xF) << 4) | (kp >> 8), kp & 0xFF,
        kd >> 4, ((kd & 0xF) << 4) | (t >> 8), t & 0xFF,
    ))  # fmt: skip


def special_of(data: bytes) -> Special | None:
    """The special frame `data` is, or None for an ordinary command."""
    try:
        return Special(bytes(data))
    except ValueError:
        return None


def unpack_command(data: bytes, ranges: ModelRanges) -> MotorCommand:
    """The command in 8 data bytes (the actuator's side; used by the emulator). Special frames
    are not commands: check `special_of` first."""
    _require_mit(ranges)
    if len(data) != 8:
        raise InvalidFrame(f"MIT command must have 8 data bytes, got {len(data)}")
    if special_of(data) is not None:
        raise InvalidFrame("MIT special frame is not a command")
    b = bytes(data)
    return MotorCommand(
        position=decode((b[0] << 8) | b[1], ranges.position, 16),
        velocity=decode((b[2] << 4) | (b[3] >> 4), ranges.velocity, 12),
        kp=decode(((b[3] & 0xF) << 8) | b[4], ranges.kp, 12),
        kd=decode((b[5] << 4) | (b[6] >> 4), ranges.kd, 12),
        torque=decode(((b[6] & 0xF) << 8) | b[7], ranges.torque, 12),
    )


def pack_reply(reply: MitReply, ranges: ModelRanges) -> bytes:
    """The data bytes of `reply` (8 if it carries temperature and error, else 6)."""
    _require_mit(ranges)
    if not 0 <= reply.motor_id <= 0xFF:
        raise ValueError(f"motor_id must fit in one byte, got {reply.motor_id}")
    p = encode(reply.position, ranges.position, 16, "position")
    v = encode(reply.velocity, ranges.velocity, 12, "velocity")
    t = encode(reply.torque, ranges.torque, 12, "torque")
    data = bytes((reply.motor_id, p >> 8, p & 0xFF, v >> 4, ((v & 0xF) << 4) | (t >> 8), t & 0xFF))
    if reply.temperature_c is None and reply.error is None:
        return data
    temperature = 0 if reply.temperature_c is None else reply.temperature_c
    if not 0 <= temperature <= 0xFF:
        raise ValueError(f"temperature_c must fit in one byte, got {temperature}")
    return data + bytes((temperature, int(reply.error or MitError.NONE)))


def parse_reply(data: bytes, ranges: ModelRanges, *, motor_id: int | None = None) -> MitReply:
    """The reply in `data` (6 or 8 bytes); `InvalidFrame` for another length, an unknown error
    code, or (if `motor_id` is given) a reply from another motor."""
    _require_mit(ranges)
    b = bytes(data)
    if len(b) not in (6, 8):
        raise InvalidFrame(f"MIT reply must have 6 or 8 data bytes, got {len(b)}")
    if motor_id is not None and b[0] != motor_id:
        raise InvalidFrame(f"MIT reply from motor {b[0]}, expected motor {motor_id}")
    temperature: int | None = None
    error: MitError | None = None
    if len(b) == 8:
        temperature = b[6]
        try:
            error = MitError(b[7])
        except ValueError:
            raise InvalidFrame(f"MIT reply from motor {b[0]} has unknown error code {b[7]}") from None
    return MitReply(
        motor_id=b[0],
        position=decode((b[1] << 8) | b[2], ranges.position, 16),
        velocity=decode((b[3] << 4) | (b[4] >> 4), ranges.velocity, 12),
        torque=decode(((b[4] & 0xF) << 8) | b[5], ranges.torque, 12),
        temperature_c=temperature,
        error=error,
    )


class PositionUnwrapper:
    """Turns a position that wraps over [lo, hi] into a continuous one.

    Assumes the shaft moves less than half the range between two samples (at 500 Hz that is
    6250 rad/s for ±12.5 rad). The first sample is taken as it is.
    """

    def __init__(self, lo: float, hi: float) -> None:
        if not lo < hi:
            raise ValueError(f"wrap range must have lo < hi, got [{lo}, {hi}]")
        self._span = hi - lo
        self._last_raw: float | None = None
        self._position = 0.0

    @property
    def position(self) -> float | None:
        """The continuous position [rad], None before the first sample."""
        return None if self._last_raw is None else self._position

    def update(self, raw: float) -> float:
        """Feed one reported position; return the continuous one."""
        if self._last_raw is None:
            self._position = raw
        else:
            delta = raw - self._last_raw
            half = self._span / 2
            if delta > half:
                delta -= self._span
            elif delta < -half:
                delta += self._span
            self._position += delta
        self._last_raw = raw
        return self._position

    def reset(self) -> None:
        """Forget the history (after zeroing the actuator)."""
        self._last_raw = None


__all__ = [
    "MAX_STANDARD_ID",
    "MitError",
    "MitReply",
    "PositionUnwrapper",
    "Special",
    "pack_command",
    "pack_reply",
    "parse_reply",
    "special_of",
    "unpack_command",
]
