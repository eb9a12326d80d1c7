"""Emulated CAN actuators (MIT mode and RobStride) on a python-can bus, on their own thread.

This is the bus side: frames in, the protocol's answers out, fault injection. Each actuator's
dynamics are its `EmulatedActuator` (see `emulated_actuator`), integrated lazily: an actuator is
brought up to the present when a frame reaches it, when a test looks at it, and on a
housekeeping pass every `HOUSEKEEPING_S` (which is when a silent host's CAN timeout is noticed).
Simulated time follows wall-clock time; the thread does not wake at the integration rate, so the
emulator costs the process's other threads (the servo loop it shares the interpreter with)
little more than the frames themselves.

Protocols as the notes describe them: an MIT actuator answers every frame addressed to it
(specials included) with an 8-byte reply; a RobStride actuator answers types 1/3/4/6/18 with
type-2 feedback, 17 with the parameter value, 0 with its id. The actuator-side CAN timeout
(`can_timeout_s`, for RobStride also parameter 0x7028) is honoured.

With an `ArmSetup`, the arm's actuators move one body instead: the robot model's forward dynamics
(`emulated_arm`), brought up to the present as one whenever any of them is; `push` puts a contact
force on a link of it until `release_push`, and `true_external_torques` reads back what it applied.

`place_obstacle` puts rigid stops in an actuator's way (an object between the gripper's fingers).
Fault injection (for tests and demos): `silence` (stop replying), `raise_fault`, `overheat`,
`send_garbage` (malformed frames), `emit_fault_frame` (RobStride type 21) and
`emit_error_frame` (python-can's virtual bus never produces error frames; this sends one).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from types import TracebackType

import can
import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.backends.can import mit
from armwarden.backends.can import robstride as rs
from armwarden.backends.can import robstride_device as rs_device
from armwarden.backends.can.emulated_actuator import ActuatorSnapshot, ActuatorSpec, EmulatedActuator
from armwarden.backends.can.emulated_arm import ArmDynamics, EmulatedArm
from armwarden.backends.can.errors import InvalidFrame
from armwarden.backends.can.ranges import Protocol

logger = logging.getLogger(__name__)

#: internal integration rate [Hz]
DEFAULT_RATE_HZ = 2000.0
#: how often every actuator is brought up to the present even when no frame arrives [s]
HOUSEKEEPING_S = 0.005
#: the host id RobStride replies go to until a request names one
DEFAULT_HOST_ID = 0xFD
#: the standard id MIT replies are sent with (the motor id is in byte 0)
DEFAULT_MIT_REPLY_ID = 0x000


@dataclass(frozen=True)
class ArmSetup:
    """The arm the emulated actuators `can_ids` (in the model's joint order) move together: joint =
    direction·(raw − offset); `time_scale` simulated seconds per wall second."""

    model: pin.Model
    can_ids: tuple[int, ...]
    direction: tuple[float, ...]
    offset: tuple[float, ...]
    dynamics: ArmDynamics
    time_scale: float = 1.0


class ActuatorEmulator:
    """Emulated actuators on one CAN channel, served by their own thread (see the module docstring)."""

    def __init__(
        self, channel: str, actuators: Sequence[ActuatorSpec], *, interface: str = "virtual",
        rate_hz: float = DEFAULT_RATE_HZ, host_id: int = DEFAULT_HOST_ID, mit_reply_id: int = DEFAULT_MIT_REPLY_ID,
        arm: ArmSetup | None = None,
    ) -> None:
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz must be a positive number, got {rate_hz}")
        now = time.monotonic()
        self._mit: dict[int, EmulatedActuator] = {}
        self._robstride: dict[int, EmulatedActuator] = {}
        for spec in actuators:
            if spec.can_id in self._mit or spec.can_id in self._robstride:
                raise ValueError(f"two actuators with can_id {spec.can_id}")
            table = self._mit if spec.ranges.protocol is Protocol.MIT else self._robstride
            table[spec.can_id] = EmulatedActuator(spec, host_id, now)
        self.dt = 1.0 / rate_hz
        #: the arm's coupled body (None: every actuator moves its own 1-DOF load)
        self.arm: EmulatedArm | None = None
        if arm is not None:
            members = [self._actuator(i) for i in arm.can_ids]
            self.arm = EmulatedArm(arm.model, members, arm.direction, arm.offset, arm.dynamics, dt=self.dt,
                                   time_scale=arm.time_scale, now=now)
        self._in_arm = frozenset(arm.can_ids if arm is not None else ())
        self.channel = channel
        self.interface = interface
        self.mit_reply_id = mit_reply_id
        #: frames addressed to no emulated actuator or malformed, and the last thread error
        self.unhandled_frames = 0
        self.error: BaseException | None = None
        self._lock = threading.Lock()
        self._bus: can.BusABC | None = None
        self._thread: threading.Thread | None = None
        self._running = False

    # ---------------------------------------------------------------- lifecycle
    def start(self) -> None:
        """Open the bus and start serving. Starting twice does nothing."""
        if self._thread is not None:
            return
        self._bus = can.Bus(interface=self.interface, channel=self.channel)
        self._running = True
        self._thread = threading.Thread(target=self._run, name=f"can-emulator-{self.channel}", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop the thread and release the bus. Safe twice and before `start`."""
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None

    def __enter__(self) -> ActuatorEmulator:
        self.start()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close()

    # ---------------------------------------------------------------- observation
    def snapshot(self, can_id: int) -> ActuatorSnapshot:
        """The actuator's state now (brought up to the present first)."""
        with self._lock:
            return self._current(can_id).snapshot()

    # ---------------------------------------------------------------- push
    def push(self, frame: str, force_base: Sequence[float], point: Sequence[float] = (0.0, 0.0, 0.0)) -> None:
        """Push on the emulated arm with `force_base` [N] (base frame) at `point` [m] (in the model
        frame `frame`'s coordinates) until `release_push` (τ_ext = Jᵀ F, every step). Thread-safe."""
        self._require_arm().push(frame, force_base, point)

    def release_push(self) -> None:
        self._require_arm().release_push()

    def true_external_torques(self) -> np.ndarray:
        """The external joint torques [N·m] the push applies (joint coordinates; zeros: no push)."""
        return self._require_arm().true_external_torques()

    def _require_arm(self) -> EmulatedArm:
        if self.arm is None:
            raise RuntimeError("this emulator moves no arm (simulate.dynamics is per_actuator)")
        return self.arm

    # ---------------------------------------------------------------- fault injection
    def silence(self, can_id: int, silent: bool = True) -> None:
        """Stop (or resume) replying; the actuator still obeys what it receives."""
        with self._lock:
            self._actuator(can_id).silent = silent

    def place_obstacle(self, can_id: int, low_rad: float = -math.inf, high_rad: float = math.inf) -> None:
        """Rigid stops at physical positions `low_rad`/`high_rad` (an object the fingers close on)."""
        with self._lock:
            self._current(can_id).stops = (low_rad, high_rad)

    def set_run_mode(self, can_id: int, mode: rs.RunMode) -> None:
        """As if someone had left the actuator in another control mode (RobStride 0x7005)."""
        with self._lock:
            self._current(can_id).run_mode = mode

    def torque_limit(self, can_id: int) -> float:
        """The actuator's torque limit now [N·m] (RobStride 0x700B as written)."""
        with self._lock:
            return self._actuator(can_id).torque_limit

    def raise_fault(self, can_id: int, fault: mit.MitError | rs.FeedbackFault) -> None:
        """Report `fault` in every reply from now on (MIT: the error code; RobStride: feedback fault bits)."""
        with self._lock:
            actuator = self._actuator(can_id)
            if isinstance(fault, mit.MitError):
                actuator.mit_error = fault
            else:
                actuator.rs_faults |= fault

    def clear_faults(self, can_id: int) -> None:
        with self._lock:
            actuator = self._actuator(can_id)
            actuator.mit_error, actuator.rs_faults = mit.MitError.NONE, rs.FeedbackFault(0)

    def overheat(self, can_id: int, temperature_c: float) -> None:
        """Report `temperature_c` from now on."""
        if not (math.isfinite(temperature_c) and 0 <= temperature_c <= 255):
            raise ValueError(f"temperature_c must be in 0..255 °C, got {temperature_c}")
        with self._lock:
            self._actuator(can_id).temperature_c = temperature_c

    def send_garbage(self, can_id: int, count: int = 1) -> None:
        """Send `count` malformed replies (3 data bytes) from `can_id`, as a failing node would."""
        with self._lock:
            actuator = self._actuator(can_id)
            if actuator.ranges.protocol is Protocol.MIT:
                arbitration_id, extended = self.mit_reply_id, False
            else:
                arbitration_id, extended = rs.build_id(rs.CommType.FEEDBACK, can_id, actuator.host_id), True
        for i in range(count):
            self._send(arbitration_id, bytes((can_id & 0xFF, 0xA5, i & 0xFF)), extended=extended)

    def emit_fault_frame(self, can_id: int, faults: rs.FaultFlag) -> None:
        """Send a RobStride type-21 fault frame from `can_id`."""
        with self._lock:
            host_id = self._actuator(can_id).host_id
        frame = rs_device.fault_frame(rs.FaultReport(can_id, faults, 0, 0), host_id=host_id)
        self._send(frame.arbitration_id, frame.data, extended=True)

    def emit_error_frame(self, class_bits: int = 0x40) -> None:
        """Send an error frame with SocketCAN error-class bits (0x40 bus-off, 0x4 controller, ...)."""
        bus = self._require_bus()
        bus.send(can.Message(arbitration_id=class_bits, is_error_frame=True, is_extended_id=False))

    # ---------------------------------------------------------------- the thread
    def _run(self) -> None:
        bus = self._require_bus()
        next_housekeeping = time.monotonic()
        while self._running:
            try:
                msg = bus.recv(timeout=max(0.0, next_housekeeping - time.monotonic()))
                if msg is not None and not msg.is_error_frame:
                    self._handle(msg)
            except Exception as exc:  # the emulator keeps serving; tests check `error`
                logger.exception("CAN emulator on %s: frame handling failed", self.channel)
                self.error = exc
            now = time.monotonic()
            if now >= next_housekeeping:  # every actuator to the present: CAN timeouts take effect
                with self._lock:
                    if self.arm is not None:
                        self.arm.advance(now)
                    for actuator in self._all():
                        self._advance(actuator, now)
                next_housekeeping = now + HOUSEKEEPING_S

    def _handle(self, msg: can.Message) -> None:
        data = bytes(msg.data)
        try:
            if msg.is_extended_id:
                replies = self._handle_robstride(msg.arbitration_id, data)
            else:
                replies = self._handle_mit(msg.arbitration_id, data)
        except (InvalidFrame, ValueError):
            replies = None
        if replies is None:
            self.unhandled_frames += 1
            return
        for arbitration_id, payload, extended in replies:
            self._send(arbitration_id, payload, extended=extended)

    def _handle_mit(self, arbitration_id: int, data: bytes) -> list[tuple[int, bytes, bool]] | None:
        with self._lock:
            actuator = self._mit.get(arbitration_id)
            if actuator is None or len(data) != 8:
                return None
            self._arrived(actuator)
            self._received(actuator)
            special = mit.special_of(data)
            if special is mit.Special.ENTER_MOTOR_MODE:
                actuator.set_enabled(True)
            elif special is mit.Special.EXIT_MOTOR_MODE:
                actuator.set_enabled(False)
            elif special is mit.Special.SET_ZERO:
                actuator.zero_offset = actuator.position
            elif actuator.enabled:
                actuator.command = mit.unpack_command(data, actuator.ranges)
            if actuator.silent:
                return []
            reply = mit.MitReply(
                motor_id=arbitration_id & 0xFF, position=actuator.reported_position(),
                velocity=actuator.reported_velocity(), torque=actuator.reported_torque(),
                temperature_c=round(actuator.temperature_c), error=actuator.mit_error,
            )
            actuator.replies_sent += 1
            return [(self.mit_reply_id, mit.pack_reply(reply, actuator.ranges), False)]

    def _handle_robstride(self, arbitration_id: int, data: bytes) -> list[tuple[int, bytes, bool]] | None:
        fields = rs.split_id(arbitration_id)
        with self._lock:
            actuator = self._robstride.get(fields.dest)
            if actuator is None:
                return None
            self._arrived(actuator)
            kind = fields.comm_type
            if kind != rs.CommType.CONTROL:
                actuator.host_id = fields.data2 & 0xFF
            reply: rs.Frame | None
            if kind == rs.CommType.GET_ID:
                reply = rs_device.device_id_reply_frame(fields.dest, actuator.spec.uid)
            elif kind == rs.CommType.CONTROL:
                _, command = rs_device.unpack_control(arbitration_id, data, actuator.ranges)
                if actuator.enabled:
                    actuator.command = command
                reply = self._feedback(actuator)
            elif kind == rs.CommType.ENABLE:
                actuator.set_enabled(True)
                reply = self._feedback(actuator)
            elif kind == rs.CommType.STOP:
                actuator.set_enabled(False)
                if data[:1] == b"\x01":
                    actuator.rs_faults = rs.FeedbackFault(0)
                reply = self._feedback(actuator)
            elif kind == rs.CommType.SET_ZERO:
                actuator.zero_offset = actuator.position
                reply = self._feedback(actuator)
            elif kind == rs.CommType.READ_PARAMETER:
                parameter, _ = rs_device.unpack_parameter_request(data)
                value = rs.ParameterValue(fields.dest, parameter, self._read_parameter(actuator, parameter))
                reply = rs_device.parameter_reply_frame(value, host_id=actuator.host_id)
            elif kind == rs.CommType.WRITE_PARAMETER:
                parameter, raw = rs_device.unpack_parameter_request(data)
                self._write_parameter(actuator, parameter, rs.decode_value(parameter, raw))
                reply = self._feedback(actuator)
            elif kind == rs.CommType.ACTIVE_REPORT:
                reply = None  # accepted; periodic reporting is not emulated
            else:
                return None
            self._received(actuator)
            if actuator.silent or reply is None:
                return []
            actuator.replies_sent += 1
            return [(reply.arbitration_id, reply.data, True)]

    def _feedback(self, actuator: EmulatedActuator) -> rs.Frame:
        feedback = rs.Feedback(
            motor_id=actuator.spec.can_id, mode=rs.MotorMode.RUN if actuator.enabled else rs.MotorMode.RESET,
            faults=actuator.rs_faults, position=actuator.reported_position(),
            velocity=actuator.reported_velocity(), torque=actuator.reported_torque(),
            temperature_c=actuator.temperature_c,
        )
        return rs_device.feedback_frame(feedback, actuator.ranges, host_id=actuator.host_id)

    @staticmethod
    def _read_parameter(actuator: EmulatedActuator, parameter: rs.Parameter) -> float:
        values: dict[rs.Parameter, float] = {
            rs.RUN_MODE: int(actuator.run_mode),
            rs.LIMIT_TORQUE: actuator.torque_limit,
            rs.LIMIT_SPD: actuator.ranges.velocity.hi,
            rs.LIMIT_CUR: 20.0,
            rs.MECH_POS: actuator.reported_continuous(),
            rs.MECH_VEL: actuator.velocity,
            rs.VBUS: 48.0,
            rs.CAN_TIMEOUT: rs.can_timeout_ticks(actuator.can_timeout_s),
        }
        return values[parameter]

    @staticmethod
    def _write_parameter(actuator: EmulatedActuator, parameter: rs.Parameter, value: float) -> None:
        if parameter == rs.CAN_TIMEOUT:
            actuator.can_timeout_s = rs.can_timeout_seconds(int(value))
        elif parameter == rs.RUN_MODE:
            actuator.run_mode = rs.RunMode(int(value))  # ValueError (unhandled frame) for an undefined mode
        elif parameter == rs.LIMIT_TORQUE:
            actuator.torque_limit = min(max(0.0, float(value)), actuator.ranges.torque.hi)
        # other parameters are read-only or not emulated: the write is acknowledged and ignored

    # ---------------------------------------------------------------- helpers
    def _arrived(self, actuator: EmulatedActuator) -> None:
        """A frame reached `actuator`: bring it to the present before the frame acts (its
        watchdog is judged on the time before this frame)."""
        self._advance(actuator, time.monotonic())

    def _advance(self, actuator: EmulatedActuator, now: float) -> None:
        """`actuator` up to `now`: with the arm's body if it is one of the arm's."""
        if self.arm is not None and actuator.spec.can_id in self._in_arm:
            self.arm.advance(now)
        else:
            actuator.advance(self.dt, now)

    def _received(self, actuator: EmulatedActuator) -> None:
        """Count a frame `actuator` accepted: it feeds the watchdog from now on."""
        actuator.frames_received += 1
        actuator.last_rx = actuator.sim_time

    def _all(self) -> list[EmulatedActuator]:
        return [*self._mit.values(), *self._robstride.values()]

    def _current(self, can_id: int) -> EmulatedActuator:
        """`_actuator`, brought up to the present (under the lock)."""
        actuator = self._actuator(can_id)
        self._advance(actuator, time.monotonic())
        return actuator

    def _actuator(self, can_id: int) -> EmulatedActuator:
        actuator = self._mit.get(can_id) or self._robstride.get(can_id)
        if actuator is None:
            raise KeyError(f"no emulated actuator with can_id {can_id}")
        return actuator

    def _require_bus(self) -> can.BusABC:
        if self._bus is None:
            raise RuntimeError("the emulator is not started")
        return self._bus

    def _send(self, arbitration_id: int, data: bytes, *, extended: bool) -> None:
        self._require_bus().send(can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=extended))


__all__ = ["DEFAULT_HOST_ID", "DEFAULT_MIT_REPLY_ID", "DEFAULT_RATE_HZ", "HOUSEKEEPING_S", "ActuatorEmulator", "ArmSetup"]
