"""The `robot` section: which description to load, its frames, the driven joints and their limits."""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Annotated

from pydantic import AfterValidator, BaseModel, Field, ValidationInfo, WrapSerializer, field_validator, model_validator

from armwarden.policy.fields import (
    MODEL_CONFIG,
    FiniteFloat,
    FrozenMap,
    Name,
    UniqueNames,
    Violation,
    enforce,
    finite,
    freeze_map,
    not_empty,
    serialize_map,
)
from armwarden.robots import BUILTIN_PREFIX

#: Fastest joint speed a policy may allow [rad/s]: one turn per second, above any arm joint
#: ArmWarden drives (FR3: 2.62–5.26). More is a unit slip (°/s) or no velocity limit at all.
MAX_JOINT_VELOCITY = round(2 * math.pi, 4)
#: Largest joint acceleration a policy may allow [rad/s²] (FR3: 7.5–20). More is a unit slip
#: (°/s²) or no acceleration limit at all.
MAX_JOINT_ACCELERATION = 50.0


class JointLimits(BaseModel):
    """Limits of one joint. The envelope refuses any plan that leaves them."""

    model_config = MODEL_CONFIG

    min: FiniteFloat = Field(description="Lower position limit [rad] (metres for a prismatic joint).")
    max: FiniteFloat = Field(description="Upper position limit [rad] (metres for a prismatic joint).")
    max_velocity: float = finite(
        gt=0,
        le=MAX_JOINT_VELOCITY,
        description=f"Maximum joint speed [rad/s] (m/s for a prismatic joint), in (0, {MAX_JOINT_VELOCITY:g}].",
    )
    max_acceleration: float = finite(
        gt=0,
        le=MAX_JOINT_ACCELERATION,
        description="Maximum joint acceleration [rad/s²] (m/s² for a prismatic joint), "
        f"in (0, {MAX_JOINT_ACCELERATION:g}].",
    )

    @model_validator(mode="after")
    def _rules(self) -> JointLimits:
        enforce([self._min_below_max()])
        return self

    def _min_below_max(self) -> Iterator[Violation]:
        """An empty position range would make every configuration invalid."""
        if not self.min < self.max:
            yield ("min",), f"min ({self.min:g}) must be less than max ({self.max:g})"


def _builtin_or_path(what: str, value: str, info: ValidationInfo) -> str:
    """`builtin:<name>` as given, or the path resolved against the policy file's folder."""
    if value.startswith(BUILTIN_PREFIX):
        key = value[len(BUILTIN_PREFIX):]
        if not key or not all(c.isalnum() or c in "_-" for c in key):
            raise ValueError(f"built-in {what} must look like `builtin:<name>` (got {value!r})")
        return value
    if value != value.strip():
        raise ValueError(f"{what} path has leading/trailing whitespace: {value!r}")
    path = Path(value).expanduser()
    base_dir = (info.context or {}).get("base_dir")
    if not path.is_absolute() and base_dir is not None:
        path = (Path(base_dir) / path).resolve()
    return str(path)


