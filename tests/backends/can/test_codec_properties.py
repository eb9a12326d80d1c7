"""Properties of the codecs, for every model and field: round trips within one LSB, bad values
refused, and random bytes either parse or raise `InvalidFrame` (never another exception)."""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from armwarden.backends.can import mit
from armwarden.backends.can import robstride as rs
from armwarden.backends.can import robstride_device as rs_device
from armwarden.backends.can import robstride_frames as rs_frames
from armwarden.backends.can.command import MotorCommand
from armwarden.backends.can.errors import InvalidFrame
from armwarden.backends.can.mapping import decode, encode, lsb
from armwarden.backends.can.ranges import MODELS, ModelRanges, Protocol, Range

# one example costs microseconds, but there are ~100 parametrised properties: a modest budget each
PROPERTY = settings(max_examples=100, deadline=None)
PER_FIELD = settings(max_examples=25, deadline=None)  # 55 model x field cases
FIELDS = ("position", "velocity", "kp", "kd", "torque")
MIT_MODELS = [r for r in MODELS.values() if r.protocol is Protocol.MIT]
ROBSTRIDE_MODELS = [r for r in MODELS.values() if r.protocol is Protocol.ROBSTRIDE]
HOST = 0xFD


def within(r: Range) -> st.SearchStrategy[float]:
    return st.floats(min_value=r.lo, max_value=r.hi, allow_nan=False)


@st.composite
def commands(draw: st.DrawFn, ranges: ModelRanges) -> MotorCommand:
    return MotorCommand(*(draw(within(getattr(ranges, name))) for name in FIELDS))


def assert_within_one_lsb(sent: MotorCommand, received: MotorCommand, ranges: ModelRanges, bits: dict[str, int]) -> None:
    for name in FIELDS:
        tolerance = lsb(getattr(ranges, name), bits[name]) * (1 + 1e-9)
        assert abs(getattr(received, name) - getattr(sent, name)) <= tolerance, name


MIT_BITS = {"position": 16, "velocity": 12, "kp": 12, "kd": 12, "torque": 12}
RS_BITS = dict.fromkeys(FIELDS, 16)


@pytest.mark.parametrize("ranges", MIT_MODELS, ids=lambda r: r.model)
@PROPERTY
@given(data=st.data())
def test_mit_command_round_trips_within_one_lsb(ranges: ModelRanges, data: st.DataObject) -> None:
    command = data.draw(commands(ranges))
    packed = mit.pack_command(command, ranges)
    if mit.special_of(packed) is None:  # all-ones values collide with the special frames by design
        assert_within_one_lsb(command, mit.unpack_command(packed, ranges), ranges, MIT_BITS)


@pytest.mark.parametrize("ranges", ROBSTRIDE_MODELS, ids=lambda r: r.model)
@PROPERTY
@given(data=st.data(), motor_id=st.integers(0, 255))
def test_robstride_control_round_trips_within_one_lsb(ranges: ModelRanges, data: st.DataObject, motor_id: int) -> None:
    command = data.draw(commands(ranges))
    frame = rs_frames.control_frame(motor_id, command, ranges)
    received_id, received = rs_device.unpack_control(frame.arbitration_id, frame.data, ranges)
    assert received_id == motor_id
    assert_within_one_lsb(command, received, ranges, RS_BITS)


@pytest.mark.parametrize("ranges", MIT_MODELS, ids=lambda r: r.model)
@PROPERTY
@given(data=st.data())
def test_mit_reply_round_trips_within_one_lsb(ranges: ModelRanges, data: st.DataObject) -> None:
    reply = mit.MitReply(
        data.draw(st.integers(0, 255)), data.draw(within(ranges.position)), data.draw(within(ranges.velocity)),
        data.draw(within(ranges.torque)), data.draw(st.integers(0, 255)), data.draw(st.sampled_from(mit.MitError)),
    )
    parsed = mit.parse_reply(mit.pack_reply(reply, ranges), ranges, motor_id=reply.motor_id)
    assert (parsed.temperature_c, parsed.error) == (reply.temperature_c, reply.error)
    assert abs(parsed.position - reply.position) <= lsb(ranges.position, 16) * (1 + 1e-9)
    assert abs(parsed.torque - reply.torque) <= lsb(ranges.torque, 12) * (1 + 1e-9)


@pytest.mark.parametrize("ranges", ROBSTRIDE_MODELS, ids=lambda r: r.model)
@PROPERTY
@given(data=st.data())
def test_robstride_feedback_round_trips_within_one_lsb(ranges: ModelRanges, data: st.DataObject) -> None:
    feedback = rs.Feedback(
        data.draw(st.integers(0, 255)), data.draw(st.sampled_from(rs.MotorMode)), rs.FeedbackFault(data.draw(st.integers(0, 63))),
        data.draw(within(ranges.position)), data.draw(within(ranges.velocity)), data.draw(within(ranges.torque)),
        data.draw(st.integers(0, 6553)) / 10,
    )
    frame = rs_device.feedback_frame(feedback, ranges, host_id=HOST)
    parsed = rs_frames.parse_feedback(frame.arbitration_id, frame.data, ranges, host_id=HOST)
    assert (parsed.motor_id, parsed.mode, parsed.faults, parsed.temperature_c) == (
        feedback.motor_id, feedback.mode, feedback.faults, feedback.temperature_c
    )
    for name in ("position", "velocity", "torque"):
        assert abs(getattr(parsed, name) - getattr(feedback, name)) <= lsb(getattr(ranges, name), 16) * (1 + 1e-9), name


