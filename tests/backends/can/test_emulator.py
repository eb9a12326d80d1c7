"""The actuator emulator, driven through the bus layer and the codecs as a backend would drive it."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator, Sequence

import can
import pytest

from armwarden.backends.can import mit
from armwarden.backends.can import robstride as rs
from armwarden.backends.can import robstride_frames as rs_frames
from armwarden.backends.can.bus import BusConfig, CanBus, FrameKind, HealthFlag
from armwarden.backends.can.command import MotorCommand
from armwarden.backends.can.emulated_actuator import ActuatorSpec
from armwarden.backends.can.emulator import DEFAULT_HOST_ID, ActuatorEmulator
from armwarden.backends.can.ranges import model_ranges
from tests.backends.can.polling import eventually, unique_channel

AK80_9 = model_ranges("AK80-9")
RS03 = model_ranges("RS03")
MIT_ID, RS_ID = 1, 2
HOST = DEFAULT_HOST_ID


class Host:
    """The host side: a `CanBus` whose handler parses every reply with the codecs and keeps them."""

    def __init__(self, channel: str) -> None:
        self.mit_replies: list[mit.MitReply] = []
        self.feedback: list[rs.Feedback] = []
        self.parameters: list[rs.ParameterValue] = []
        self.device_ids: list[rs.DeviceId] = []
        self.faults: list[rs.FaultReport] = []
        self._lock = threading.Lock()
        self.bus = CanBus(BusConfig(channel=channel), self._handle)

    def _handle(self, msg: can.Message) -> None:
        data = bytes(msg.data)
        with self._lock:
            if not msg.is_extended_id:
                self.mit_replies.append(mit.parse_reply(data, AK80_9))
                return
            kind = rs.split_id(msg.arbitration_id).comm_type
            if kind == rs.CommType.FEEDBACK:
                self.feedback.append(rs_frames.parse_feedback(msg.arbitration_id, data, RS03, host_id=HOST))
            elif kind == rs.CommType.READ_PARAMETER:
                self.parameters.append(rs_frames.parse_parameter(msg.arbitration_id, data, host_id=HOST))
            elif kind == rs.CommType.GET_ID:
                self.device_ids.append(rs_frames.parse_device_id(msg.arbitration_id, data))
            elif kind == rs.CommType.FAULT:
                self.faults.append(rs_frames.parse_fault(msg.arbitration_id, data, host_id=HOST))

    def count(self, what: Callable[[Host], Sequence[object]]) -> Callable[[], int]:
        """A counter of the replies `what` selects, for polling."""
        def counter() -> int:
            with self._lock:
                return len(what(self))
        return counter

    def has(self, what: Callable[[Host], Sequence[object]]) -> Callable[[], bool]:
        """Whether any reply `what` selects has arrived, for polling."""
        return lambda: self.count(what)() > 0

    def send_mit(self, data: bytes, kind: FrameKind = FrameKind.COMMAND) -> None:
        assert self.bus.send_frame(MIT_ID, data, extended=False, kind=kind)

    def send_rs(self, frame: rs.Frame, kind: FrameKind) -> None:
        assert self.bus.send_frame(frame.arbitration_id, frame.data, extended=True, kind=kind)

    def request_mit(self, data: bytes) -> mit.MitReply:
        before = self.count(lambda h: h.mit_replies)()
        self.send_mit(data)
        eventually(lambda: self.count(lambda h: h.mit_replies)() > before, "the MIT actuator replied")
        with self._lock:
            return self.mit_replies[before]

    def request_rs(self, frame: rs.Frame, kind: FrameKind = FrameKind.MODE) -> rs.Feedback:
        before = self.count(lambda h: h.feedback)()
        self.send_rs(frame, kind)
        eventually(lambda: self.count(lambda h: h.feedback)() > before, "the RobStride actuator sent feedback")
        with self._lock:
            return self.feedback[before]


@pytest.fixture
def channel() -> str:
    return unique_channel()


@pytest.fixture
def emulator(channel: str) -> Iterator[ActuatorEmulator]:
    specs = [
        ActuatorSpec(MIT_ID, "AK80-9", initial_position_rad=0.0),
        ActuatorSpec(RS_ID, "RS03", initial_position_rad=0.5),
    ]
    with ActuatorEmulator(channel, specs) as emulator:
        yield emulator
    assert emulator.error is None


@pytest.fixture
def host(channel: str, emulator: ActuatorEmulator) -> Iterator[Host]:
    host = Host(channel)
    with host.bus:
        yield host


def near(target: float, tolerance: float = 0.02) -> Callable[[float], bool]:
    return lambda value: abs(value - target) < tolerance


def test_mit_actuator_converges_to_the_commanded_position(emulator: ActuatorEmulator, host: Host) -> None:
    host.request_mit(mit.Special.ENTER_MOTOR_MODE.value)
    host.request_mit(mit.pack_command(MotorCommand(position=1.0, velocity=0.0, kp=20.0, kd=1.0, torque=0.0), AK80_9))
    eventually(lambda: near(1.0)(emulator.snapshot(MIT_ID).position_rad), "the MIT actuator reached 1 rad")
    eventually(lambda: near(1.0)(host.request_mit(mit.Special.ENTER_MOTOR_MODE.value).position), "its reply reports 1 rad")


def test_robstride_actuator_converges_to_the_commanded_position(emulator: ActuatorEmulator, host: Host) -> None:
    assert host.request_rs(rs_frames.enable_frame(RS_ID, HOST)).mode is rs.MotorMode.RUN
    command = MotorCommand(position=-0.5, velocity=0.0, kp=30.0, kd=2.0, torque=0.0)
    host.request_rs(rs_frames.control_frame(RS_ID, command, RS03), FrameKind.COMMAND)
    eventually(lambda: near(-0.5)(emulator.snapshot(RS_ID).position_rad), "the RobStride actuator reached -0.5 rad")
    eventually(lambda: near(-0.5)(host.request_rs(rs_frames.enable_frame(RS_ID, HOST)).position), "its feedback reports -0.5 rad")


def test_gravity_load_leaves_the_steady_state_error_of_the_stiffness(channel: str) -> None:
    spec = ActuatorSpec(RS_ID, "RS03", gravity_torque_nm=6.0)
    with ActuatorEmulator(channel, [spec]) as emulator, Host(channel).bus as bus:
        bus.send_frame(*_fields(rs_frames.enable_frame(RS_ID, HOST)), extended=True, kind=FrameKind.MODE)
        eventually(lambda: emulator.snapshot(RS_ID).enabled, "enabled")
        command = MotorCommand(position=0.0, velocity=0.0, kp=60.0, kd=3.0, torque=0.0)
        bus.send_frame(*_fields(rs_frames.control_frame(RS_ID, command, RS03)), extended=True, kind=FrameKind.COMMAND)
        eventually(lambda: near(-0.1, 0.01)(emulator.snapshot(RS_ID).position_rad), "sagged to -g/kp = -0.1 rad")


def test_a_disabled_actuator_applies_no_torque(emulator: ActuatorEmulator, host: Host) -> None:
    command = MotorCommand(position=2.0, velocity=0.0, kp=50.0, kd=1.0, torque=5.0)
    reply = host.request_rs(rs_frames.control_frame(RS_ID, command, RS03), FrameKind.COMMAND)
    assert reply.mode is rs.MotorMode.RESET
    snapshot = emulator.snapshot(RS_ID)
    assert (snapshot.enabled, snapshot.torque_nm, snapshot.command.kp) == (False, 0.0, 0.0)


def test_torque_is_clipped_to_the_torque_limit(channel: str) -> None:
    with ActuatorEmulator(channel, [ActuatorSpec(MIT_ID, "AK80-9", torque_limit_nm=2.0, inertia_kgm2=50.0)]) as emulator:
        host = Host(channel)
        with host.bus:
            host.request_mit(mit.Special.ENTER_MOTOR_MODE.value)
            host.request_mit(mit.pack_command(MotorCommand(10.0, 0.0, 100.0, 0.0, 0.0), AK80_9))
            eventually(lambda: emulator.snapshot(MIT_ID).torque_nm == 2.0, "the torque saturated at 2 N·m")


def test_exit_motor_mode_removes_the_torque(emulator: ActuatorEmulator, host: Host) -> None:
    host.request_mit(mit.Special.ENTER_MOTOR_MODE.value)
    host.request_mit(mit.pack_command(MotorCommand(1.0, 0.0, 20.0, 1.0, 0.0), AK80_9))
    host.request_mit(mit.Special.EXIT_MOTOR_MODE.value)
    eventually(lambda: emulator.snapshot(MIT_ID).torque_nm == 0.0, "no torque after exit")
    assert not emulator.snapshot(MIT_ID).enabled


def test_can_timeout_written_by_the_host_stops_a_silent_hosts_motor(channel: str) -> None:
    spec = ActuatorSpec(RS_ID, "RS03", gravity_torque_nm=6.0)
    with ActuatorEmulator(channel, [spec]) as emulator:
        host = Host(channel)
        with host.bus:
            host.request_rs(rs_frames.write_parameter_frame(RS_ID, HOST, rs.CAN_TIMEOUT, rs.can_timeout_ticks(0.2)), FrameKind.PARAMETER)
            host.request_rs(rs_frames.enable_frame(RS_ID, HOST))
            host.request_rs(rs_frames.control_frame(RS_ID, MotorCommand(0.0, 0.0, 60.0, 3.0, 0.0), RS03), FrameKind.COMMAND)
        # the host is gone: nothing more arrives
        eventually(lambda: emulator.snapshot(RS_ID).timeouts == 1, "the CAN timeout fired")
        snapshot = emulator.snapshot(RS_ID)
        assert (snapshot.enabled, snapshot.torque_nm) == (False, 0.0)


def test_can_timeout_is_readable_as_a_parameter(emulator: ActuatorEmulator, host: Host) -> None:
    host.request_rs(rs_frames.write_parameter_frame(RS_ID, HOST, rs.CAN_TIMEOUT, 4000), FrameKind.PARAMETER)
    host.send_rs(rs_frames.read_parameter_frame(RS_ID, HOST, rs.CAN_TIMEOUT), FrameKind.PARAMETER)
    eventually(host.has(lambda h: h.parameters), "the parameter was read")
    assert (host.parameters[0].parameter, host.parameters[0].value) == (rs.CAN_TIMEOUT, 4000)


def test_mechanical_position_parameter_reports_the_position(emulator: ActuatorEmulator, host: Host) -> None:
    host.send_rs(rs_frames.read_parameter_frame(RS_ID, HOST, rs.MECH_POS), FrameKind.PARAMETER)
    eventually(host.has(lambda h: h.parameters), "the parameter was read")
    assert host.parameters[0].value == pytest.approx(0.5, abs=1e-3)


def test_a_ping_is_answered_with_the_device_id(emulator: ActuatorEmulator, host: Host) -> None:
    host.send_rs(rs_frames.get_id_frame(RS_ID, HOST), FrameKind.QUERY)
    eventually(host.has(lambda h: h.device_ids), "the ping was answered")
    assert host.device_ids[0].motor_id == RS_ID


def test_a_silenced_actuator_stops_replying(emulator: ActuatorEmulator, host: Host) -> None:
    emulator.silence(RS_ID)
    host.send_rs(rs_frames.enable_frame(RS_ID, HOST), FrameKind.MODE)
    host.request_mit(mit.Special.ENTER_MOTOR_MODE.value)  # served after the silent actuator's frame
    assert host.count(lambda h: h.feedback)() == 0
    assert emulator.snapshot(RS_ID).enabled  # it still obeys


def test_a_raised_fault_bit_appears_in_robstride_feedback(emulator: ActuatorEmulator, host: Host) -> None:
    emulator.raise_fault(RS_ID, rs.FeedbackFault.MAGNETIC_ENCODER)
    assert host.request_rs(rs_frames.enable_frame(RS_ID, HOST)).faults == rs.FeedbackFault.MAGNETIC_ENCODER


def test_stop_with_clear_faults_clears_the_fault_bits(emulator: ActuatorEmulator, host: Host) -> None:
    emulator.raise_fault(RS_ID, rs.FeedbackFault.STALL_OVERLOAD)
    assert host.request_rs(rs_frames.stop_frame(RS_ID, HOST, clear_faults=True)).faults == rs.FeedbackFault(0)


def test_a_raised_error_code_appears_in_mit_replies(emulator: ActuatorEmulator, host: Host) -> None:
    emulator.raise_fault(MIT_ID, mit.MitError.OVER_CURRENT)
    assert host.request_mit(mit.Special.ENTER_MOTOR_MODE.value).error is mit.MitError.OVER_CURRENT


def test_an_overheated_actuator_reports_its_temperature(emulator: ActuatorEmulator, host: Host) -> None:
    emulator.overheat(MIT_ID, 95.0)
    emulator.overheat(RS_ID, 101.5)
    assert host.request_mit(mit.Special.ENTER_MOTOR_MODE.value).temperature_c == 95
    assert host.request_rs(rs_frames.enable_frame(RS_ID, HOST)).temperature_c == 101.5


def test_a_fault_frame_is_parsed_with_its_named_bits(emulator: ActuatorEmulator, host: Host) -> None:
    emulator.emit_fault_frame(RS_ID, rs.FaultFlag.OVER_VOLTAGE)
    eventually(host.has(lambda h: h.faults), "the fault frame arrived")
    assert rs.flag_names(host.faults[0].faults) == ("OVER_VOLTAGE",)


@pytest.mark.parametrize("can_id", [MIT_ID, RS_ID])
def test_garbage_frames_are_counted_as_invalid_by_the_bus_layer(emulator: ActuatorEmulator, host: Host, can_id: int) -> None:
    emulator.send_garbage(can_id, count=3)
    eventually(lambda: host.bus.health().invalid_frames == 3, "three invalid frames counted")
    assert HealthFlag.INVALID_FRAME in host.bus.health().flags


def test_a_bus_off_error_frame_reaches_the_bus_layer(emulator: ActuatorEmulator, host: Host) -> None:
    emulator.emit_error_frame(0x40)
    eventually(lambda: HealthFlag.BUS_OFF in host.bus.health().flags, "BUS_OFF flagged")


def test_actuator_ids_must_be_unique(channel: str) -> None:
    with pytest.raises(ValueError, match="two actuators with can_id 3"):
        ActuatorEmulator(channel, [ActuatorSpec(3, "AK80-9"), ActuatorSpec(3, "RS03")])


def test_spec_refuses_non_physical_loads() -> None:
    with pytest.raises(ValueError, match="inertia must be > 0"):
        ActuatorSpec(1, "RS03", inertia_kgm2=0.0)


def _fields(frame: rs.Frame) -> tuple[int, bytes]:
    return frame.arbitration_id, frame.data
