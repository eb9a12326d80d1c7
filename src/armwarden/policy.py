"""The safety policy: a strict, versioned, immutable description of everything the daemon allows.

The policy is the one input the server trusts (DESIGN.md §1.2), so it is validated harder than
anything else:

* every mapping rejects unknown keys (a typo must never silently fall back to a default);
* scalars are strictly typed (``true`` is not ``1.0``, ``"0.3"`` is not ``0.3``) and floats must
  be finite (``.nan`` / ``.inf`` are errors);
* sequences become tuples and mappings become read-only, so the loaded policy cannot be changed
  for the life of the process;
* duplicate YAML keys are errors (PyYAML would silently keep the last one);
* cross-field rules (limits cover the joints, home within limits, defaults within caps, ...) are
  small named functions, each returning the violations it found;
* every problem is reported at once, each with the YAML path of the offending value, as a
  :class:`~armwarden.errors.PolicyError`.

Units are SI throughout: metres, radians, seconds, newtons; positions in the robot base frame.

Public API: :func:`load_policy`, :func:`parse_policy`, :class:`Policy` (and its section models),
:func:`summarize_policy`, :func:`policy_json_schema`, :data:`TOOL_GROUPS`, :data:`ALL_TOOLS`.
"""

from __future__ import annotations

import copy
import difflib
import math
import os
import types
import typing
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any, Literal, Optional, TypeVar, Union

import yaml
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    WrapSerializer,
    field_validator,
    model_validator,
)

from armwarden.errors import PolicyError

__all__ = [
    "ALL_TOOLS",
    "APPROVAL_ACTIONS",
    "DOCUMENT_PATH",
    "MAX_POLICY_BYTES",
    "RATE_LIMIT_EXEMPT_TOOLS",
    "TOOL_GROUPS",
    "ApprovalConfig",
    "Box",
    "ControllersConfig",
    "ForceConfig",
    "FrozenMap",
    "GripperConfig",
    "JointLimits",
    "KeepOutZone",
    "MotionConfig",
    "PerceptionConfig",
    "Policy",
    "RateLimitsConfig",
    "RobotConfig",
    "ToolsConfig",
    "WorkspaceConfig",
    "format_path",
    "load_policy",
    "parse_policy",
    "policy_json_schema",
    "summarize_policy",
    "validation_errors",
]

# ====================================================================== public constants

#: Tool group → tool names, in the order of DESIGN.md §3. The names are a public contract.
TOOL_GROUPS: dict[str, tuple[str, ...]] = {
    "introspect": (
        "get_robot_state",
        "get_safety_envelope",
        "lookup_transform",
        "list_controllers",
        "list_ros_graph",
        "get_audit_tail",
    ),
    "perception": ("camera_snapshot",),
    "motion": ("plan_to_joints", "plan_to_pose", "plan_cartesian_path", "execute_plan", "get_motion_status"),
    "gripper": ("gripper_move", "gripper_grasp", "gripper_home"),
    "control": ("switch_controllers", "set_collision_thresholds"),
    "safety": ("stop_motion", "estop", "reset_estop", "error_recovery", "get_safety_status"),
}
#: Every tool name, group by group.
ALL_TOOLS: tuple[str, ...] = tuple(tool for tools in TOOL_GROUPS.values() for tool in tools)
#: Tools the rate limiter never throttles (stopping must always work; DESIGN.md §4).
RATE_LIMIT_EXEMPT_TOOLS: tuple[str, ...] = ("stop_motion", "estop", "get_safety_status")
#: Actions that can be put behind human approval; `reset_estop` is always among them.
APPROVAL_ACTIONS: tuple[str, ...] = (
    "execute",
    "switch_controllers",
    "reset_estop",
    "error_recovery",
    "set_collision_thresholds",
)
#: Policy files larger than this are refused before parsing.
MAX_POLICY_BYTES = 1024 * 1024
#: The path reported for problems with the document as a whole (unreadable, not YAML, not a mapping).
DOCUMENT_PATH = "<document>"

BUILTIN_PREFIX = "builtin:"
DEFAULT_SCALING = 0.1

ToolGroup = Literal["introspect", "perception", "motion", "gripper", "control", "safety"]
ApprovalAction = Literal["execute", "switch_controllers", "reset_estop", "error_recovery", "set_collision_thresholds"]

# ====================================================================== building-block types

_K = TypeVar("_K")
_V = TypeVar("_V")


class FrozenMap(Mapping[_K, _V]):
    """A read-only mapping that keeps insertion order, hashes, compares like a dict and pickles.

    `types.MappingProxyType` would do, except that it cannot be copied or pickled, and callers
    (tests, `model_copy(deep=True)`) legitimately do both.
    """

    __slots__ = ("_data",)

    def __init__(self, data: Mapping[_K, _V] | Iterable[tuple[_K, _V]] = ()) -> None:
        self._data: dict[_K, _V] = dict(data)

    def __getitem__(self, key: _K) -> _V:
        return self._data[key]

    def __iter__(self) -> Iterator[_K]:
        return iter(self._data)

    def __len__(self) -> int:
        return len(self._data)

    def __hash__(self) -> int:
        return hash(tuple(self._data.items()))

    def __repr__(self) -> str:
        return f"FrozenMap({self._data!r})"

    def __reduce__(self) -> tuple[Any, ...]:
        return (FrozenMap, (self._data,))