class RobotConfig(BaseModel):
    """The arm: which description to load, its frames, the joints ArmWarden drives and their limits."""

    model_config = MODEL_CONFIG

    name: Name = Field(description="Human-readable robot name (no unit), shown in summaries and prompts.")
    description: str = Field(
        strict=True,
        min_length=1,
        description=(
            "Robot description (no unit): `builtin:<name>` (e.g. `builtin:fr3`) or a path to a URDF file; "
            "a relative path is resolved against the folder of the policy file."
        ),
    )
    collision_geometry: str = Field(
        default="auto",
        strict=True,
        min_length=1,
        description=(
            "Collision bodies the envelope checks (no unit): `auto` (the default: the capsules fitted to the "
            "manufacturer's collision meshes that ship with a built-in description, else the URDF's own collision "
            "primitives), `urdf` (one capsule around each URDF collision primitive), `builtin:<name>` (a bundled "
            "fitted file, e.g. `builtin:fr3`) or a path to a fitted-geometry file written by "
            "scripts/fit_geometry.py (relative paths resolve against the policy file's folder)."
        ),
    )
    base_frame: Name = Field(description="Frame (no unit) every position in the policy and the tools is expressed in.")
    tcp_frame: Name = Field(
        description="Tool-centre-point frame (no unit) that pose targets refer to and whose path length "
        "`motion.max_cartesian_step_m` caps. It must move with the last joint of `joint_names`: check-policy and "
        "serve refuse a frame on the base or on an inner link (the cap would measure nothing), listing the "
        "frames that qualify."
    )
    joint_names: Annotated[UniqueNames, AfterValidator(not_empty)] = Field(
        json_schema_extra={"minItems": 1},
        description="Driven joints (no unit), in the kinematic order of the description; at least one.",
    )
    joint_limits: Annotated[
        Mapping[Name, JointLimits], AfterValidator(freeze_map), WrapSerializer(serialize_map)
    ] = Field(description="Limits per joint name (rad, rad/s, rad/s²); must cover exactly `joint_names`.")
    home_joint_positions: tuple[FiniteFloat, ...] = Field(
        description="Home configuration [rad], one value per joint in `joint_names` order, within the limits."
    )

    @field_validator("description")
    @classmethod
    def _resolve_description(cls, value: str, info: ValidationInfo) -> str:
        """Built-ins pass through; relative URDF paths resolve against the policy's folder.

        Resolving here (rather than against the daemon's working directory at start-up) means the
        same policy file loads the same robot wherever the daemon is started from.
        """
        return _builtin_or_path("description", value, info)

    @field_validator("collision_geometry")
    @classmethod
    def _resolve_collision_geometry(cls, value: str, info: ValidationInfo) -> str:
        """Keywords and built-ins pass through; a relative path resolves against the policy's folder."""
        if value in ("auto", "urdf"):
            return value
        return _builtin_or_path("collision geometry", value, info)

    @model_validator(mode="after")
    def _rules(self) -> RobotConfig:
        enforce([self._limits_cover_joints(), self._home_has_one_value_per_joint(), self._home_within_limits()])
        if set(self.joint_limits) == set(self.joint_names):  # normalise: limits in joint order
            ordered = FrozenMap((name, self.joint_limits[name]) for name in self.joint_names)
            object.__setattr__(self, "joint_limits", ordered)
        return self

    def _limits_cover_joints(self) -> Iterator[Violation]:
        """A joint without limits would be unchecked; limits for an unknown joint hint at a typo."""
        missing = [name for name in self.joint_names if name not in self.joint_limits]
        extra = [name for name in self.joint_limits if name not in self.joint_names]
        if missing or extra:
            parts = []
            if missing:
                parts.append(f"no limits for joint(s) {missing}")
            if extra:
                parts.append(f"limits given for joint(s) not in joint_names {extra}")
            yield ("joint_limits",), "joint_limits must cover exactly joint_names: " + "; ".join(parts)

    def _home_has_one_value_per_joint(self) -> Iterator[Violation]:
        if len(self.home_joint_positions) != len(self.joint_names):
            yield ("home_joint_positions",), (
                f"has {len(self.home_joint_positions)} value(s) but joint_names has {len(self.joint_names)}"
            )

    def _home_within_limits(self) -> Iterator[Violation]:
        """Home is a motion target; it must be reachable without leaving the limits."""
        # a count mismatch is its own rule (_home_has_one_value_per_joint)
        for index, (name, value) in enumerate(zip(self.joint_names, self.home_joint_positions, strict=False)):
            limits = self.joint_limits.get(name)
            if limits is not None and not limits.min <= value <= limits.max:
                yield ("home_joint_positions", index), (
                    f"home of {name} is {value:g} rad, outside its limits [{limits.min:g}, {limits.max:g}] rad"
                )

    # convenience views in joint order (plain properties: the model stays frozen and comparable)
    @property
    def lower_limits(self) -> tuple[float, ...]:
        """Lower position limits [rad] in `joint_names` order."""
        return tuple(self.joint_limits[n].min for n in self.joint_names)

    @property
    def upper_limits(self) -> tuple[float, ...]:
        """Upper position limits [rad] in `joint_names` order."""
        return tuple(self.joint_limits[n].max for n in self.joint_names)

    @property
    def velocity_limits(self) -> tuple[float, ...]:
        """Maximum joint speeds [rad/s] in `joint_names` order."""
        return tuple(self.joint_limits[n].max_velocity for n in self.joint_names)

    @property
    def acceleration_limits(self) -> tuple[float, ...]:
        """Maximum joint accelerations [rad/s²] in `joint_names` order."""
        return tuple(self.joint_limits[n].max_acceleration for n in self.joint_names)

