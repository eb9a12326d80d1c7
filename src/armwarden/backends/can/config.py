"""`--backend-config` of the CAN backend: the bus, the actuators behind each policy joint, and an
optional emulation of those actuators (strict pydantic: unknown keys, NaN, duplicate ids and
models that do not speak the declared protocol are errors with their YAML path).

Units are in the field names. Joint = direction·(raw − homing_offset_rad) for positions; velocity
and torque scale by the direction only. Cross-checks that need the policy (every policy joint
exactly once, the joint limits representable in each model's position range) are made by
`check_against_policy` when the backend is built.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from armwarden.backends.can.bus import BusConfig
from armwarden.backends.can.errors import UnknownModel
from armwarden.backends.can.ranges import ModelRanges, Protocol, Range, model_ranges
from armwarden.core.errors import ConfigurationError

_STRICT = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


def _actuator_ranges(actuator: JointConfig | GripperConfig) -> ModelRanges:
    """The value ranges of `actuator`'s model, once its model, protocol, id, gains and torque
    limit are checked against them (ValueError naming the field otherwise)."""
    try:
        ranges = model_ranges(actuator.model)
    except UnknownModel as exc:
        raise ValueError(str(exc)) from None
    if ranges.protocol is not actuator.protocol:
        raise ValueError(f"model {actuator.model} speaks {ranges.protocol.value}, not {actuator.protocol.value}")
    if actuator.protocol is Protocol.ROBSTRIDE and actuator.can_id > 0xFD:
        raise ValueError(f"RobStride can_id must be 1..253, got {actuator.can_id}")
    for field, value, valid in (("kp_nm_per_rad", actuator.kp_nm_per_rad, ranges.kp),
                                ("kd_nms_per_rad", actuator.kd_nms_per_rad, ranges.kd),
                                ("damping_kd_nms_per_rad", actuator.damping_kd_nms_per_rad, ranges.kd),
                                ("torque_limit_nm", actuator.torque_limit_nm, ranges.torque)):
        if value not in valid:
            raise ValueError(f"{field} {value} is outside the {actuator.model} range [{valid.lo}, {valid.hi}]")
    return ranges


class JointConfig(BaseModel):
    """One actuator driving one policy joint."""

    model_config = _STRICT
    name: str = Field(min_length=1, description="Policy joint this actuator drives.")
    can_id: int = Field(ge=1, le=0x7FF, description="Actuator CAN id (RobStride: 1..253; MIT: 1..2047).")
    protocol: Protocol = Field(description="Wire protocol: 'robstride' or 'mit'.")
    model: str = Field(description="Actuator model (RS00..RS06, AK80-9, ...): selects the value ranges.")
    direction: Literal[1, -1] = Field(default=1, description="+1 or -1: sign between joint and actuator.")
    homing_offset_rad: float = Field(default=0.0, description="Actuator position [rad] at joint zero.")
    kp_nm_per_rad: float = Field(gt=0, description="Stiffness [N·m/rad] while tracking and holding.")
    kd_nms_per_rad: float = Field(ge=0, description="Damping [N·m·s/rad] while tracking and holding.")
    damping_kd_nms_per_rad: float = Field(gt=0, description="Damping [N·m·s/rad] of the fault/e-stop damping mode (kp = 0).")
    torque_limit_nm: float = Field(gt=0, description="Largest feed-forward torque [N·m] (the backend sends none today).")

    @property
    def ranges(self) -> ModelRanges:
        return model_ranges(self.model)

    @model_validator(mode="after")
    def _model_fits(self) -> JointConfig:
        _actuator_ranges(self)
        return self


class GripperConfig(BaseModel):
    """An optional actuator driving the gripper's fingers. Gripper position = direction·(raw −
    homing_offset_rad); the width is linear in it: 0 at `closed_position_rad`, `max_width_m` at
    `open_position_rad`. A grasp's force maps to actuator torque by virtual work (F·dw = τ·dθ) and
    must fit under `torque_limit_nm` (refused otherwise)."""

    model_config = _STRICT
    name: str = Field(default="gripper", min_length=1, description="Name in messages and in simulate.loads.")
    can_id: int = Field(ge=1, le=0x7FF, description="Actuator CAN id (RobStride: 1..253; MIT: 1..2047).")
    protocol: Protocol = Field(description="Wire protocol: 'robstride' or 'mit'.")
    model: str = Field(description="Actuator model: selects the value ranges.")
    direction: Literal[1, -1] = Field(default=1, description="+1 or -1: sign between gripper position and actuator.")
    homing_offset_rad: float = Field(default=0.0, description="Actuator position [rad] at gripper position zero.")
    open_position_rad: float = Field(description="Gripper position [rad] with the fingers fully open (max_width_m).")
    closed_position_rad: float = Field(description="Gripper position [rad] with the fingers closed (width 0).")
    max_width_m: float = Field(gt=0, le=0.5, description="Finger opening [m] at open_position_rad.")
    kp_nm_per_rad: float = Field(gt=0, description="Stiffness [N·m/rad] while moving and holding.")
    kd_nms_per_rad: float = Field(ge=0, description="Damping [N·m·s/rad] while moving and holding.")
    damping_kd_nms_per_rad: float = Field(gt=0, description="Damping [N·m·s/rad] of the fault/e-stop damping mode.")
    torque_limit_nm: float = Field(gt=0, description="Largest torque [N·m] a move or grasp may ask (caps the force).")
    position_tolerance_rad: float = Field(default=0.01, gt=0, description="A move is at its target within this [rad].")

    @property
    def ranges(self) -> ModelRanges:
        return model_ranges(self.model)

    @property
    def width_per_rad_m(self) -> float:
        """Finger opening per gripper radian [m/rad] (signed: negative if opening lowers the position)."""
        return self.max_width_m / (self.open_position_rad - self.closed_position_rad)

    def position_of(self, width_m: float) -> float:
        return self.closed_position_rad + width_m / self.width_per_rad_m

    def width_of(self, position_rad: float) -> float:
        return (position_rad - self.closed_position_rad) * self.width_per_rad_m

    @model_validator(mode="after")
    def _fits(self) -> GripperConfig:
        ranges = _actuator_ranges(self)
        if self.open_position_rad == self.closed_position_rad:
            raise ValueError("open_position_rad and closed_position_rad must differ")
        for field, value in (("open_position_rad", self.open_position_rad), ("closed_position_rad", self.closed_position_rad)):
            raw = self.direction * value + self.homing_offset_rad
            if raw not in ranges.position:
                raise ValueError(f"{field} maps to actuator position {raw:.3f} rad, outside the {self.model} range")
        return self


class SimulatedLoad(BaseModel):
    """The load an emulated actuator drives (see `armwarden.backends.can.emulated_actuator`). Under
    `dynamics: robot_model` an arm joint's `inertia_kgm2` is its rotor inertia (armature), added to
    the robot model's own, and `gravity_torque_nm` must stay 0 (the model has the gravity)."""

    model_config = _STRICT
    inertia_kgm2: float = Field(default=0.02, gt=0, description="Reflected (rotor) inertia [kg·m²].")
    damping_nms_per_rad: float = Field(default=0.05, ge=0, description="Viscous friction [N·m·s/rad].")
    coulomb_friction_nm: float = Field(default=0.0, ge=0,
                                       description="Coulomb friction [N·m] (robot_model dynamics only).")
    gravity_torque_nm: float = Field(default=0.0, description="Amplitude of a gravity load [N·m] (0: none).")
    temperature_c: float = Field(default=30.0, ge=0, le=255, description="Reported temperature [°C].")