def _serialize_map(value: Mapping[Any, Any], handler: Callable[[Any], Any]) -> Any:
    return handler(dict(value))


def _freeze_map(value: Mapping[Any, Any]) -> FrozenMap[Any, Any]:
    return FrozenMap(value)


def _unique(values: tuple[str, ...]) -> tuple[str, ...]:
    """Reject repeated names: a repeat is almost always a typo for a name that is now missing."""
    seen: set[str] = set()
    repeated = [v for v in values if v in seen or seen.add(v)]  # type: ignore[func-returns-value]
    if repeated:
        raise ValueError(f"names must be unique; repeated: {sorted(set(repeated))}")
    return values


def _not_empty(values: tuple[str, ...]) -> tuple[str, ...]:
    """Checked after the items (pydantic's `min_length` would also fire when an item is invalid)."""
    if not values:
        raise ValueError("must list at least one name")
    return values


def _finite(**limits: Any) -> Any:
    """A strict, finite float field constraint (ints are accepted and widened; bools are not)."""
    return Field(strict=True, allow_inf_nan=False, **limits)


#: A finite float (no NaN/Inf, no bool, no numeric string).
FiniteFloat = Annotated[float, Field(strict=True, allow_inf_nan=False)]
#: A name: non-empty, no whitespace (joints, frames, links, cameras, controllers, zones).
Name = Annotated[str, Field(strict=True, min_length=1, max_length=128, pattern=r"^\S+$")]
UniqueNames = Annotated[tuple[Name, ...], AfterValidator(_unique)]
#: [x, y, z] in metres, in the robot base frame.
Vector3 = tuple[FiniteFloat, FiniteFloat, FiniteFloat]
StrictBool = Annotated[bool, Field(strict=True)]
_Rate = Annotated[int, Field(strict=True, ge=1)]

_MODEL_CONFIG = ConfigDict(extra="forbid", frozen=True)

# ====================================================================== cross-field rule plumbing

Violation = tuple[tuple[Union[str, int], ...], str]
"""A rule violation: the path of the offending value relative to the model, and a message."""


class _RuleViolations(ValueError):
    """Raised by a model's rule check; carries every violation with its relative path.

    Pydantic keeps the raised exception in the error's context, so `validation_errors`
    can turn each violation into its own `(yaml_path, message)` pair with an exact path.
    """

    def __init__(self, violations: Sequence[Violation]) -> None:
        self.violations = list(violations)
        super().__init__("; ".join(message for _, message in self.violations))


def _enforce(rules: Iterable[Iterable[Violation]]) -> None:
    """Run every rule and raise once with all their violations (so all are reported together)."""
    violations = [violation for rule in rules for violation in rule]
    if violations:
        raise _RuleViolations(violations)


def _check_min_below_max(lo: Sequence[float], hi: Sequence[float]) -> Iterator[Violation]:
    """An axis-aligned box needs min < max on every axis; an empty or flat box is a typo."""
    bad = [f"{axis}: {a:g} >= {b:g}" for axis, a, b in zip("xyz", lo, hi) if not a < b]
    if bad:
        yield ("min",), f"min must be less than max on every axis ({', '.join(bad)})"


# ====================================================================== robot


class JointLimits(BaseModel):
    """Limits of one joint. The envelope refuses any plan that leaves them."""

    model_config = _MODEL_CONFIG

    min: FiniteFloat = Field(description="Lower position limit [rad] (metres for a prismatic joint).")
    max: FiniteFloat = Field(description="Upper position limit [rad] (metres for a prismatic joint).")
    max_velocity: float = _finite(gt=0, description="Maximum joint speed [rad/s] (m/s for a prismatic joint).")
    max_acceleration: float = _finite(
        gt=0, description="Maximum joint acceleration [rad/s²] (m/s² for a prismatic joint)."
    )

    @model_validator(mode="after")
    def _rules(self) -> JointLimits:
        _enforce([self._min_below_max()])
        return self

    def _min_below_max(self) -> Iterator[Violation]:
        """An empty position range would make every configuration invalid."""
        if not self.min < self.max:
            yield ("min",), f"min ({self.min:g}) must be less than max ({self.max:g})"