@pytest.mark.parametrize("ranges", list(MODELS.values()), ids=lambda r: r.model)
@pytest.mark.parametrize("field", FIELDS)
@PER_FIELD
@given(data=st.data())
def test_every_field_refuses_values_outside_its_range(ranges: ModelRanges, field: str, data: st.DataObject) -> None:
    r: Range = getattr(ranges, field)
    bad = data.draw(st.one_of(
        st.sampled_from([math.nan, math.inf, -math.inf]),
        st.floats(max_value=r.lo, exclude_max=True, allow_nan=False),
        st.floats(min_value=r.hi, exclude_min=True, allow_nan=False),
    ))
    values = {name: (getattr(ranges, name).lo + getattr(ranges, name).hi) / 2 for name in FIELDS}
    command = MotorCommand(**{**values, field: bad})
    pack = mit.pack_command if ranges.protocol is Protocol.MIT else (lambda c, r: rs_frames.control_frame(1, c, r))
    with pytest.raises(ValueError, match=field):
        pack(command, ranges)


@PROPERTY
@given(bits=st.integers(1, 32), lo=st.floats(-1e6, 1e6), width=st.floats(1e-3, 1e6), fraction=st.floats(0, 1))
def test_mapping_round_trips_within_one_lsb_on_any_range(bits: int, lo: float, width: float, fraction: float) -> None:
    r = Range(lo, lo + width)
    value = min(r.lo + fraction * r.span, r.hi)
    assert abs(decode(encode(value, r, bits, "x"), r, bits) - value) <= lsb(r, bits) * (1 + 1e-6) + 1e-9 * abs(value)


def _parsers() -> list[tuple[str, Callable[[int, bytes], object]]]:
    parsers: list[tuple[str, Callable[[int, bytes], object]]] = [
        ("split_id", lambda i, _d: rs.split_id(i)),
        ("rs_frames.parse_fault", lambda i, d: rs_frames.parse_fault(i, d, host_id=HOST)),
        ("rs_frames.parse_parameter", lambda i, d: rs_frames.parse_parameter(i, d, host_id=HOST)),
        ("rs_frames.parse_device_id", rs_frames.parse_device_id),
        ("rs_device.unpack_parameter_request", lambda _i, d: rs_device.unpack_parameter_request(d)),
    ]
    for r in MODELS.values():
        if r.protocol is Protocol.MIT:
            parsers.append((f"mit.parse_reply[{r.model}]", lambda _i, d, r=r: mit.parse_reply(d, r, motor_id=1)))
            parsers.append((f"mit.unpack_command[{r.model}]", lambda _i, d, r=r: mit.unpack_command(d, r)))
        else:
            parsers.append((f"rs_frames.parse_feedback[{r.model}]", lambda i, d, r=r: rs_frames.parse_feedback(i, d, r, host_id=HOST)))
            parsers.append((f"rs_device.unpack_control[{r.model}]", lambda i, d, r=r: rs_device.unpack_control(i, d, r)))
    return parsers


@pytest.mark.parametrize(("name", "parse"), _parsers(), ids=[name for name, _ in _parsers()])
@PROPERTY
@given(arbitration_id=st.integers(0, (1 << 32) - 1), data=st.binary(max_size=12))
def test_random_frames_parse_or_raise_invalid_frame(
    name: str, parse: Callable[[int, bytes], object], arbitration_id: int, data: bytes
) -> None:
    try:
        parsed = parse(arbitration_id, data)
    except InvalidFrame:
        return  # refused the way callers count as an invalid frame; any other exception fails the test
    assert parsed is not None


@PROPERTY
@given(fields=st.tuples(st.integers(0, 31), st.integers(0, 0xFFFF), st.integers(0, 0xFF)))
def test_extended_ids_split_into_the_fields_they_were_built_from(fields: tuple[int, int, int]) -> None:
    assert rs.split_id(rs.build_id(*fields)) == rs.ExtId(*fields)


@pytest.mark.parametrize("parameter", rs.PARAMETERS, ids=lambda p: p.name)
@PROPERTY
@given(data=st.data())
def test_parameter_values_round_trip(parameter: rs.Parameter, data: st.DataObject) -> None:
    if parameter.type is rs.ParamType.F32:
        value: float = data.draw(st.floats(width=32, allow_nan=False, allow_infinity=False))
    else:
        value = data.draw(st.integers(0, 0xFF if parameter.type is rs.ParamType.U8 else 0xFFFFFFFF))
    reply = rs_device.parameter_reply_frame(rs.ParameterValue(1, parameter, value), host_id=HOST)
    assert rs_frames.parse_parameter(reply.arbitration_id, reply.data, host_id=HOST).value == value