class Simulation(BaseModel):
    """Emulated actuators on the (virtual) bus, started with the backend: no hardware needed."""

    model_config = _STRICT
    rate_hz: float = Field(default=2000.0, gt=0, le=10000, description="Emulator integration rate [Hz].")
    speedup: float = Field(default=1.0, gt=0, le=10,
                       description="Trajectory time per wall time, no unit (tests only; hardware always runs at 1).")
    loads: dict[str, SimulatedLoad] = Field(default_factory=dict,
                                            description="Load per joint name; joints not named get the defaults.")
    dynamics: Literal["robot_model", "per_actuator"] = Field(
        default="per_actuator",
        description="robot_model: the arm's actuators move one body by the robot model's forward dynamics "
                    "(gravity, inertia, coupling); per_actuator: each moves its own 1-DOF load. The gripper is always "
                    "per_actuator.")
    mass_error: float = Field(default=0.0, ge=0, le=0.2,
                              description="Relative std of each emulated body's mass/inertia scale (model error on "
                                          "purpose; robot_model only).")
    torque_noise_nm: float = Field(default=0.0, ge=0, le=5,
                                   description="Std [N·m] of Gaussian noise on each reported torque (robot_model only).")
    seed: int = Field(default=0, ge=0, description="Seed of the mass error and the torque noise.")
    brakes: bool = Field(default=True, strict=True,
                         description="Holding brakes hold the emulated arm while an actuator is disabled or damping "
                                     "(kp = 0); false: it falls against the damping (robot_model only).")
    payload_kg: float = Field(default=0.0, ge=0, le=20,
                              description="Payload [kg] the emulated arm carries (undeclared to the policy unless it says so).")
    payload_com_m: tuple[float, float, float] = Field(default=(0.0, 0.0, 0.0),
                                                      description="The payload's centre of mass [m] in the TCP frame.")