class RobotConfig(BaseModel):
    """The arm: which description to load, its frames, the joints ArmWarden drives and their limits."""

    model_config = _MODEL_CONFIG

    name: Name = Field(description="Human-readable robot name (no unit), shown in summaries and prompts.")
    description: str = Field(
        strict=True,
        min_length=1,
        description=(
            "Robot description (no unit): `builtin:<name>` (e.g. `builtin:fr3`) or a path to a URDF file; "
            "a relative path is resolved against the folder of the policy file."
        ),
    )
    base_frame: Name = Field(description="Frame (no unit) every position in the policy and the tools is expressed in.")
    tcp_frame: Name = Field(description="Tool-centre-point frame (no unit) that pose targets refer to.")
    joint_names: Annotated[UniqueNames, AfterValidator(_not_empty)] = Field(
        json_schema_extra={"minItems": 1},
        description="Driven joints (no unit), in the kinematic order of the description; at least one.",
    )
    joint_limits: Annotated[
        Mapping[Name, JointLimits], AfterValidator(_freeze_map), WrapSerializer(_serialize_map)
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
        if value.startswith(BUILTIN_PREFIX):
            key = value[len(BUILTIN_PREFIX):]
            if not key or not all(c.isalnum() or c in "_-" for c in key):
                raise ValueError(f"built-in description must look like `builtin:<name>` (got {value!r})")
            return value
        if value != value.strip():
            raise ValueError(f"description path has leading/trailing whitespace: {value!r}")
        path = Path(value).expanduser()
        base_dir = (info.context or {}).get("base_dir")
        if not path.is_absolute() and base_dir is not None:
            path = (Path(base_dir) / path).resolve()
        return str(path)

    @model_validator(mode="after")
    def _rules(self) -> RobotConfig:
        _enforce([self._limits_cover_joints(), self._home_has_one_value_per_joint(), self._home_within_limits()])
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
        for index, (name, value) in enumerate(zip(self.joint_names, self.home_joint_positions)):
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


# ====================================================================== tools


def _normalise_groups(groups: tuple[str, ...]) -> tuple[str, ...]:
    """`safety` (stop, e-stop, ...) can never be switched off; order is canonical, repeats dropped."""
    wanted = set(groups) | {"safety"}
    return tuple(group for group in TOOL_GROUPS if group in wanted)


class ToolsConfig(BaseModel):
    """Which tool groups are registered. A disabled tool does not appear in `tools/list` at all."""

    model_config = _MODEL_CONFIG

    enabled: Annotated[tuple[ToolGroup, ...], AfterValidator(_normalise_groups)] = Field(
        default=("introspect", "safety"),
        description=(
            "Enabled tool groups (no unit), a subset of introspect, perception, motion, gripper, control, "
            "safety; `safety` is always added."
        ),
    )

    @property
    def tools(self) -> tuple[str, ...]:
        """Every tool name of the enabled groups."""
        return tuple(tool for group in self.enabled for tool in TOOL_GROUPS[group])


# ====================================================================== workspace


class Box(BaseModel):
    """An axis-aligned box in the robot base frame."""

    model_config = _MODEL_CONFIG

    min: Vector3 = Field(description="Lower corner [x, y, z] in metres, base frame.")
    max: Vector3 = Field(description="Upper corner [x, y, z] in metres, base frame.")

    @model_validator(mode="after")
    def _rules(self) -> Box:
        _enforce([_check_min_below_max(self.min, self.max)])
        return self


class KeepOutZone(BaseModel):
    """A named box no part of the arm (TCP or padded link geometry) may enter."""

    model_config = _MODEL_CONFIG

    name: Name = Field(description="Zone name (no unit), unique, quoted in violations.")
    min: Vector3 = Field(description="Lower corner [x, y, z] in metres, base frame.")
    max: Vector3 = Field(description="Upper corner [x, y, z] in metres, base frame.")

    @model_validator(mode="after")
    def _rules(self) -> KeepOutZone:
        _enforce([_check_min_below_max(self.min, self.max)])
        return self


class WorkspaceConfig(BaseModel):
    """Where the arm may be: inside `box`, outside every `keep_out` zone, links padded."""

    model_config = _MODEL_CONFIG

    box: Box = Field(description="Workspace box (metres, base frame) the TCP and every checked link must stay in.")
    keep_out: tuple[KeepOutZone, ...] = Field(
        default=(), description="Keep-out boxes (metres, base frame) the TCP and every checked link must avoid."
    )
    link_padding_m: float = _finite(
        ge=0, default=0.01, description="Padding [m] added to every link's collision geometry."
    )
    check_links: Optional[Annotated[UniqueNames, AfterValidator(_not_empty)]] = Field(
        default=None,
        description="Links (no unit) whose collision geometry is checked; null means every link that moves. "
        "An empty list is an error: it would silently check no link at all.",
    )
    self_collision: StrictBool = Field(default=True, description="Check links against each other (boolean).")

    @model_validator(mode="after")
    def _rules(self) -> WorkspaceConfig:
        _enforce([self._keep_out_names_unique()])
        return self

    def _keep_out_names_unique(self) -> Iterator[Violation]:
        """Violations quote the zone name; two zones with one name would make reports ambiguous."""
        first: dict[str, int] = {}
        for index, zone in enumerate(self.keep_out):
            if zone.name in first:
                yield ("keep_out", index, "name"), (
                    f"duplicate keep-out name {zone.name!r} (already used by keep_out[{first[zone.name]}])"
                )
            else:
                first[zone.name] = index


# ====================================================================== motion


class MotionConfig(BaseModel):
    """Caps on planned motion. Scalings multiply the joint velocity/acceleration limits."""

    model_config = _MODEL_CONFIG

    max_velocity_scaling: float = _finite(
        gt=0, le=1, description="Cap on velocity scaling (fraction of joint max_velocity, in (0, 1])."
    )
    max_acceleration_scaling: float = _finite(
        gt=0, le=1, description="Cap on acceleration scaling (fraction of joint max_acceleration, in (0, 1])."
    )
    default_velocity_scaling: float = _finite(
        gt=0,
        le=1,
        default=DEFAULT_SCALING,
        description="Velocity scaling (fraction, in (0, 1]) used when a request gives none; ≤ the cap. "
        "Default 0.1, or the cap if that is lower.",
    )
    default_acceleration_scaling: float = _finite(
        gt=0,
        le=1,
        default=DEFAULT_SCALING,
        description="Acceleration scaling (fraction, in (0, 1]) used when a request gives none; ≤ the cap. "
        "Default 0.1, or the cap if that is lower.",
    )
    max_joint_step_rad: float = _finite(gt=0, description="Hard cap on any joint's travel in one plan [rad].")
    soft_joint_step_rad: Optional[float] = _finite(
        gt=0,
        default=None,
        description="Joint travel in one plan [rad] above which approval is needed; ≤ max_joint_step_rad. "
        "Null: no soft threshold.",
    )
    max_cartesian_step_m: float = _finite(gt=0, description="Hard cap on the TCP path length of one plan [m].")
    plan_ttl_s: float = _finite(gt=0, le=3600, default=120, description="Plan lifetime [s], in (0, 3600].")
    joint_limit_margin_rad: float = _finite(
        ge=0, default=0.05, description="Distance to a joint limit [rad] below which a plan needs approval."
    )
    start_tolerance_rad: float = _finite(
        gt=0, default=0.01, description="Largest joint deviation [rad] from a plan's start state at execution."
    )
    check_resolution_rad: float = _finite(
        gt=0, default=0.02, description="Largest joint step [rad] between configurations the planner checks."
    )
    sweep_resolution_m: float = _finite(
        gt=0,
        le=0.05,
        default=0.01,
        description="Largest displacement [m] of any checked body between envelope samples, in (0, 0.05].",
    )

    @model_validator(mode="before")
    @classmethod
    def _default_scalings_follow_low_caps(cls, data: Any) -> Any:
        """An omitted default scaling is 0.1, lowered to the cap when the cap is below 0.1.

        Writing only a (low) cap is the natural way to make a policy more conservative; it should
        not fail because of a default the author never wrote. An explicit default above the cap is
        still an error.
        """
        if not isinstance(data, Mapping):
            return data
        data = dict(data)
        for default_key, cap_key in (
            ("default_velocity_scaling", "max_velocity_scaling"),
            ("default_acceleration_scaling", "max_acceleration_scaling"),
        ):
            cap = data.get(cap_key)
            if (
                default_key not in data
                and isinstance(cap, (int, float))
                and not isinstance(cap, bool)
                and math.isfinite(cap)
                and 0 < cap < DEFAULT_SCALING
            ):
                data[default_key] = cap
        return data

    @model_validator(mode="after")
    def _rules(self) -> MotionConfig:
        _enforce([self._defaults_within_caps(), self._soft_step_within_hard_step()])
        return self

    def _defaults_within_caps(self) -> Iterator[Violation]:
        """Above-cap requests are clamped to the cap; a default above it would be clamped on every call."""
        for default_key, cap_key in (
            ("default_velocity_scaling", "max_velocity_scaling"),
            ("default_acceleration_scaling", "max_acceleration_scaling"),
        ):
            default, cap = getattr(self, default_key), getattr(self, cap_key)
            if default > cap:
                yield (default_key,), f"{default_key} ({default:g}) must not exceed {cap_key} ({cap:g})"

    def _soft_step_within_hard_step(self) -> Iterator[Violation]:
        """A soft threshold above the hard cap could never trigger: the plan is rejected first."""
        if self.soft_joint_step_rad is not None and self.soft_joint_step_rad > self.max_joint_step_rad:
            yield ("soft_joint_step_rad",), (
                f"soft_joint_step_rad ({self.soft_joint_step_rad:g}) must not exceed "
                f"max_joint_step_rad ({self.max_joint_step_rad:g})"
            )


# ====================================================================== force, gripper, controllers, perception


class ForceConfig(BaseModel):
    """Contact-force monitoring while a trajectory runs. Over the limit: stop and latch the e-stop."""

    model_config = _MODEL_CONFIG

    max_contact_force_n: float = _finite(gt=0, description="Largest external force at the TCP [N] (vector norm).")
    max_contact_torque_nm: float = _finite(gt=0, description="Largest external torque at the TCP [N·m] (vector norm).")
    monitor_rate_hz: float = _finite(gt=0, le=5000, default=200, description="Wrench polling rate [Hz], in (0, 5000].")
    require_wrench: StrictBool = Field(
        default=True,
        description="Refuse to execute without a wrench signal (boolean). False runs without force enforcement.",
    )
    wrench_timeout_s: float = _finite(
        gt=0, le=2, default=0.1, description="Oldest acceptable wrench sample [s], in (0, 2]; older aborts the motion."
    )


class GripperConfig(BaseModel):
    """Gripper bounds; required when the `gripper` tool group is enabled."""

    model_config = _MODEL_CONFIG

    min_width_m: float = _finite(ge=0, default=0.0, description="Narrowest commanded opening [m].")
    max_width_m: float = _finite(gt=0, description="Widest commanded opening [m]; greater than min_width_m.")
    max_grasp_force_n: float = _finite(gt=0, description="Largest grasp force [N].")
    max_speed_mps: float = _finite(gt=0, description="Largest finger speed [m/s].")

    @model_validator(mode="after")
    def _rules(self) -> GripperConfig:
        _enforce([self._width_range_not_empty()])
        return self

    def _width_range_not_empty(self) -> Iterator[Violation]:
        if not self.max_width_m > self.min_width_m:
            yield ("max_width_m",), (
                f"max_width_m ({self.max_width_m:g}) must be greater than min_width_m ({self.min_width_m:g})"
            )


class ControllersConfig(BaseModel):
    """Controllers `switch_controllers` may activate; anything else is refused."""

    model_config = _MODEL_CONFIG

    allowlist: UniqueNames = Field(default=(), description="Controller names (no unit) that may be activated.")


class PerceptionConfig(BaseModel):
    """Cameras `camera_snapshot` may read, and how large an image may be."""

    model_config = _MODEL_CONFIG

    cameras: UniqueNames = Field(default=(), description="Camera names (no unit) that may be read.")
    max_image_width: int = Field(
        default=640, strict=True, ge=16, le=4096, description="Largest returned image width [pixels], 16..4096."
    )


# ====================================================================== rate limits, approval


def _check_rate_limited_tool(name: str) -> str:
    """Per-tool overrides must name a real, throttled tool; anything else would be silently ignored."""
    if name in RATE_LIMIT_EXEMPT_TOOLS:
        raise ValueError(
            f"{name!r} is never rate limited (exempt: {', '.join(RATE_LIMIT_EXEMPT_TOOLS)}); remove this entry"
        )
    if name not in ALL_TOOLS:
        hint = difflib.get_close_matches(name, ALL_TOOLS, n=1)
        did_you_mean = f"did you mean {hint[0]!r}? " if hint else ""
        raise ValueError(f"unknown tool name {name!r}; {did_you_mean}valid tools: {', '.join(ALL_TOOLS)}")
    return name


RateLimitedTool = Annotated[str, Field(strict=True), AfterValidator(_check_rate_limited_tool)]


class RateLimitsConfig(BaseModel):
    """Token buckets with continuous refill. stop_motion, estop and get_safety_status are exempt."""

    model_config = _MODEL_CONFIG

    global_per_minute: _Rate = Field(default=120, description="Calls per minute [1/min] across all tools.")
    default_per_minute: _Rate = Field(default=60, description="Calls per minute [1/min] per tool without an override.")
    per_tool: Annotated[
        Mapping[RateLimitedTool, _Rate], AfterValidator(_freeze_map), WrapSerializer(_serialize_map)
    ] = Field(default_factory=FrozenMap, description="Per-tool overrides: tool name → calls per minute [1/min].")

    def limit_for(self, tool: str) -> int:
        """Calls per minute allowed for `tool` (its override, else the default)."""
        return self.per_tool.get(tool, self.default_per_minute)


def _normalise_require_for(actions: tuple[str, ...]) -> tuple[str, ...]:
    """Releasing an e-stop always needs a human (DESIGN.md §4); order is canonical, repeats dropped."""
    wanted = set(actions) | {"reset_estop"}
    return tuple(action for action in APPROVAL_ACTIONS if action in wanted)


class ApprovalConfig(BaseModel):
    """When a human must approve, through the client's elicitation UI or the operator console."""

    model_config = _MODEL_CONFIG

    mode: Literal["always", "outside_envelope", "never"] = Field(
        default="outside_envelope",
        description="always: every approvable action; outside_envelope: only with soft violations; never (no unit).",
    )
    on_client_without_elicitation: Literal["deny", "allow"] = Field(
        default="deny",
        description="What to do when approval is needed but the client cannot ask (no unit); "
        "`reset_estop` always needs a human.",
    )
    require_for: Annotated[tuple[ApprovalAction, ...], AfterValidator(_normalise_require_for)] = Field(
        default=APPROVAL_ACTIONS,
        description="Actions (no unit) that go through approval; `reset_estop` is always included.",
    )


# ====================================================================== the policy


class Policy(BaseModel):
    """ArmWarden safety policy, version 1. Loaded once, validated strictly, immutable."""

    model_config = _MODEL_CONFIG

    version: Literal[1] = Field(description="Policy format version (no unit); must be 1.")
    robot: RobotConfig = Field(description="The arm, its frames, joints and joint limits.")
    tools: ToolsConfig = Field(default_factory=ToolsConfig, description="Enabled tool groups.")
    workspace: WorkspaceConfig = Field(description="Workspace box and keep-out zones (metres, base frame).")
    motion: MotionConfig = Field(description="Motion caps (scalings, joint/Cartesian steps, timing, resolutions).")
    force: ForceConfig = Field(description="Contact force/torque limits (N, N·m) and monitoring.")
    gripper: Optional[GripperConfig] = Field(
        default=None, description="Gripper bounds (m, N, m/s); required when the gripper group is enabled."
    )
    controllers: ControllersConfig = Field(default_factory=ControllersConfig, description="Controller allowlist.")
    perception: PerceptionConfig = Field(default_factory=PerceptionConfig, description="Camera allowlist, image size.")
    rate_limits: RateLimitsConfig = Field(default_factory=RateLimitsConfig, description="Rate limits [1/min].")
    approval: ApprovalConfig = Field(default_factory=ApprovalConfig, description="Human approval rules.")
    dry_run: StrictBool = Field(default=False, description="Validate and ask, but never actuate (boolean).")

    @field_validator("version", mode="before")
    @classmethod
    def _version_is_an_integer(cls, value: Any) -> Any:
        """`Literal[1]` alone would accept `true` and `1.0`; the version must be the integer 1."""
        if type(value) is not int:
            raise ValueError(f"version must be the integer 1 (got {_show(value)})")
        return value

    @model_validator(mode="after")
    def _rules(self) -> Policy:
        _enforce([self._gripper_section_when_gripper_enabled(), self._limit_margin_leaves_room()])
        return self

    def _gripper_section_when_gripper_enabled(self) -> Iterator[Violation]:
        """Gripper tools without bounds would be unbounded; refuse rather than guess."""
        if "gripper" in self.tools.enabled and self.gripper is None:
            yield ("gripper",), "the gripper tool group is enabled, so the gripper section is required"

    def _limit_margin_leaves_room(self) -> Iterator[Violation]:
        """A margin of half a joint's range or more would flag every position of that joint."""
        for name, limits in self.robot.joint_limits.items():
            if 2 * self.motion.joint_limit_margin_rad >= limits.max - limits.min:
                yield ("motion", "joint_limit_margin_rad"), (
                    f"joint_limit_margin_rad ({self.motion.joint_limit_margin_rad:g}) leaves no room in the range "
                    f"of {name} [{limits.min:g}, {limits.max:g}]"
                )

    @property
    def enabled_tools(self) -> tuple[str, ...]:
        """Every tool name of the enabled groups (before backend capabilities are considered)."""
        return self.tools.tools

    def with_dry_run(self, enabled: bool = True) -> Policy:
        """A copy with dry run forced on when `enabled` (the `--dry-run` flag).

        `with_dry_run(False)` never turns off a dry run the policy file asked for: the flag can
        only make the daemon safer, so `policy.with_dry_run(args.dry_run)` is always correct.
        """
        if not enabled or self.dry_run:
            return self
        return self.model_copy(update={"dry_run": True})


# ====================================================================== loading


class _PolicyLoader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate keys (PyYAML keeps the last one silently)."""


def _construct_mapping_without_duplicates(loader: _PolicyLoader, node: yaml.MappingNode) -> dict[Any, Any]:
    seen: dict[Any, yaml.Node] = {}
    for key_node, _ in node.value:
        if key_node.tag == "tag:yaml.org,2002:merge" or not isinstance(key_node, yaml.ScalarNode):
            continue  # merge keys may be overridden on purpose; non-scalar keys fail validation anyway
        key = loader.construct_object(key_node)
        if key in seen:
            raise yaml.constructor.ConstructorError(
                "while constructing a mapping",
                node.start_mark,
                f"found duplicate key {key!r} (first at line {seen[key].start_mark.line + 1})",
                key_node.start_mark,
            )
        seen[key] = key_node
    return loader.construct_mapping(node, deep=True)


_PolicyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping_without_duplicates)


def _yaml_error_message(exc: yaml.YAMLError) -> str:
    if isinstance(exc, yaml.MarkedYAMLError):
        mark = exc.problem_mark or exc.context_mark
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        what = "; ".join(part for part in (exc.context, exc.problem) if part)
        return f"invalid YAML{where}: {what}"
    return f"invalid YAML: {exc}"


def load_policy(path: str | os.PathLike[str]) -> Policy:
    """Read, parse and validate a policy file. Raises `PolicyError` listing every problem.

    Relative `robot.description` paths are resolved against the folder holding the file.
    """
    path = Path(path).expanduser()
    source = str(path)
    try:
        with path.open("rb") as handle:
            raw = handle.read(MAX_POLICY_BYTES + 1)
    except OSError as exc:
        raise PolicyError(source, [(DOCUMENT_PATH, f"cannot read the policy file: {exc.strerror or exc}")]) from exc
    if len(raw) > MAX_POLICY_BYTES:
        raise PolicyError(source, [(DOCUMENT_PATH, f"the policy file is larger than {MAX_POLICY_BYTES} bytes")])
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise PolicyError(source, [(DOCUMENT_PATH, f"the policy file is not UTF-8 text: {exc}")]) from exc
    try:
        document = yaml.load(text, Loader=_PolicyLoader)  # noqa: S506 - _PolicyLoader is a SafeLoader
    except yaml.YAMLError as exc:
        raise PolicyError(source, [(DOCUMENT_PATH, _yaml_error_message(exc))]) from exc
    return parse_policy(document, source=source, base_dir=path.resolve().parent)


def apply_overrides(document: Mapping[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """A deep copy of a policy document with dotted keys replaced, e.g. `{"approval.mode": "always"}`.

    For tests, benchmarks and evaluations that need a variant of a shipped policy; the result is
    validated like any policy when parsed.
    """
    result = copy.deepcopy(dict(document))
    for dotted, value in overrides.items():
        node = result
        *parents, leaf = dotted.split(".")
        for key in parents:
            node = node[key]
        node[leaf] = value
    return result


def parse_policy(
    mapping: Any, source: str = "<memory>", *, base_dir: str | os.PathLike[str] | None = None
) -> Policy:
    """Validate an already-parsed policy document. Raises `PolicyError` listing every problem.

    `base_dir`, when given, is the folder relative `robot.description` paths resolve against
    (`load_policy` passes the policy file's folder); otherwise they are kept as written.
    """
    if not isinstance(mapping, Mapping):
        got = "an empty document" if mapping is None else f"a {type(mapping).__name__}"
        raise PolicyError(source, [(DOCUMENT_PATH, f"the policy must be a YAML mapping of sections (got {got})")])
    try:
        return Policy.model_validate(mapping, context={"base_dir": base_dir})
    except ValidationError as exc:
        raise PolicyError(source, validation_errors(exc, Policy)) from None


# ====================================================================== error reporting


def format_path(loc: Sequence[str | int]) -> str:
    """`('workspace', 'keep_out', 1, 'min')` → `workspace.keep_out[1].min` (`[key]` markers dropped)."""
    out = ""
    for part in loc:
        if part == "[key]":
            continue
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += f".{part}" if out else str(part)
    return out or DOCUMENT_PATH


def validation_errors(exc: ValidationError, root: type[BaseModel]) -> list[tuple[str, str]]:
    """Every error of `exc` as `(yaml_path, human message)`, in document order, without repeats.

    `root` is the model that was validated (used to list valid keys and describe missing ones).
    Reusable for any strict YAML config built the same way (e.g. the backend config).
    """
    errors: list[tuple[str, str]] = []
    for error in exc.errors(include_url=False):
        loc = tuple(error["loc"])
        rule = (error.get("ctx") or {}).get("error")
        if isinstance(rule, _RuleViolations):
            errors.extend((format_path(loc + relative), message) for relative, message in rule.violations)
        elif error["type"] == "missing" and loc and isinstance(loc[-1], int):
            # a fixed-length list (e.g. [x, y, z]) that is too short: one error for the list itself
            items = typing.get_args(_type_at(root, loc[:-1]))
            errors.append((format_path(loc[:-1]), f"must have exactly {len(items)} items (too few given)"))
        else:
            errors.append((format_path(loc), _humanise(error, root)))
    return list(dict.fromkeys(errors))  # drop repeats, keep order


def _show(value: Any) -> str:
    """A value as the YAML author wrote it (true/null/.nan), truncated."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and not math.isfinite(value):
        return ".nan" if math.isnan(value) else (".inf" if value > 0 else "-.inf")
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


_TYPE_WORDS = {
    "float_type": "a number",
    "float_parsing": "a number",
    "int_type": "an integer",
    "int_from_float": "an integer",
    "bool_type": "true or false",
    "string_type": "a string",
    "tuple_type": "a list",
    "list_type": "a list",
    "dict_type": "a mapping",
    "model_type": "a mapping",
    "model_attributes_type": "a mapping",
}


def _humanise(error: Mapping[str, Any], root: type[BaseModel]) -> str:
    """Turn a pydantic error into a message for the person editing the YAML file."""
    kind, loc, value = error["type"], tuple(error["loc"]), error.get("input")
    if kind == "missing":
        field = _field_at(root, loc)
        about = f" ({field.description})" if field is not None and field.description else ""
        return f"required key is missing{about}"
    if kind == "extra_forbidden":
        key = str(loc[-1])
        valid = _keys_at(root, loc[:-1])
        hint = difflib.get_close_matches(key, valid, n=1)
        did_you_mean = f"did you mean {hint[0]!r}? " if hint else ""
        return f"unknown key {key!r}; {did_you_mean}valid keys: {', '.join(valid)}"
    if kind in _TYPE_WORDS:
        return f"must be {_TYPE_WORDS[kind]} (got {_show(value)})"
    if kind == "finite_number":
        return f"must be a finite number (got {_show(value)})"
    if kind == "literal_error":
        expected = str(error["ctx"]["expected"])
        choice = "one of " if " or " in expected else ""
        return f"must be {choice}{expected} (got {_show(value)})"
    if kind == "string_pattern_mismatch":
        return f"must be a name without whitespace (got {_show(value)})"
    if kind == "string_too_short":
        return "must not be empty"
    if kind == "value_error":
        return str(error["msg"]).removeprefix("Value error, ")
    message = str(error["msg"]).replace("Input should", "must").replace("Tuple should", "must")
    message = message.replace("String should", "must").replace("Dictionary should", "must")
    if not isinstance(value, (Mapping, list, tuple)):
        message += f" (got {_show(value)})"
    return message


def _unwrap(annotation: Any) -> Any:
    """Strip `Annotated[...]` and `Optional[...]` to reach the underlying type."""
    while True:
        origin = typing.get_origin(annotation)
        if origin is Annotated:
            annotation = typing.get_args(annotation)[0]
        elif origin is Union or isinstance(annotation, types.UnionType):
            members = [arg for arg in typing.get_args(annotation) if arg is not type(None)]
            if len(members) != 1:
                return annotation
            annotation = members[0]
        else:
            return annotation


def _type_at(root: type[BaseModel], loc: Sequence[str | int]) -> Any:
    """The annotation of the value at `loc` inside a document validated by `root` (None when unknown)."""
    annotation: Any = root
    for part in loc:
        annotation = _unwrap(annotation)
        origin = typing.get_origin(annotation)
        if isinstance(annotation, type) and issubclass(annotation, BaseModel) and isinstance(part, str):
            field = annotation.model_fields.get(part)
            if field is None:
                return None
            annotation = field.annotation
        elif origin is tuple and isinstance(part, int):
            annotation = typing.get_args(annotation)[0]
        elif origin in (dict, Mapping):
            annotation = typing.get_args(annotation)[1]
        else:
            return None
    return _unwrap(annotation)


def _keys_at(root: type[BaseModel], loc: Sequence[str | int]) -> list[str]:
    model = _type_at(root, loc)
    if isinstance(model, type) and issubclass(model, BaseModel):
        return list(model.model_fields)
    return []


def _field_at(root: type[BaseModel], loc: Sequence[str | int]) -> Any:
    if not loc or not isinstance(loc[-1], str):
        return None
    model = _type_at(root, loc[:-1])
    if isinstance(model, type) and issubclass(model, BaseModel):
        return model.model_fields.get(loc[-1])
    return None


# ====================================================================== summary and schema


def _deg(value: float) -> float:
    return math.degrees(value)


def _box_text(lo: Sequence[float], hi: Sequence[float]) -> str:
    return "  ".join(f"{axis} [{a:+.3f}, {b:+.3f}]" for axis, a, b in zip("xyz", lo, hi)) + " m"


def summarize_policy(policy: Policy) -> str:
    """A human-readable, multi-line summary of what the policy allows (`armwarden check-policy`)."""
    robot, ws, motion, force = policy.robot, policy.workspace, policy.motion, policy.force
    lines = [
        f"Policy version {policy.version}",
        f"Robot: {robot.name}  description: {robot.description}",
        f"  base frame: {robot.base_frame}  TCP frame: {robot.tcp_frame}",
        f"  joints ({len(robot.joint_names)}):",
    ]
    width = max(len(name) for name in (*robot.joint_names, "joint"))
    lines.append(
        f"    {'joint':<{width}}  {'position [rad]':<20}  {'position [deg]':<18}  {'vel [rad/s]':>11}"
        f"  {'acc [rad/s²]':>12}  {'home [rad]':>10}"
    )
    for name, home in zip(robot.joint_names, robot.home_joint_positions):
        lim = robot.joint_limits[name]
        lines.append(
            f"    {name:<{width}}  [{lim.min:+8.4f}, {lim.max:+8.4f}]  [{_deg(lim.min):+7.1f}, {_deg(lim.max):+7.1f}]"
            f"  {lim.max_velocity:11.3f}  {lim.max_acceleration:12.3f}  {home:+10.4f}"
        )
    lines.append(f"Tool groups: {', '.join(policy.tools.enabled)}  ({len(policy.enabled_tools)} tools)")
    for group in policy.tools.enabled:
        lines.append(f"  {group}: {', '.join(TOOL_GROUPS[group])}")
    lines.append(f"Workspace box ({robot.base_frame}): {_box_text(ws.box.min, ws.box.max)}")
    if ws.keep_out:
        lines.append(f"Keep-out zones ({len(ws.keep_out)}):")
        lines.extend(f"  {zone.name}: {_box_text(zone.min, zone.max)}" for zone in ws.keep_out)
    else:
        lines.append("Keep-out zones: none")
    checked = "every moving link" if ws.check_links is None else ", ".join(ws.check_links) or "none"
    lines.append(
        f"  link padding {ws.link_padding_m:g} m; self-collision {'on' if ws.self_collision else 'OFF'}; "
        f"checked links: {checked}"
    )
    soft = (
        f"approval above {motion.soft_joint_step_rad:g} rad" if motion.soft_joint_step_rad is not None
        else "no soft threshold"
    )
    lines += [
        f"Motion: velocity scaling ≤ {motion.max_velocity_scaling:g} (default {motion.default_velocity_scaling:g}), "
        f"acceleration scaling ≤ {motion.max_acceleration_scaling:g} (default {motion.default_acceleration_scaling:g})",
        f"  joint travel per plan ≤ {motion.max_joint_step_rad:g} rad ({soft}); "
        f"TCP path ≤ {motion.max_cartesian_step_m:g} m; plan TTL {motion.plan_ttl_s:g} s",
        f"  limit margin {motion.joint_limit_margin_rad:g} rad; start tolerance {motion.start_tolerance_rad:g} rad; "
        f"check resolution {motion.check_resolution_rad:g} rad; sweep resolution {motion.sweep_resolution_m:g} m",
        f"Force: ≤ {force.max_contact_force_n:g} N, ≤ {force.max_contact_torque_nm:g} N·m, "
        f"monitored at {force.monitor_rate_hz:g} Hz, wrench older than {force.wrench_timeout_s:g} s aborts; "
        + ("wrench REQUIRED" if force.require_wrench else "wrench NOT required (force may be unenforced)"),
    ]
    if policy.gripper is None:
        lines.append("Gripper: none")
    else:
        g = policy.gripper
        lines.append(
            f"Gripper: width {g.min_width_m:g}..{g.max_width_m:g} m, force ≤ {g.max_grasp_force_n:g} N, "
            f"speed ≤ {g.max_speed_mps:g} m/s"
        )
    lines += [
        f"Controllers allowed: {', '.join(policy.controllers.allowlist) or 'none'}",
        f"Cameras allowed: {', '.join(policy.perception.cameras) or 'none'} "
        f"(max image width {policy.perception.max_image_width} px)",
    ]
    rl = policy.rate_limits
    overrides = ", ".join(f"{tool} {rate}/min" for tool, rate in rl.per_tool.items()) or "none"
    lines.append(
        f"Rate limits: {rl.global_per_minute}/min global, {rl.default_per_minute}/min per tool; "
        f"overrides: {overrides}; exempt: {', '.join(RATE_LIMIT_EXEMPT_TOOLS)}"
    )
    ap = policy.approval
    lines.append(
        f"Approval: mode {ap.mode}; required for {', '.join(ap.require_for)}; "
        f"client without elicitation: {ap.on_client_without_elicitation}"
    )
    lines.append("Dry run: ON (nothing actuates)" if policy.dry_run else "Dry run: off (execution moves the robot)")
    return "\n".join(lines)


def policy_json_schema() -> dict[str, Any]:
    """JSON schema of the policy file (validation mode), e.g. to generate docs/policy.md."""
    return Policy.model_json_schema(mode="validation")
