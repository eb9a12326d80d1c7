"""Simulated CAN actuators (MIT mode and RobStride) on a python-can bus, on their own thread.

Each emulated actuator has simple rigid-body dynamics — inertia, viscous damping, an optional
gravity load torque −gravity_torque_nm·cos(position) (a link that is horizontal at zero) — and
applies the impedance law τ = kp·(p* − p) + kd·(v* − v) + τ_ff, clipped to its torque limit,
while enabled. The state is integrated in fixed steps at an internal rate (semi-implicit Euler),
lazily: an actuator is brought up to the present when a frame reaches it, when a test looks at
it, and on a housekeeping pass every `HOUSEKEEPING_S` (which is when a silent host's CAN timeout
is noticed). Simulated time follows wall-clock time; the thread does not wake at the
integration rate, so the emulator costs the process's other threads (the servo loop it shares
the interpreter with) little more than the frames themselves.

Protocols as the notes describe them: an MIT actuator answers every frame addressed to it
(specials included) with an 8-byte reply; a RobStride actuator answers types 1/3/4/6/18 with
type-2 feedback, 17 with the parameter value, 0 with its id. The actuator-side CAN timeout
(`can_timeout_s`, for RobStride also parameter 0x7028) is honoured: no frame addressed to the
actuator for that long -> reset mode, disabled, zero torque. Reported positions wrap over the
model's position range and reported velocity/torque saturate at its ranges, as hardware does.

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
from dataclasses import dataclass, field
from types import TracebackType

import can

from armwarden.backends.can import mit
from armwarden.backends.can import robstride as rs
from armwarden.backends.can import robstride_device as rs_device
from armwarden.backends.can.command import MotorCommand
from armwarden.backends.can.errors import InvalidFrame
from armwarden.backends.can.ranges import ModelRanges, Protocol, Range, model_ranges

logger = logging.getLogger(__name__)

#: internal integration rate [Hz]
DEFAULT_RATE_HZ = 2000.0
#: the most integration steps one catch-up may take after a stall (beyond: the backlog is dropped)
MAX_CATCH_UP_STEPS = 400
#: how often every actuator is brought up to the present even when no frame arrives [s]
HOUSEKEEPING_S = 0.005
#: the host id RobStride replies go to until a request names one
DEFAULT_HOST_ID = 0xFD
#: the standard id MIT replies are sent with (the motor id is in byte 0)
DEFAULT_MIT_REPLY_ID = 0x000
_ZERO_COMMAND = MotorCommand(0.0, 0.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class ActuatorSpec:
    """One simulated actuator: its id and model, and the load it drives.

    `inertia_kgm2` [kg·m²] > 0, `damping_nms_per_rad` [N·m·s/rad] ≥ 0, `gravity_torque_nm` [N·m]
    (amplitude of the gravity load), `torque_limit_nm` [N·m] (default: the model's torque range),
    `initial_position_rad`, `temperature_c` [°C], `can_timeout_s` [s] (0 = no watchdog).
    """

    can_id: int
    model: str
    inertia_kgm2: float = 0.02
    damping_nms_per_rad: float = 0.05
    gravity_torque_nm: float = 0.0
    torque_limit_nm: float | None = None
    initial_position_rad: float = 0.0
    temperature_c: float = 30.0
    can_timeout_s: float = 0.0
    uid: bytes = field(default=bytes(8))

    def __post_init__(self) -> None:
        ranges = model_ranges(self.model)
        limit = 0x7FF if ranges.protocol is Protocol.MIT else 0xFD
        if not 1 <= self.can_id <= limit:
            raise ValueError(f"can_id {self.can_id} is outside 1..{limit} for {ranges.protocol.value} actuators")
        numbers = {
            "inertia_kgm2": self.inertia_kgm2, "damping_nms_per_rad": self.damping_nms_per_rad,
            "gravity_torque_nm": self.gravity_torque_nm, "initial_position_rad": self.initial_position_rad,
            "temperature_c": self.temperature_c, "can_timeout_s": self.can_timeout_s,
        }
        for name, value in numbers.items():
            if not math.isfinite(value):
                raise ValueError(f"actuator {self.can_id}: {name} must be finite, got {value}")
        if self.inertia_kgm2 <= 0 or self.damping_nms_per_rad < 0 or self.can_timeout_s < 0:
            raise ValueError(f"actuator {self.can_id}: inertia must be > 0, damping and can_timeout_s ≥ 0")
        if self.torque_limit_nm is not None and not (math.isfinite(self.torque_limit_nm) and self.torque_limit_nm > 0):
            raise ValueError(f"actuator {self.can_id}: torque_limit_nm must be a positive number, got {self.torque_limit_nm}")
        if not 0 <= self.temperature_c <= 255:
            raise ValueError(f"actuator {self.can_id}: temperature_c must be in 0..255 °C, got {self.temperature_c}")
        if len(self.uid) != 8:
            raise ValueError(f"actuator {self.can_id}: uid must be 8 bytes")

    @property
    def ranges(self) -> ModelRanges:
        return model_ranges(self.model)


@dataclass(frozen=True)
class ActuatorSnapshot:
    """What an emulated actuator is doing (the test's view, not the bus's)."""

    can_id: int
    position_rad: float  # physical, continuous (before zeroing offsets and wrapping)
    velocity_rad_s: float
    torque_nm: float  # applied by the motor (0 while disabled)
    enabled: bool
    command: MotorCommand
    temperature_c: float
    timeouts: int  # how often the CAN timeout disabled it
    frames_received: int
    replies_sent: int


class _Actuator:
    """Mutable state of one emulated actuator (guarded by the emulator's lock)."""

    def __init__(self, spec: ActuatorSpec, host_id: int, now: float) -> None:
        self.spec = spec
        self.ranges = spec.ranges
        self.torque_limit = min(spec.torque_limit_nm or math.inf, self.ranges.torque.hi)
        self.position = spec.initial_position_rad
        self.velocity = 0.0
        self.torque = 0.0
        self.zero_offset = 0.0
        self.enabled = False
        self.command = _ZERO_COMMAND
        self.temperature_c = spec.temperature_c
        self.can_timeout_s = spec.can_timeout_s
        self.run_mode = rs.RunMode.OPERATION
        self.host_id = host_id
        self.last_rx = now
        self.sim_time = now  # the instant the state below describes
        self.silent = False
        self.stops = (-math.inf, math.inf)  # physical positions [rad] it cannot move beyond
        self.mit_error = mit.MitError.NONE
        self.rs_faults = rs.FeedbackFault(0)
        self.timeouts = 0
        self.frames_received = 0
        self.replies_sent = 0

    def set_enabled(self, enabled: bool) -> None:
        self.enabled = enabled
        self.command = _ZERO_COMMAND  # a stale command never acts after (re-)enabling

    def advance(self, dt: float, now: float) -> None:
        """Integrate in steps of `dt` up to `now` (monotonic); a backlog beyond
        `MAX_CATCH_UP_STEPS` is dropped (the state jumps in time, as after a stalled thread)."""
        t = self.sim_time
        steps = 0
        while t + dt <= now and steps < MAX_CATCH_UP_STEPS:
            t += dt
            self.step(dt, t)
            steps += 1
        self.sim_time = t if t + dt > now else now

    def step(self, dt: float, now: float) -> None:
        if self.enabled and self.can_timeout_s > 0 and now - self.last_rx > self.can_timeout_s:
            self.set_enabled(False)
            self.timeouts += 1
            logger.info("emulated actuator %d: CAN timeout (%.3f s): reset mode", self.spec.can_id, self.can_timeout_s)
        self.torque = 0.0
        if self.enabled and self.run_mode == rs.RunMode.OPERATION:
            c = self.command
            tau = c.kp * (c.position - self.reported_continuous()) + c.kd * (c.velocity - self.velocity) + c.torque
            self.torque = max(-self.torque_limit, min(self.torque_limit, tau))
        load = self.spec.damping_nms_per_rad * self.velocity + self.spec.gravity_torque_nm * math.cos(self.position)
        self.velocity += (self.torque - load) / self.spec.inertia_kgm2 * dt
        self.position += self.velocity * dt
        lo, hi = self.stops
        if not lo <= self.position <= hi:  # a rigid obstacle (an object between the fingers)
            self.position, self.velocity = min(max(self.position, lo), hi), 0.0

    def reported_continuous(self) -> float:
        return self.position - self.zero_offset

    def reported_position(self) -> float:
        r = self.ranges.position
        return _wrap(self.reported_continuous(), r)

    def snapshot(self) -> ActuatorSnapshot:
        return ActuatorSnapshot(
            self.spec.can_id, self.position, self.velocity, self.torque, self.enabled, self.command,
            self.temperature_c, self.timeouts, self.frames_received, self.replies_sent,
        )


def _wrap(value: float, r: Range) -> float:
    return (value - r.lo) % r.span + r.lo


def _saturate(value: float, r: Range) -> float:
    return max(r.lo, min(r.hi, value))


class ActuatorEmulator:
    """Emulated actuators on one CAN channel, served by their own thread (see the module docstring)."""

    def __init__(
        self, channel: str, actuators: Sequence[ActuatorSpec], *, interface: str = "virtual",
        rate_hz: float = DEFAULT_RATE_HZ, host_id: int = DEFAULT_HOST_ID, mit_reply_id: int = DEFAULT_MIT_REPLY_ID,
    ) -> None:
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz must be a positive number, got {rate_hz}")
        now = time.monotonic()
        self._mit: dict[int, _Actuator] = {}
        self._robstride: dict[int, _Actuator] = {}
        for spec in actuators:
            if spec.can_id in self._mit or spec.can_id in self._robstride:
                raise ValueError(f"two actuators with can_id {spec.can_id}")
            table = self._mit if spec.ranges.protocol is Protocol.MIT else self._robstride
            table[spec.can_id] = _Actuator(spec, host_id, now)
        self.channel = channel
        self.interface = interface
        self.dt = 1.0 / rate_hz
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
                    for actuator in self._all():
                        actuator.advance(self.dt, now)
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
            r = actuator.ranges
            reply = mit.MitReply(
                motor_id=arbitration_id & 0xFF, position=actuator.reported_position(),
                velocity=_saturate(actuator.velocity, r.velocity), torque=_saturate(actuator.torque, r.torque),
                temperature_c=round(actuator.temperature_c), error=actuator.mit_error,
            )
            actuator.replies_sent += 1
            return [(self.mit_reply_id, mit.pack_reply(reply, r), False)]

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

    def _feedback(self, actuator: _Actuator) -> rs.Frame:
        r = actuator.ranges
        feedback = rs.Feedback(
            motor_id=actuator.spec.can_id, mode=rs.MotorMode.RUN if actuator.enabled else rs.MotorMode.RESET,
            faults=actuator.rs_faults, position=actuator.reported_position(),
            velocity=_saturate(actuator.velocity, r.velocity), torque=_saturate(actuator.torque, r.torque),
            temperature_c=actuator.temperature_c,
        )
        return rs_device.feedback_frame(feedback, r, host_id=actuator.host_id)

    @staticmethod
    def _read_parameter(actuator: _Actuator, parameter: rs.Parameter) -> float:
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
    def _write_parameter(actuator: _Actuator, parameter: rs.Parameter, value: float) -> None:
        if parameter == rs.CAN_TIMEOUT:
            actuator.can_timeout_s = rs.can_timeout_seconds(int(value))
        elif parameter == rs.RUN_MODE:
            actuator.run_mode = rs.RunMode(int(value))  # ValueError (unhandled frame) for an undefined mode
        elif parameter == rs.LIMIT_TORQUE:
            actuator.torque_limit = min(max(0.0, float(value)), actuator.ranges.torque.hi)
        # other parameters are read-only or not emulated: the write is acknowledged and ignored

    # ---------------------------------------------------------------- helpers
    def _arrived(self, actuator: _Actuator) -> None:
        """A frame reached `actuator`: bring it to the present before the frame acts (its
        watchdog is judged on the time before this frame)."""
        actuator.advance(self.dt, time.monotonic())

    def _received(self, actuator: _Actuator) -> None:
        """Count a frame `actuator` accepted: it feeds the watchdog from now on."""
        actuator.frames_received += 1
        actuator.last_rx = actuator.sim_time

    def _all(self) -> list[_Actuator]:
        return [*self._mit.values(), *self._robstride.values()]

    def _current(self, can_id: int) -> _Actuator:
        """`_actuator`, brought up to the present (under the lock)."""
        actuator = self._actuator(can_id)
        actuator.advance(self.dt, time.monotonic())
        return actuator

    def _actuator(self, can_id: int) -> _Actuator:
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


__all__ = ["DEFAULT_HOST_ID", "DEFAULT_MIT_REPLY_ID", "DEFAULT_RATE_HZ", "ActuatorEmulator", "ActuatorSnapshot", "ActuatorSpec"]