class Config(BaseModel):
    """`--backend-config` for the CAN backend."""

    model_config = _STRICT
    bus: BusConfig = Field(description="The CAN interface (socketcan on hardware, virtual in simulation).")
    host_id: int = Field(default=0xFD, ge=0, le=0xFF, description="This host's id on the bus (RobStride data area 2).")
    mit_reply_id: int = Field(default=0x000, ge=0, le=0x7FF, description="Standard id MIT actuators reply with.")
    control_rate_hz: float = Field(default=500.0, ge=50, le=2000, description="Servo loop rate [Hz], moving and idle.")
    realtime_priority: int | None = Field(
        default=None, ge=1, le=99,
        description="SCHED_FIFO priority of the servo thread (Linux; needs CAP_SYS_NICE or ulimit -r); "
                    "the daemon refuses to start if it cannot have it. Unset: the ordinary scheduler.")
    rx_timeout_s: float = Field(default=0.1, gt=0, le=1,
                                description="A command unanswered this long is an RX_TIMEOUT fault [s].")
    temperature_limit_c: float = Field(default=80.0, gt=0, le=150, description="Hotter than this is a fault [°C].")
    can_timeout_s: float = Field(
        default=0.25, gt=0, le=3,
        description="Actuator-side watchdog [s]: no frame for this long and the actuator disables itself. Written to "
                    "RobStride parameter 0x7028 at start-up; MIT mode has no frame to set it (configure the firmware).",
    )
    startup_timeout_s: float = Field(default=0.5, gt=0, le=10, description="How long start-up waits for each reply [s].")
    settle_timeout_s: float = Field(default=2.0, gt=0, le=30,
                                    description="How long a finished trajectory may take to settle at its goal [s].")
    joints: tuple[JointConfig, ...] = Field(min_length=1, description="One actuator per policy joint.")
    gripper: GripperConfig | None = Field(default=None, description="The gripper's actuator; null: no gripper.")
    simulate: Simulation | None = Field(default=None, description="Emulate the actuators (no hardware); null: real bus.")
    gravity_feedforward: bool | None = Field(
        default=None, strict=True,
        description="Send each joint's gravity torque g(q*) of the robot model as the command's feed-forward torque, "
                    "so the arm does not sag by g/kp. Unset: on when the robot model has masses, except under "
                    "simulate.dynamics per_actuator (whose loads have no arm gravity).")
    joint_torques: bool = Field(
        default=False, strict=True,
        description="Publish each actuator's feedback torque (through the joint's direction) as the joint's measured "
        "torque, so the policy can watch contact from it (force.joint_torques). Set it once the arm at rest reads its "
        "gravity torques g(q) (docs/contact.md). Under `simulate` only with `dynamics: robot_model`: per_actuator "
        "loads are not the arm's coupled dynamics, so their torques are not the arm's.")

    @model_validator(mode="after")
    def _unique(self) -> Config:
        gripper = [] if self.gripper is None else [self.gripper]
        columns: tuple[tuple[str, list[str]], ...] = (("joint name", [j.name for j in [*self.joints, *gripper]]),
                                                      ("can_id", [str(j.can_id) for j in [*self.joints, *gripper]]))
        for what, values in columns:
            duplicates = sorted({v for v in values if values.count(v) > 1})
            if duplicates:
                raise ValueError(f"duplicate {what}: {', '.join(duplicates)}")
        if self.simulate is not None:
            unknown = sorted(set(self.simulate.loads) - {j.name for j in [*self.joints, *gripper]})
            if unknown:
                raise ValueError(f"simulate.loads names joints that are not configured: {', '.join(unknown)}")
            if self.simulate.dynamics == "robot_model":
                gravity = sorted(j.name for j in self.joints
                                 if j.name in self.simulate.loads and self.simulate.loads[j.name].gravity_torque_nm)
                if gravity:
                    raise ValueError(f"simulate.loads: gravity_torque_nm of {', '.join(gravity)} must be 0 under "
                                     "dynamics robot_model (the robot model has the gravity)")
        return self


