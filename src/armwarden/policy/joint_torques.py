"""The `force.joint_torques` section: contact limits on the external joint torques the observer
estimates from the motors' own measured torques (arms without a force/torque sensor).

Why per joint: a push on the forearm loads the shoulder and elbow but barely the wrist, and the
TCP wrench computed from joint torques is only well defined for a contact at the TCP. The limits
are stated where the estimate is made, in joint space; `armwarden calibrate-contact` measures
what each joint's estimate reads with nothing touching the arm and recommends them.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Annotated

from pydantic import AfterValidator, BaseModel, Field, WrapSerializer, model_validator

from armwarden.policy.fields import (
    MODEL_CONFIG,
    FiniteFloat,
    FrozenMap,
    Name,
    Violation,
    enforce,
    finite,
    freeze_map,
    serialize_map,
)

#: Largest external-torque limit per joint [N·m]. An FR3 shoulder holds 87 N·m; a limit above
#: 100 N·m stops nothing a person would survive, and 1e4 is "no limit" in disguise.
MAX_EXTERNAL_TORQUE_NM = 100.0
#: Largest friction allowance per joint [N·m] (Coulomb) and [N·m·s/rad] (viscous).
MAX_FRICTION_NM = 50.0
#: Largest rotor inertia reflected at a joint [kg·m²] (an FR3 shoulder drive: about 0.1).
MAX_ROTOR_INERTIA_KGM2 = 5.0
#: Observer bandwidth bounds [1/s]: below 5 a contact takes more than 0.2 s to show; above 500
#: the estimate is mostly measurement noise (and needs a far faster sample rate than any bus gives).
MIN_OBSERVER_GAIN, MAX_OBSERVER_GAIN = 5.0, 500.0
#: Heaviest payload a policy may declare [kg].
MAX_PAYLOAD_KG = 50.0
#: Furthest payload centre of mass from the TCP [m].
MAX_PAYLOAD_OFFSET_M = 0.5

#: provisional external-torque limit per joint, as a share of its effort limit, and its bounds [N·m]
CONTACT_SHARE_OF_EFFORT = 0.15
MIN_PROVISIONAL_LIMIT_NM, MAX_PROVISIONAL_LIMIT_NM, UNKNOWN_EFFORT_LIMIT_NM = 2.0, 30.0, 5.0


def provisional_limit_nm(effort_nm: float | None) -> float:
    """A provisional external-torque limit [N·m] for a joint before it is calibrated: 15 % of its
    effort limit, within [2, 30] N·m (Franka's own defaults sit at 10–20 N·m on 87 N·m drives);
    5 N·m when the effort limit is unknown."""
    if effort_nm is None or not effort_nm > 0:
        return UNKNOWN_EFFORT_LIMIT_NM
    return round(min(MAX_PROVISIONAL_LIMIT_NM, max(MIN_PROVISIONAL_LIMIT_NM, CONTACT_SHARE_OF_EFFORT * effort_nm)), 1)


PerJoint = Annotated[Mapping[Name, FiniteFloat], AfterValidator(freeze_map), WrapSerializer(serialize_map)]
PayloadOffset = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=-MAX_PAYLOAD_OFFSET_M,
                                       le=MAX_PAYLOAD_OFFSET_M)]


def _each_within(values: Mapping[str, float], low: float, high: float, low_open: bool) -> Iterator[tuple[str, str]]:
    for name, value in values.items():
        if (value <= low if low_open else value < low) or value > high:
            bracket = "(" if low_open else "["
            yield name, f"{value!r} is outside {bracket}{low:g}, {high:g}]"


class JointTorqueConfig(BaseModel):
    """External-torque limits per joint, the friction and rotor inertia the observer allows for,
    its bandwidth and the payload the arm carries (its weight is not a contact). How to choose the
    limits, and `armwarden calibrate-contact`, which measures them: docs/contact.md."""

    model_config = MODEL_CONFIG

    max_external_torque_nm: PerJoint = Field(
        description=f"Largest estimated external torque per joint [N·m], by joint name, each in "
        f"(0, {MAX_EXTERNAL_TORQUE_NM:g}]; must cover exactly robot.joint_names.",
    )
    max_tcp_force_n: float | None = finite(
        gt=0, default=None,
        description="Largest TCP force [N] estimated from the joint torques (vector norm), held while the TCP "
        "Jacobian is well conditioned; at most force.max_contact_force_n. Unset: force.max_contact_force_n. "
        "The estimate's error in free motion differs from a sensor's, so it gets a limit of its own; "
        "`armwarden calibrate-contact` recommends one.",
    )
    friction_coulomb_nm: PerJoint = Field(
        default_factory=FrozenMap,
        description=f"Coulomb friction per joint [N·m] the observer expects while the joint moves "
        f"(not a contact), in [0, {MAX_FRICTION_NM:g}]; a joint not listed has none.",
    )
    friction_viscous_nms: PerJoint = Field(
        default_factory=FrozenMap,
        description=f"Viscous friction per joint [N·m·s/rad], in [0, {MAX_FRICTION_NM:g}]; a joint not listed has none.",
    )
    rotor_inertia_kgm2: PerJoint = Field(
        default_factory=FrozenMap,
        description=f"Rotor inertia reflected at each joint through its gearbox (armature) [kg·m²], in "
        f"[0, {MAX_ROTOR_INERTIA_KGM2:g}]; the motors spend torque accelerating it, which is not a contact. "
        "A joint not listed has none.",
    )
    observer_gain_per_s: float = finite(
        ge=MIN_OBSERVER_GAIN, le=MAX_OBSERVER_GAIN, default=50.0,
        description=f"Observer bandwidth K [1/s], in [{MIN_OBSERVER_GAIN:g}, {MAX_OBSERVER_GAIN:g}]: a step of "
        "external torque shows 63 % of its size after 1/K s. It is updated with every joint state the backend "
        "publishes (a servo loop's each tick where the backend keeps them, else once per force.monitor_rate_hz "
        "poll): a K near that rate filters little of the torque noise.",
    )
    payload_kg: float = finite(
        ge=0, le=MAX_PAYLOAD_KG, default=0.0,
        description=f"Mass the arm carries beyond its description [kg], in [0, {MAX_PAYLOAD_KG:g}] "
        "(its weight is not a contact).",
    )
    payload_com_m: tuple[PayloadOffset, PayloadOffset, PayloadOffset] = Field(
        default=(0.0, 0.0, 0.0),
        description=f"The payload's centre of mass in the TCP frame [m], each within ±{MAX_PAYLOAD_OFFSET_M:g}.",
    )

    @model_validator(mode="after")
    def _rules(self) -> JointTorqueConfig:
        enforce([self._values_in_range()])
        return self

    def _values_in_range(self) -> Iterator[Violation]:
        for field, low, high, low_open in (("max_external_torque_nm", 0.0, MAX_EXTERNAL_TORQUE_NM, True),
                                           ("friction_coulomb_nm", 0.0, MAX_FRICTION_NM, False),
                                           ("friction_viscous_nms", 0.0, MAX_FRICTION_NM, False),
                                           ("rotor_inertia_kgm2", 0.0, MAX_ROTOR_INERTIA_KGM2, False)):
            for name, message in _each_within(getattr(self, field), low, high, low_open):
                yield (field, name), message

    def per_joint(self, field: str, joint_names: tuple[str, ...]) -> tuple[float, ...]:
        """`field`'s values in `joint_names` order (an unlisted joint: 0)."""
        values: Mapping[str, float] = getattr(self, field)
        return tuple(float(values.get(name, 0.0)) for name in joint_names)

    def coverage_violations(self, joint_names: tuple[str, ...]) -> Iterator[Violation]:
        """The limits name exactly the driven joints; the friction maps name no other joint."""
        limits = self.max_external_torque_nm
        missing = [name for name in joint_names if name not in limits]
        extra = [name for name in limits if name not in joint_names]
        if missing or extra:
            parts = ([f"no limit for joint(s) {missing}"] if missing else []) + (
                [f"limit given for joint(s) not in robot.joint_names {extra}"] if extra else [])
            yield ("max_external_torque_nm",), "must cover exactly robot.joint_names: " + "; ".join(parts)
        for field in ("friction_coulomb_nm", "friction_viscous_nms", "rotor_inertia_kgm2"):
            unknown = [name for name in getattr(self, field) if name not in joint_names]
            if unknown:
                yield (field,), f"names joint(s) not in robot.joint_names: {unknown}"
