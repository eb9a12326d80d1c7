"""The motor model of an emulated CAN actuator: its load's dynamics and its impedance law; no bus.

Each emulated actuator has simple rigid-body dynamics — inertia, viscous damping, an optional
gravity load torque −gravity_torque_nm·cos(position) (a link that is horizontal at zero) — and
applies the impedance law τ = kp·(p* − p) + kd·(v* − v) + τ_ff, clipped to its torque limit,
while enabled. The state is integrated in fixed steps (semi-implicit Euler) up to the instant it
is asked about (`advance`), so whoever drives it (the emulator's bus side) decides when time
passes. The actuator-side CAN timeout (`can_timeout_s`) is judged on the same clock: no frame
accepted for that long -> reset mode, disabled, zero torque. Reported positions wrap over the
model's position range and reported velocity/torque saturate at its ranges, as hardware does.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

from armwarden.backends.can import mit
from armwarden.backends.can import robstride as rs
from armwarden.backends.can.command import MotorCommand
from armwarden.backends.can.ranges import ModelRanges, Protocol, Range, model_ranges

logger = logging.getLogger(__name__)

#: the most integration steps one catch-up may take after a stall (beyond: the backlog is dropped)
MAX_CATCH_UP_STEPS = 400
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


class EmulatedActuator:
    """Mutable state of one emulated actuator; not thread-safe (the emulator's lock guards it)."""

    def __init__(self, spec: ActuatorSpec, host_id: int, now: float) -> None:
        self.spec = spec
        self.ranges = spec.ranges
        self.torque_limit = min(spec.torque_limit_nm or math.inf, self.ranges.torque.hi)
        self.position = spec.initial_position_rad
        self.velocity = 0.0
        self.torque = 0.0
        self.torque_noise = 0.0  # added to the reported torque (the emulated arm's seeded measurement noise)
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

    def motor_torque(self, now: float) -> float:
        """The motor torque [N·m, raw] at `now`: the impedance law, clipped, while enabled; zero
        once the CAN timeout has disabled it (judged here)."""
        if self.enabled and self.can_timeout_s > 0 and now - self.last_rx > self.can_timeout_s:
            self.set_enabled(False)
            self.timeouts += 1
            logger.info("emulated actuator %d: CAN timeout (%.3f s): reset mode", self.spec.can_id, self.can_timeout_s)
        self.torque = 0.0
        if self.enabled and self.run_mode == rs.RunMode.OPERATION:
            c = self.command
            tau = c.kp * (c.position - self.reported_continuous()) + c.kd * (c.velocity - self.velocity) + c.torque
            self.torque = max(-self.torque_limit, min(self.torque_limit, tau))
        return self.torque

    def step(self, dt: float, now: float) -> None:
        self.motor_torque(now)
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

    def reported_velocity(self) -> float:
        """The velocity a reply carries: saturated at the model's range, as hardware reports it."""
        return _saturate(self.velocity, self.ranges.velocity)

    def reported_torque(self) -> float:
        """The torque a reply carries: saturated at the model's range."""
        return _saturate(self.torque + self.torque_noise, self.ranges.torque)


def _wrap(value: float, r: Range) -> float:
    return (value - r.lo) % r.span + r.lo


def _saturate(value: float, r: Range) -> float:
    return max(r.lo, min(r.hi, value))


__all__ = ["MAX_CATCH_UP_STEPS", "ActuatorSnapshot", "ActuatorSpec", "EmulatedActuator"]