def check_against_policy(config: Config, joint_names: tuple[str, ...], lower: tuple[float, ...],
                         upper: tuple[float, ...], max_velocity: tuple[float, ...] | None = None,
                         max_finger_speed_mps: float | None = None) -> tuple[JointConfig, ...]:
    """The joint configs in policy order; `ConfigurationError` if a policy joint is missing or an
    extra one is configured, a joint's limits do not map into its model's position range, or a
    speed the policy allows (a joint's `max_velocity`, the gripper's finger speed) does not fit
    its model's velocity field: such a command could never be sent, and the backend would have
    to damp the arm mid-motion instead."""
    by_name = {j.name: j for j in config.joints}
    missing = [n for n in joint_names if n not in by_name]
    extra = [n for n in by_name if n not in joint_names]
    if missing or extra:
        parts = ([f"missing {', '.join(missing)}"] if missing else []) + ([f"not in the policy: {', '.join(extra)}"] if extra else [])
        raise ConfigurationError(f"invalid can backend config: joints must name every policy joint exactly once ({'; '.join(parts)})")
    ordered = tuple(by_name[n] for n in joint_names)
    for joint, lo, hi in zip(ordered, lower, upper, strict=True):
        position = joint.ranges.position
        raw = sorted((joint.direction * lo + joint.homing_offset_rad, joint.direction * hi + joint.homing_offset_rad))
        if not (position.lo <= raw[0] and raw[1] <= position.hi):
            raise ConfigurationError(
                f"invalid can backend config: joint {joint.name} limits [{lo}, {hi}] rad map to actuator positions "
                f"[{raw[0]:.3f}, {raw[1]:.3f}] rad, outside the {joint.model} range [{position.lo:.3f}, {position.hi:.3f}]")
    for joint, speed in zip(ordered, max_velocity or (), strict=False):
        _speed_fits(joint.name, joint.model, joint.ranges.velocity, speed, f"max_velocity {speed:g} rad/s")
    gripper = config.gripper
    if gripper is not None and max_finger_speed_mps is not None:
        speed = max_finger_speed_mps / abs(gripper.width_per_rad_m)
        _speed_fits(gripper.name, gripper.model, gripper.ranges.velocity, speed,
                    f"the policy's finger speed {max_finger_speed_mps:g} m/s ({speed:.2f} rad/s at the actuator)")
    return ordered


def _speed_fits(name: str, model: str, velocity: Range, speed: float, what: str) -> None:
    if not (velocity.lo <= -speed and speed <= velocity.hi):
        raise ConfigurationError(f"invalid can backend config: {name}: {what} does not fit the {model} velocity range "
                                 f"[{velocity.lo:g}, {velocity.hi:g}] rad/s")


__all__ = ["Config", "GripperConfig", "JointConfig", "SimulatedLoad", "Simulation", "check_against_policy"]
