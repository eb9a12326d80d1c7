"""Tests for armwarden.policy: strict validation, exact error paths, normalisation, loading."""

from __future__ import annotations

import copy
import math
import pickle
import re
import string
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Union

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import BaseModel, ValidationError

from armwarden.core.errors import ConfigurationError, PolicyError
from armwarden.policy import (
    ALL_TOOLS,
    APPROVAL_ACTIONS,
    DOCUMENT_PATH,
    MAX_POLICY_BYTES,
    RATE_LIMIT_EXEMPT_TOOLS,
    TOOL_GROUPS,
    Policy,
    bundled_policy,
    load_policy,
    parse_policy,
    policy_json_schema,
    summarize_policy,
)

FR3_YAML = bundled_policy("fr3")
READONLY_YAML = bundled_policy("readonly")
NAN, INF = float("nan"), float("inf")
FIRST_JOINT = "fr3_joint1"

HYPOTHESIS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


# ====================================================================== helpers and fixtures


def full_mapping() -> dict[str, Any]:
    """A fresh copy of the shipped FR3 policy document: valid, and every key present."""
    return copy.deepcopy(_FR3_DOCUMENT)


_FR3_DOCUMENT = yaml.safe_load(FR3_YAML.read_text(encoding="utf-8"))


@pytest.fixture
def doc() -> dict[str, Any]:
    return full_mapping()


def _parts(path: str) -> list[str | int]:
    """`workspace.keep_out[1].min` → ['workspace', 'keep_out', 1, 'min']."""
    return [int(index) if index else key for key, index in re.findall(r"([^.\[\]]+)|\[(\d+)\]", path)]


def set_at(mapping: dict[str, Any], path: str, value: Any) -> dict[str, Any]:
    *parents, last = _parts(path)
    node: Any = mapping
    for part in parents:
        node = node[part]
    node[last] = value
    return mapping


def delete_at(mapping: dict[str, Any], path: str) -> dict[str, Any]:
    *parents, last = _parts(path)
    node: Any = mapping
    for part in parents:
        node = node[part]
    del node[last]
    return mapping


def errors_of(mapping: Any) -> list[tuple[str, str]]:
    with pytest.raises(PolicyError) as caught:
        parse_policy(mapping)
    return caught.value.errors


def paths_of(mapping: Any) -> list[str]:
    return [path for path, _ in errors_of(mapping)]


def _unwrap(annotation: Any) -> Any:
    while True:
        origin = typing.get_origin(annotation)
        if origin is typing.Annotated:
            annotation = typing.get_args(annotation)[0]
        elif origin is Union or isinstance(annotation, types.UnionType):
            annotation = next(a for a in typing.get_args(annotation) if a is not type(None))
        else:
            return annotation


def _is_model(annotation: Any) -> bool:
    return isinstance(annotation, type) and issubclass(annotation, BaseModel)


def walk_fields(model: type[BaseModel] = Policy, prefix: str = "") -> tuple[list[str], list[str]]:
    """(every field path, every mapping location) of the policy format, with sample keys/indices."""
    fields: list[str] = []
    containers: list[str] = [prefix]
    for name, info in model.model_fields.items():
        path = f"{prefix}.{name}" if prefix else name
        fields.append(path)
        annotation = _unwrap(info.annotation)
        origin, args = typing.get_origin(annotation), typing.get_args(annotation)
        if _is_model(annotation):
            sub = (annotation, path)
        elif origin is tuple and args and _is_model(_unwrap(args[0])):
            sub = (_unwrap(args[0]), f"{path}[0]")
        elif origin in (dict, Mapping) and _is_model(_unwrap(args[1])):
            sub = (_unwrap(args[1]), f"{path}.{FIRST_JOINT}")
        else:
            continue
        sub_fields, sub_containers = walk_fields(*sub)
        fields += sub_fields
        containers += sub_containers
    return fields, containers


ALL_FIELD_PATHS, ALL_MAPPING_PATHS = walk_fields()


# ====================================================================== the bad-value table


def _floats(path: str, *extra: Any, nullable: bool = False) -> list[tuple[str, Any, str]]:
    """Non-finite, wrong-typed (string, bool) and extra out-of-range values for a float field."""
    values: list[Any] = [NAN, INF, -INF, "0.5", True, [1.0], *extra]
    if not nullable:
        values.append(None)
    return [(path, value, path) for value in values]


def _ints(path: str, *extra: Any) -> list[tuple[str, Any, str]]:
    return [(path, value, path) for value in (1.5, NAN, "10", True, None, *extra)]


def _bools(path: str) -> list[tuple[str, Any, str]]:
    return [(path, value, path) for value in ("yes", 1, 0.0, None)]


def _names(path: str) -> list[tuple[str, Any, str]]:
    return [(path, value, path) for value in ("", "two words", 5, None)]


def _name_lists(path: str, *, nullable: bool = False) -> list[tuple[str, Any, str]]:
    rows = [(path, "not_a_list", path), (path, ["a", "a"], path), (path, [""], f"{path}[0]"), (path, [3], f"{path}[0]")]
    if not nullable:
        rows.append((path, None, path))
    return rows


def _vectors(path: str) -> list[tuple[str, Any, str]]:
    return [
        (path, [0.0, 0.0], path),
        (path, [0.0, 0.0, 0.0, 0.0], path),
        (path, "0 0 0", path),
        (path, None, path),
        (path, [NAN, 0.0, 0.0], f"{path}[0]"),
        (path, [0.0, INF, 0.0], f"{path}[1]"),
        (path, [0.0, 0.0, "1"], f"{path}[2]"),
    ]


def _sections(path: str) -> list[tuple[str, Any, str]]:
    return [(path, value, path) for value in ("text", 5, [1, 2])]


JOINT = f"robot.joint_limits.{FIRST_JOINT}"
#: the bundled policy's per-joint external-torque limits
TORQUE_LIMITS = {f"fr3_joint{i}": 5.0 for i in range(1, 8)}
KEEP_OUT = "workspace.keep_out[0]"

BAD_VALUES: list[tuple[str, Any, str]] = [
    *[("version", value, "version") for value in (2, 0, "1", True, 1.0, None)],
    *_sections("robot"),
    *_names("robot.name"),
    *[("robot.description", v, "robot.description") for v in ("", 5, None, "builtin:", "builtin:two words", " a.urdf")],
    *[("robot.collision_geometry", v, "robot.collision_geometry") for v in ("", 5, None, "builtin:", " a.yaml")],
    *_names("robot.base_frame"),
    *_names("robot.tcp_frame"),
    *_name_lists("robot.joint_names"),
    ("robot.joint_names", [], "robot.joint_names"),
    *[("robot.joint_limits", value, "robot.joint_limits") for value in ("text", [1], None)],
    *_sections(JOINT),
    *_floats(f"{JOINT}.min"),
    *_floats(f"{JOINT}.max"),
    *_floats(f"{JOINT}.max_velocity", 0, -1.0, 150.0),
    *_floats(f"{JOINT}.max_acceleration", 0, -10, 573.0),
    ("robot.home_joint_positions", "ready", "robot.home_joint_positions"),
    ("robot.home_joint_positions", None, "robot.home_joint_positions"),
    ("robot.home_joint_positions", [NAN, 0, 0, -2, 0, 1.5, 0], "robot.home_joint_positions[0]"),
    ("robot.home_joint_positions", [0, 0, 0, -2, 0, 1.5, "0"], "robot.home_joint_positions[6]"),
    *_sections("tools"),
    ("tools.enabled", "motion", "tools.enabled"),
    ("tools.enabled", None, "tools.enabled"),
    ("tools.enabled", ["flying"], "tools.enabled[0]"),
    ("tools.enabled", ["safety", 1], "tools.enabled[1]"),
    *_sections("workspace"),
    *_sections("workspace.box"),
    *_vectors("workspace.box.min"),
    ("workspace.box.min", [-5.01, 0.0, 0.0], "workspace.box.min[0]"),
    *_vectors("workspace.box.max"),
    ("workspace.keep_out", "monitor", "workspace.keep_out"),
    ("workspace.keep_out", [5], "workspace.keep_out[0]"),
    *_sections(KEEP_OUT),
    *_names(f"{KEEP_OUT}.name"),
    *_vectors(f"{KEEP_OUT}.min"),
    *_vectors(f"{KEEP_OUT}.max"),
    (f"{KEEP_OUT}.max", [0.7, 0.65, 45.0], f"{KEEP_OUT}.max[2]"),
    *_floats("workspace.link_padding_m", -0.01),
    ("workspace.padding_by_link_m", {"fr3_hand": -0.01}, "workspace.padding_by_link_m.fr3_hand"),
    ("workspace.padding_by_link_m", {"fr3_hand": 0.6}, "workspace.padding_by_link_m.fr3_hand"),
    ("workspace.padding_by_link_m", {"fr3_hand": "1"}, "workspace.padding_by_link_m.fr3_hand"),
    ("workspace.padding_by_link_m", [0.01], "workspace.padding_by_link_m"),
    *_name_lists("workspace.check_links", nullable=True),
    ("workspace.check_links", [], "workspace.check_links"),  # would silently check no link
    *_bools("workspace.self_collision"),
    *_sections("motion"),
    *_floats("motion.max_velocity_scaling", 0, -0.1, 1.01),
    *_floats("motion.max_acceleration_scaling", 0, -0.1, 1.5),
    *_floats("motion.default_velocity_scaling", 0, -0.1, 2),
    *_floats("motion.default_acceleration_scaling", 0, -0.1, 2),
    *_floats("motion.max_joint_step_rad", 0, -1.5, 3.2),
    *_floats("motion.soft_joint_step_rad", 0, -0.8, nullable=True),
    *_floats("motion.max_cartesian_step_m", 0, -0.5, 5.1),
    *_floats("motion.plan_ttl_s", 0, -1, 3600.5),
    *_floats("motion.joint_limit_margin_rad", -0.01),
    *_floats("motion.start_tolerance_rad", 0, -0.01, 0.11, 10),
    *_floats("motion.check_resolution_rad", 0, -0.02, 0.0009, 0.11),
    *_floats("motion.sweep_resolution_m", 0, -0.01, 0.051, 0.0009),
    *_floats("motion.planning_time_s", 0, -0.5, 2.01, 60),
    *_sections("force"),
    *_floats("force.max_contact_force_n", 0, -30, 150.1),
    *_floats("force.max_contact_torque_nm", 0, -10, 30.1),
    *_floats("force.monitor_rate_hz", 0, -200, 5001, 9.9, 0.001),
    *_bools("force.require_wrench"),
    *_floats("force.wrench_timeout_s", 0, -0.1, 0.51, 2.5),
    *[("force.source", value, "force.source") for value in ("both", "SENSOR", 1, None, True)],
    *_sections("force.joint_torques"),
    *[("force.joint_torques.max_external_torque_nm", value, "force.joint_torques.max_external_torque_nm")
      for value in ("10", [10.0], None)],
    *[("force.joint_torques.max_external_torque_nm", {**TORQUE_LIMITS, FIRST_JOINT: value},
       f"force.joint_torques.max_external_torque_nm.{FIRST_JOINT}") for value in (0, -1.0, 100.5, NAN, INF, "5", True)],
    *[(f"force.joint_torques.{name}", value, f"force.joint_torques.{name}")
      for name in ("friction_coulomb_nm", "friction_viscous_nms", "rotor_inertia_kgm2") for value in ("1", [1.0], None)],
    *[(f"force.joint_torques.{name}", {FIRST_JOINT: value}, f"force.joint_torques.{name}.{FIRST_JOINT}")
      for name in ("friction_coulomb_nm", "friction_viscous_nms") for value in (-0.1, 50.5, NAN, "1", True)],
    *[("force.joint_torques.rotor_inertia_kgm2", {FIRST_JOINT: value},
       f"force.joint_torques.rotor_inertia_kgm2.{FIRST_JOINT}") for value in (-0.1, 5.5, NAN, "1", True)],
    *_floats("force.joint_torques.observer_gain_per_s", 0, 4.9, 501),
    *_floats("force.joint_torques.max_tcp_force_n", 0, -1.0, 30.5, nullable=True),  # 30.5: over max_contact_force_n
    *_floats("force.joint_torques.payload_kg", -0.1, 50.1),
    *_vectors("force.joint_torques.payload_com_m"),
    ("force.joint_torques.payload_com_m", [0.0, 0.0, 0.6], "force.joint_torques.payload_com_m[2]"),
    *_sections("gripper"),
    *_floats("gripper.min_width_m", -0.01),
    *_floats("gripper.max_width_m", 0, -0.08, 0.51),
    *_floats("gripper.max_grasp_force_n", 0, -70, 250.1),
    *_floats("gripper.max_speed_mps", 0, -0.1, 0.51),
    *_sections("controllers"),
    *_name_lists("controllers.allowlist"),
    *_sections("perception"),
    *_name_lists("perception.cameras"),
    *_ints("perception.max_image_width", 15, 4097, 0, -640),
    *_sections("rate_limits"),
    *_ints("rate_limits.global_per_minute", 0, -1),
    *_ints("rate_limits.default_per_minute", 0, -1),
    ("rate_limits.per_tool", "execute_plan: 20", "rate_limits.per_tool"),
    ("rate_limits.per_tool", None, "rate_limits.per_tool"),
    ("rate_limits.per_tool", {"launch_missiles": 5}, "rate_limits.per_tool.launch_missiles"),
    ("rate_limits.per_tool", {"estop": 5}, "rate_limits.per_tool.estop"),
    ("rate_limits.per_tool", {"execute_plan": 0}, "rate_limits.per_tool.execute_plan"),
    ("rate_limits.per_tool", {"execute_plan": 2.5}, "rate_limits.per_tool.execute_plan"),
    ("rate_limits.per_tool", {"execute_plan": NAN}, "rate_limits.per_tool.execute_plan"),
    *_sections("approval"),
    *[("approval.mode", value, "approval.mode") for value in ("sometimes", "ALWAYS", 1, None, True)],
    *[
        ("approval.on_client_without_elicitation", value, "approval.on_client_without_elicitation")
        for value in ("ask", "", 0, None, False)
    ],
    *[("approval.channel", value, "approval.channel") for value in ("console", "URL", 1, None, True)],
    ("approval.require_for", "execute", "approval.require_for"),
    ("approval.require_for", None, "approval.require_for"),
    ("approval.require_for", ["launch"], "approval.require_for[0]"),
    ("approval.require_for", ["execute", 3], "approval.require_for[1]"),
    *_bools("approval.allow_self_approval"),
    *_bools("dry_run"),
]


def _row_id(row: tuple[str, Any, str]) -> str:
    path, value, _ = row
    return f"{path}={value!r}"


# ====================================================================== per-field validation


def test_bad_value_table_covers_every_field_of_the_policy_format() -> None:
    covered = {path for path, _, _ in BAD_VALUES}
    assert set(ALL_FIELD_PATHS) - covered == set()


@pytest.mark.parametrize("row", BAD_VALUES, ids=_row_id)
def test_bad_value_is_reported_at_exactly_its_field(doc: dict[str, Any], row: tuple[str, Any, str]) -> None:
    path, value, expected_path = row
    errors = errors_of(set_at(doc, path, value))
    assert [p for p, _ in errors] == [expected_path], errors
    assert all(message.strip() for _, message in errors)


@pytest.mark.parametrize("path", ALL_FIELD_PATHS)
def test_removed_key_falls_back_to_its_default_or_is_reported_at_its_path(doc: dict[str, Any], path: str) -> None:
    delete_at(doc, path)
    errors = None
    try:
        parse_policy(doc)
    except PolicyError as exc:
        errors = exc.errors
    if errors is not None:
        assert [p for p, _ in errors] == [path], errors


@pytest.mark.parametrize(
    "path",
    [
        "version",
        "robot",
        "robot.name",
        "robot.description",
        "robot.base_frame",
        "robot.tcp_frame",
        "robot.joint_names",
        "robot.joint_limits",
        "robot.home_joint_positions",
        "workspace",
        "workspace.box",
        "workspace.box.min",
        f"{KEEP_OUT}.name",
        "motion",
        "motion.max_velocity_scaling",
        "motion.max_acceleration_scaling",
        "motion.max_joint_step_rad",
        "motion.max_cartesian_step_m",
        "force",
        "force.max_contact_force_n",
        "force.max_contact_torque_nm",
        "gripper.max_width_m",
    ],
)
def test_key_without_default_is_required(doc: dict[str, Any], path: str) -> None:
    assert paths_of(delete_at(doc, path)) == [path]


def test_sections_with_defaults_may_be_omitted(doc: dict[str, Any]) -> None:
    for section in ("tools", "gripper", "controllers", "perception", "rate_limits", "approval", "dry_run"):
        del doc[section]
    policy = parse_policy(doc)
    assert policy.tools.enabled == ("introspect", "safety")
    assert policy.gripper is None
    assert policy.controllers.allowlist == ()
    assert policy.perception.cameras == () and policy.perception.max_image_width == 640
    assert (policy.rate_limits.global_per_minute, policy.rate_limits.default_per_minute) == (120, 60)
    assert dict(policy.rate_limits.per_tool) == {}
    assert policy.approval.mode == "outside_envelope"
    assert policy.approval.on_client_without_elicitation == "deny"
    assert policy.approval.require_for == APPROVAL_ACTIONS
    assert policy.dry_run is False


def test_field_defaults_match_the_documented_values() -> None:
    policy = load_policy(READONLY_YAML)
    motion, force, ws = policy.motion, policy.force, policy.workspace
    assert (motion.plan_ttl_s, motion.joint_limit_margin_rad, motion.start_tolerance_rad) == (120, 0.05, 0.01)
    assert (motion.check_resolution_rad, motion.sweep_resolution_m, motion.soft_joint_step_rad) == (0.02, 0.01, None)
    assert motion.planning_time_s == 0.5
    assert (force.monitor_rate_hz, force.require_wrench, force.wrench_timeout_s) == (200, True, 0.1)
    assert (force.source, force.joint_torques) == ("auto", None)
    assert (ws.link_padding_m, ws.check_links, ws.self_collision) == (0.01, None, True)


# ====================================================================== unknown keys

MAPPING_LOCATIONS = [
    "",
    "robot",
    JOINT,
    "tools",
    "workspace",
    "workspace.box",
    KEEP_OUT,
    "motion",
    "force",
    "force.joint_torques",
    "gripper",
    "controllers",
    "perception",
    "rate_limits",
    "approval",
]


def test_unknown_key_locations_cover_every_mapping_of_the_format() -> None:
    assert set(ALL_MAPPING_PATHS) == set(MAPPING_LOCATIONS)


@pytest.mark.parametrize("location", MAPPING_LOCATIONS, ids=lambda loc: loc or "<top>")
def test_unknown_key_is_rejected_at_every_level(doc: dict[str, Any], location: str) -> None:
    path = f"{location}.max_velocity_scalling" if location else "max_velocity_scalling"
    errors = errors_of(set_at(doc, path, 0.5))
    assert [p for p, _ in errors] == [path]
    assert "unknown key 'max_velocity_scalling'" in errors[0][1]
    assert "valid keys:" in errors[0][1]


def test_unknown_key_message_suggests_the_closest_valid_key(doc: dict[str, Any]) -> None:
    doc["motion"]["max_velocity_scalling"] = doc["motion"].pop("max_velocity_scaling")
    errors = dict(errors_of(doc))
    assert "did you mean 'max_velocity_scaling'?" in errors["motion.max_velocity_scalling"]


@HYPOTHESIS
@given(
    location=st.sampled_from(MAPPING_LOCATIONS),
    key=st.text(alphabet=string.ascii_letters + string.digits + "_-", min_size=1, max_size=20),
)
def test_any_unknown_key_name_is_rejected_with_its_path(location: str, key: str) -> None:
    doc = full_mapping()
    node: Any = doc
    for part in _parts(location):
        node = node[part]
    if key in node:
        return
    path = f"{location}.{key}" if location else key
    assert paths_of(set_at(doc, path, 1)) == [path]


# ====================================================================== cross-field rules


def test_joint_limits_missing_a_joint_is_reported_with_its_name(doc: dict[str, Any]) -> None:
    del doc["robot"]["joint_limits"]["fr3_joint7"]
    errors = errors_of(doc)
    assert [p for p, _ in errors] == ["robot.joint_limits"]
    assert "fr3_joint7" in errors[0][1] and "no limits" in errors[0][1]


def test_joint_limits_for_unknown_joint_are_reported_with_its_name(doc: dict[str, Any]) -> None:
    doc["robot"]["joint_limits"]["fr3_joint8"] = dict(doc["robot"]["joint_limits"]["fr3_joint1"])
    errors = errors_of(doc)
    assert [p for p, _ in errors] == ["robot.joint_limits"]
    assert "fr3_joint8" in errors[0][1] and "not in joint_names" in errors[0][1]


def test_joint_names_must_be_unique(doc: dict[str, Any]) -> None:
    doc["robot"]["joint_names"][6] = "fr3_joint1"
    errors = errors_of(doc)
    assert [p for p, _ in errors] == ["robot.joint_names"]
    assert "fr3_joint1" in errors[0][1]


def test_joint_limits_are_stored_in_joint_name_order(doc: dict[str, Any]) -> None:
    limits = doc["robot"]["joint_limits"]
    doc["robot"]["joint_limits"] = dict(reversed(list(limits.items())))
    policy = parse_policy(doc)
    assert tuple(policy.robot.joint_limits) == policy.robot.joint_names
    assert policy.robot.lower_limits[3] == -3.0421 and policy.robot.upper_limits[5] == 4.5169


def test_joint_min_must_be_below_max(doc: dict[str, Any]) -> None:
    set_at(doc, "robot.joint_limits.fr3_joint2.min", 1.7837)
    errors = errors_of(doc)
    assert [p for p, _ in errors] == ["robot.joint_limits.fr3_joint2.min"]
    assert "1.7837" in errors[0][1]


def test_home_outside_limits_names_joint_value_and_limits(doc: dict[str, Any]) -> None:
    doc["robot"]["home_joint_positions"][3] = 0.0  # q = 0 is outside FR3 joint 4's range
    errors = errors_of(doc)
    assert [p for p, _ in errors] == ["robot.home_joint_positions[3]"]
    message = errors[0][1]
    assert "fr3_joint4" in message and "0 rad" in message and "-3.0421" in message and "-0.1518" in message


def test_home_every_joint_outside_limits_is_reported(doc: dict[str, Any]) -> None:
    doc["robot"]["home_joint_positions"] = [0.0] * 7  # joints 4 and 6 out of range
    assert paths_of(doc) == ["robot.home_joint_positions[3]", "robot.home_joint_positions[5]"]


def test_home_needs_one_value_per_joint(doc: dict[str, Any]) -> None:
    doc["robot"]["home_joint_positions"].pop()
    errors = errors_of(doc)
    assert [p for p, _ in errors] == ["robot.home_joint_positions"]
    assert "6 value(s)" in errors[0][1] and "7" in errors[0][1]


@HYPOTHESIS
@given(joint=st.integers(0, 6), value=st.floats(-5, 5))
def test_home_is_accepted_exactly_when_within_limits(joint: int, value: float) -> None:
    doc = full_mapping()
    doc["robot"]["home_joint_positions"][joint] = value
    limits = doc["robot"]["joint_limits"][f"fr3_joint{joint + 1}"]
    if limits["min"] <= value <= limits["max"]:
        assert parse_policy(doc).robot.home_joint_positions[joint] == value
    else:
        assert paths_of(doc) == [f"robot.home_joint_positions[{joint}]"]


@pytest.mark.parametrize(
    ("default_key", "cap_key"),
    [
        ("default_velocity_scaling", "max_velocity_scaling"),
        ("default_acceleration_scaling", "max_acceleration_scaling"),
    ],
)
def test_default_scaling_above_its_cap_is_rejected(doc: dict[str, Any], default_key: str, cap_key: str) -> None:
    doc["motion"][default_key] = 0.5
    doc["motion"][cap_key] = 0.3
    errors = errors_of(doc)
    assert [p for p, _ in errors] == [f"motion.{default_key}"]
    assert "0.5" in errors[0][1] and "0.3" in errors[0][1]


def test_omitted_default_scaling_follows_a_cap_below_one_tenth(doc: dict[str, Any]) -> None:
    del doc["motion"]["default_velocity_scaling"], doc["motion"]["default_acceleration_scaling"]
    doc["motion"]["max_velocity_scaling"] = 0.05
    doc["motion"]["max_acceleration_scaling"] = 0.5
    motion = parse_policy(doc).motion
    assert motion.default_velocity_scaling == 0.05
    assert motion.default_acceleration_scaling == 0.1


@HYPOTHESIS
@given(cap=st.floats(allow_nan=False, allow_infinity=False, min_value=-2, max_value=2))
def test_velocity_cap_is_accepted_exactly_in_zero_to_one(cap: float) -> None:
    doc = full_mapping()
    del doc["motion"]["default_velocity_scaling"]
    doc["motion"]["max_velocity_scaling"] = cap
    if 0 < cap <= 1:
        motion = parse_policy(doc).motion
        assert motion.default_velocity_scaling == min(0.1, cap) <= motion.max_velocity_scaling
    else:
        assert paths_of(doc) == ["motion.max_velocity_scaling"]


def test_soft_joint_step_above_hard_step_is_rejected(doc: dict[str, Any]) -> None:
    doc["motion"]["soft_joint_step_rad"] = 1.6
    errors = errors_of(doc)
    assert [p for p, _ in errors] == ["motion.soft_joint_step_rad"]
    assert "1.6" in errors[0][1] and "1.5" in errors[0][1]


def test_soft_joint_step_may_be_null(doc: dict[str, Any]) -> None:
    doc["motion"]["soft_joint_step_rad"] = None
    assert parse_policy(doc).motion.soft_joint_step_rad is None


def test_both_motion_rules_broken_gives_both_errors(doc: dict[str, Any]) -> None:
    doc["motion"].update(default_velocity_scaling=0.9, soft_joint_step_rad=2.0)
    assert paths_of(doc) == ["motion.default_velocity_scaling", "motion.soft_joint_step_rad"]


def test_limit_margin_that_leaves_no_room_is_rejected(doc: dict[str, Any]) -> None:
    doc["motion"]["joint_limit_margin_rad"] = 1.5  # joint 4 spans only 2.89 rad
    errors = errors_of(doc)
    assert [p for p, _ in errors] == ["motion.joint_limit_margin_rad"]
    assert "fr3_joint4" in errors[0][1]


def test_workspace_box_min_not_below_max_is_rejected(doc: dict[str, Any]) -> None:
    doc["workspace"]["box"]["min"][2] = 1.15
    errors = errors_of(doc)
    assert [p for p, _ in errors] == ["workspace.box.min"]
    assert "z" in errors[0][1]


def test_keep_out_min_not_below_max_is_rejected(doc: dict[str, Any]) -> None:
    doc["workspace"]["keep_out"][1]["min"][0] = 0.80
    assert paths_of(doc) == ["workspace.keep_out[1].min"]


@HYPOTHESIS
@given(
    lo=st.tuples(*[st.floats(-3, 3)] * 3),
    hi=st.tuples(*[st.floats(-3, 3)] * 3),
)
def test_box_is_accepted_exactly_when_min_below_max_on_every_axis(lo: tuple, hi: tuple) -> None:
    doc = full_mapping()
    doc["workspace"]["box"] = {"min": list(lo), "max": list(hi)}
    doc["workspace"]["keep_out"] = []  # zones outside a random box are a separate rule
    if all(a < b for a, b in zip(lo, hi, strict=True)):
        box = parse_policy(doc).workspace.box
        assert (box.min, box.max) == (lo, hi)
    else:
        assert paths_of(doc) == ["workspace.box.min"]


def test_keep_out_names_must_be_unique(doc: dict[str, Any]) -> None:
    doc["workspace"]["keep_out"][1]["name"] = "monitor"
    errors = errors_of(doc)
    assert [p for p, _ in errors] == ["workspace.keep_out[1].name"]
    assert "monitor" in errors[0][1]


def test_gripper_section_required_when_gripper_group_enabled(doc: dict[str, Any]) -> None:
    doc["gripper"] = None
    errors = errors_of(doc)
    assert [p for p, _ in errors] == ["gripper"]
    assert "gripper tool group" in errors[0][1]


def test_gripper_section_optional_without_gripper_group(doc: dict[str, Any]) -> None:
    doc["gripper"] = None
    doc["tools"]["enabled"] = ["introspect", "motion"]
    assert parse_policy(doc).gripper is None


def test_gripper_max_width_must_exceed_min_width(doc: dict[str, Any]) -> None:
    doc["gripper"]["min_width_m"] = 0.08
    assert paths_of(doc) == ["gripper.max_width_m"]


def test_safety_group_is_always_added(doc: dict[str, Any]) -> None:
    doc["tools"]["enabled"] = ["motion", "introspect"]
    policy = parse_policy(doc)
    assert policy.tools.enabled == ("introspect", "motion", "safety")
    assert "estop" in policy.enabled_tools and "camera_snapshot" not in policy.enabled_tools


def test_empty_tool_list_still_has_safety(doc: dict[str, Any]) -> None:
    doc["tools"]["enabled"] = []
    assert parse_policy(doc).tools.enabled == ("safety",)


@HYPOTHESIS
@given(groups=st.lists(st.sampled_from(list(TOOL_GROUPS)), max_size=8))
def test_enabled_groups_normalise_to_canonical_order_with_safety(groups: list[str]) -> None:
    doc = full_mapping()
    doc["tools"]["enabled"] = groups
    if "gripper" not in groups:
        doc["gripper"] = None
    enabled = parse_policy(doc).tools.enabled
    assert set(enabled) == set(groups) | {"safety"}
    assert list(enabled) == [g for g in TOOL_GROUPS if g in enabled]


def test_reset_estop_is_always_added_back_to_require_for(doc: dict[str, Any]) -> None:
    doc["approval"]["require_for"] = ["execute"]
    assert parse_policy(doc).approval.require_for == ("execute", "reset_estop")


@HYPOTHESIS
@given(actions=st.lists(st.sampled_from(APPROVAL_ACTIONS), max_size=8))
def test_require_for_always_contains_reset_estop(actions: list[str]) -> None:
    doc = full_mapping()
    doc["approval"]["require_for"] = actions
    require_for = parse_policy(doc).approval.require_for
    assert set(require_for) == set(actions) | {"reset_estop"}
    assert list(require_for) == [a for a in APPROVAL_ACTIONS if a in require_for]


@HYPOTHESIS
@given(name=st.text(alphabet=string.ascii_lowercase + "_", min_size=1, max_size=25), rate=st.integers(1, 10_000))
def test_per_tool_accepts_exactly_the_throttled_tool_names(name: str, rate: int) -> None:
    doc = full_mapping()
    doc["rate_limits"]["per_tool"] = {name: rate}
    if name in ALL_TOOLS and name not in RATE_LIMIT_EXEMPT_TOOLS:
        assert parse_policy(doc).rate_limits.limit_for(name) == rate
    else:
        assert paths_of(doc) == [f"rate_limits.per_tool.{name}"]


def test_unknown_per_tool_name_suggests_the_real_one(doc: dict[str, Any]) -> None:
    doc["rate_limits"]["per_tool"] = {"execute_plans": 5}
    (message,) = [m for _, m in errors_of(doc)]
    assert "unknown tool name 'execute_plans'" in message and "did you mean 'execute_plan'?" in message


def test_limit_for_tool_without_override_is_the_default() -> None:
    policy = load_policy(FR3_YAML)
    assert policy.rate_limits.limit_for("execute_plan") == 20
    assert policy.rate_limits.limit_for("get_robot_state") == 60


# ====================================================================== values that would switch a protection off

#: (YAML path, a value that would quietly disable what the field protects, text the message must
#: carry). Each is refused with its path; the value just inside the bound is accepted.
DISABLING_VALUES: list[tuple[str, Any, Any, str]] = [
    (f"{JOINT}.max_velocity", 150.0, 6.2832, "at most 6.2832"),  # °/s written as rad/s
    (f"{JOINT}.max_acceleration", 573.0, 50, "at most 50"),
    ("workspace.box.max", [85, 70, 115], [5, 5, 5], "at most 5"),  # centimetres written as metres
    (f"{KEEP_OUT}.min", [45, 40, 0], [-5, -5, -5], "at most 5"),
    ("motion.max_joint_step_rad", 100.0, 3.1416, "at most 3.1416"),
    ("motion.max_cartesian_step_m", 1000.0, 5.0, "at most 5"),
    ("motion.start_tolerance_rad", 10.0, 0.1, "at most 0.1"),  # would switch the start check off
    ("motion.check_resolution_rad", 10.0, 0.1, "at most 0.1"),
    ("motion.check_resolution_rad", 1e-9, 0.001, "at least 0.001"),  # planning would never finish
    ("motion.sweep_resolution_m", 1e-9, 0.001, "at least 0.001"),
    ("force.max_contact_force_n", 10_000.0, 150, "at most 150"),
    ("force.max_contact_torque_nm", 1000.0, 30, "at most 30"),
    ("force.monitor_rate_hz", 0.001, 10, "at least 10"),  # the 999 N run: one poll per 1000 s
    ("force.wrench_timeout_s", 2.0, 0.5, "at most 0.5"),
    ("gripper.max_width_m", 80.0, 0.5, "at most 0.5"),  # millimetres written as metres
    ("gripper.max_grasp_force_n", 10_000.0, 250, "at most 250"),
    ("gripper.max_speed_mps", 100.0, 0.5, "at most 0.5"),
]


def _disabling_id(row: tuple[str, Any, Any, str]) -> str:
    return f"{row[0]}={row[1]!r}"


@pytest.mark.parametrize("row", DISABLING_VALUES, ids=_disabling_id)
def test_value_that_would_switch_a_protection_off_is_refused_at_its_path(
    doc: dict[str, Any], row: tuple[str, Any, Any, str]
) -> None:
    path, bad, _, expected = row
    errors = errors_of(set_at(doc, path, bad))
    assert errors
    for error_path, message in errors:  # a vector reports each bad item at its own index
        assert error_path == path or error_path.startswith(f"{path}["), errors
        assert expected in message and "got" in message


@pytest.mark.parametrize("row", DISABLING_VALUES, ids=lambda row: f"{row[0]}={row[2]!r}")
def test_value_at_the_bound_is_accepted(doc: dict[str, Any], row: tuple[str, Any, Any, str]) -> None:
    path, _, at_bound, _ = row
    if path.endswith("min"):  # a corner at the bound needs the other corner beyond it
        set_at(doc, path.removesuffix("min") + "max", [5, 5, 5])
    if path.endswith(("wrench_timeout_s", "monitor_rate_hz")):
        doc["force"].update(monitor_rate_hz=10, wrench_timeout_s=0.5)
    set_at(doc, path, at_bound)
    if path == "motion.max_joint_step_rad":
        doc["motion"]["soft_joint_step_rad"] = None
    parse_policy(doc)


def test_force_monitor_polling_slower_than_the_wrench_timeout_is_refused(doc: dict[str, Any]) -> None:
    doc["force"].update(monitor_rate_hz=10, wrench_timeout_s=0.05)  # one poll per 0.1 s, samples stale after 0.05 s
    errors = errors_of(doc)
    assert [p for p, _ in errors] == ["force.monitor_rate_hz"]
    assert "wrench_timeout_s (0.05 s)" in errors[0][1] and "at least 20 Hz" in errors[0][1]


def test_force_monitor_period_equal_to_the_wrench_timeout_is_accepted(doc: dict[str, Any]) -> None:
    doc["force"].update(monitor_rate_hz=10, wrench_timeout_s=0.1)
    assert parse_policy(doc).force.monitor_rate_hz == 10


def test_keep_out_zone_outside_the_workspace_box_is_refused(doc: dict[str, Any]) -> None:
    doc["workspace"]["keep_out"][1].update(min=[0.6, -0.65, -1.0], max=[0.7, -0.55, -0.5])  # below the table
    errors = errors_of(doc)
    assert [p for p, _ in errors] == ["workspace.keep_out[1]"]
    assert "camera_mast" in errors[0][1] and "protect nothing" in errors[0][1]


def test_keep_out_zone_only_touching_the_box_is_refused(doc: dict[str, Any]) -> None:
    doc["workspace"]["keep_out"][0].update(min=[0.85, 0.4, 0.0], max=[1.0, 0.65, 0.45])  # shares the x = 0.85 face
    assert paths_of(doc) == ["workspace.keep_out[0]"]


def test_keep_out_zone_reaching_outside_the_box_is_accepted(doc: dict[str, Any]) -> None:
    doc["workspace"]["keep_out"][0].update(min=[0.45, 0.4, -1.0], max=[2.0, 2.0, 0.45])
    assert parse_policy(doc).workspace.keep_out[0].max == (2.0, 2.0, 0.45)


def test_outside_envelope_approval_with_no_soft_threshold_is_refused(doc: dict[str, Any]) -> None:
    doc["motion"].update(soft_joint_step_rad=None, joint_limit_margin_rad=0)
    errors = errors_of(doc)
    assert [p for p, _ in errors] == ["approval.mode"]
    assert "never ask" in errors[0][1]


@pytest.mark.parametrize(
    "change",
    [
        {"motion": {"soft_joint_step_rad": None}},
        {"motion": {"joint_limit_margin_rad": 0}},
        {"motion": {"soft_joint_step_rad": None, "joint_limit_margin_rad": 0}, "approval": {"mode": "never"}},
        {"motion": {"soft_joint_step_rad": None, "joint_limit_margin_rad": 0}, "approval": {"mode": "always"}},
    ],
)
def test_approval_mode_that_can_still_ask_or_says_never_is_accepted(doc: dict[str, Any], change: dict) -> None:
    for section, values in change.items():
        doc[section].update(values)
    parse_policy(doc)


@pytest.mark.parametrize("shipped", [FR3_YAML, READONLY_YAML], ids=lambda p: p.name)
def test_shipped_policy_is_inside_every_bound(shipped: Path) -> None:
    policy = load_policy(shipped)
    assert policy.motion.start_tolerance_rad <= 0.1
    assert 1 / policy.force.monitor_rate_hz <= policy.force.wrench_timeout_s


def test_bound_error_names_the_bound_the_value_and_the_field(doc: dict[str, Any]) -> None:
    doc["motion"]["start_tolerance_rad"] = 10
    ((path, message),) = errors_of(doc)
    assert path == "motion.start_tolerance_rad"
    assert message.startswith("must be at most 0.1 (got 10) (Largest joint deviation [rad]")


# ====================================================================== strict typing details


def test_check_links_may_name_specific_links(doc: dict[str, Any]) -> None:
    doc["workspace"]["check_links"] = ["fr3_link5", "fr3_hand"]
    assert parse_policy(doc).workspace.check_links == ("fr3_link5", "fr3_hand")


def test_wrong_version_message_names_the_supported_version(doc: dict[str, Any]) -> None:
    doc["version"] = 2
    assert errors_of(doc) == [("version", "must be 1 (got 2)")]


def test_integer_values_are_accepted_for_float_fields(doc: dict[str, Any]) -> None:
    doc["force"]["max_contact_force_n"] = 30
    value = parse_policy(doc).force.max_contact_force_n
    assert value == 30.0 and isinstance(value, float)


def test_nan_message_uses_yaml_spelling(doc: dict[str, Any]) -> None:
    doc["force"]["max_contact_force_n"] = NAN
    assert errors_of(doc) == [("force.max_contact_force_n", "must be a finite number (got .nan)")]


def test_short_vector_is_one_error_on_the_vector(doc: dict[str, Any]) -> None:
    doc["workspace"]["box"]["max"] = [1.0]
    errors = errors_of(doc)
    assert errors == [("workspace.box.max", "must have exactly 3 items (too few given)")]


# ====================================================================== all errors at once


def test_two_bad_fields_in_different_sections_give_two_errors(doc: dict[str, Any]) -> None:
    doc["motion"]["max_velocity_scaling"] = 1.5
    doc["workspace"]["keep_out"][1]["min"] = [0.0, NAN, 0.0]
    assert paths_of(doc) == ["workspace.keep_out[1].min[1]", "motion.max_velocity_scaling"]


def test_field_error_and_rule_error_in_different_sections_are_both_reported(doc: dict[str, Any]) -> None:
    doc["robot"]["home_joint_positions"][5] = 0.0
    doc["force"]["monitor_rate_hz"] = 0
    doc["rate_limits"]["per_tool"]["bogus"] = 1
    assert paths_of(doc) == ["robot.home_joint_positions[5]", "force.monitor_rate_hz", "rate_limits.per_tool.bogus"]


def test_policy_error_message_lists_every_path(doc: dict[str, Any]) -> None:
    doc["dry_run"] = "no"
    doc["version"] = 2
    with pytest.raises(PolicyError) as caught:
        parse_policy(doc, source="site.yaml")
    assert isinstance(caught.value, ConfigurationError)
    text = str(caught.value)
    assert "site.yaml" in text and "version:" in text and "dry_run:" in text


# ====================================================================== loading files


def write(tmp_path: Path, text: str | bytes, name: str = "policy.yaml") -> Path:
    path = tmp_path / name
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize("shipped", [FR3_YAML, READONLY_YAML], ids=lambda p: p.name)
def test_shipped_policy_loads(shipped: Path) -> None:
    policy = load_policy(shipped)
    assert policy.robot.description == "builtin:fr3"
    assert policy.robot.joint_names == tuple(f"fr3_joint{i}" for i in range(1, 8))
    assert policy.dry_run is False


def test_fr3_policy_enables_every_tool_and_has_the_ready_home() -> None:
    policy = load_policy(FR3_YAML)
    assert policy.enabled_tools == ALL_TOOLS
    assert policy.robot.home_joint_positions == pytest.approx(
        [0, -math.pi / 4, 0, -3 * math.pi / 4, 0, math.pi / 2, math.pi / 4], abs=1e-6
    )
    assert [zone.name for zone in policy.workspace.keep_out] == ["monitor", "camera_mast"]
    assert policy.gripper is not None and policy.gripper.max_width_m == 0.08


def test_readonly_policy_enables_only_introspect_and_safety() -> None:
    policy = load_policy(READONLY_YAML)
    assert policy.tools.enabled == ("introspect", "safety")
    assert not {"execute_plan", "gripper_move", "camera_snapshot", "switch_controllers"} & set(policy.enabled_tools)
    assert policy.workspace == load_policy(FR3_YAML).workspace


@pytest.mark.parametrize("shipped", [FR3_YAML, READONLY_YAML], ids=lambda p: p.name)
def test_policy_survives_a_round_trip_through_its_json_dump(shipped: Path) -> None:
    policy = load_policy(shipped)
    assert parse_policy(policy.model_dump(mode="json")) == policy


def test_yaml_syntax_error_is_a_policy_error_with_the_line(tmp_path: Path) -> None:
    path = write(tmp_path, "version: 1\nrobot: [unclosed\n")
    with pytest.raises(PolicyError) as caught:
        load_policy(path)
    (error,) = caught.value.errors
    assert error[0] == DOCUMENT_PATH and "invalid YAML" in error[1] and "line" in error[1]
    assert caught.value.source == str(path)


@pytest.mark.parametrize("text", ["- version\n- robot\n", "42\n", "just a string\n", "", "# only a comment\n"])
def test_non_mapping_document_is_a_policy_error(tmp_path: Path, text: str) -> None:
    with pytest.raises(PolicyError) as caught:
        load_policy(write(tmp_path, text))
    assert [p for p, _ in caught.value.errors] == [DOCUMENT_PATH]
    assert "mapping" in caught.value.errors[0][1]


@pytest.mark.parametrize("value", [None, [], "text", 3])
def test_parse_policy_rejects_non_mapping(value: Any) -> None:
    assert paths_of(value) == [DOCUMENT_PATH]


def test_duplicate_yaml_key_is_a_policy_error(tmp_path: Path) -> None:
    text = FR3_YAML.read_text(encoding="utf-8").replace("dry_run: false", "dry_run: false\ndry_run: true")
    with pytest.raises(PolicyError) as caught:
        load_policy(write(tmp_path, text))
    assert "duplicate key 'dry_run'" in caught.value.errors[0][1]


def test_yaml_merge_keys_may_override_merged_values(tmp_path: Path) -> None:
    text = FR3_YAML.read_text(encoding="utf-8").replace(
        "  box:\n    min: [-0.45, -0.70, 0.0]\n    max: [0.85, 0.70, 1.15]\n",
        "  box: &box\n    min: [-0.45, -0.70, 0.0]\n    max: [0.85, 0.70, 1.15]\n",
    )
    text += "\n_unused: {<<: *box, max: [1, 1, 1]}\n"
    with pytest.raises(PolicyError) as caught:
        load_policy(write(tmp_path, text))
    assert [p for p, _ in caught.value.errors] == ["_unused"]  # merge accepted; only the unknown key fails


def test_file_larger_than_one_mebibyte_is_refused(tmp_path: Path) -> None:
    text = FR3_YAML.read_text(encoding="utf-8") + "#" * MAX_POLICY_BYTES
    with pytest.raises(PolicyError) as caught:
        load_policy(write(tmp_path, text))
    assert "larger than" in caught.value.errors[0][1]


def test_missing_file_is_a_policy_error(tmp_path: Path) -> None:
    with pytest.raises(PolicyError) as caught:
        load_policy(tmp_path / "absent.yaml")
    assert "cannot read" in caught.value.errors[0][1]


def test_non_utf8_file_is_a_policy_error(tmp_path: Path) -> None:
    with pytest.raises(PolicyError) as caught:
        load_policy(write(tmp_path, b"version: 1\nname: \xff\xfe\n"))
    assert "UTF-8" in caught.value.errors[0][1]


def test_yaml_nan_literal_in_file_is_rejected_at_its_path(tmp_path: Path) -> None:
    text = FR3_YAML.read_text(encoding="utf-8").replace("link_padding_m: 0.01", "link_padding_m: .nan")
    with pytest.raises(PolicyError) as caught:
        load_policy(write(tmp_path, text))
    assert [p for p, _ in caught.value.errors] == ["workspace.link_padding_m"]


def test_relative_description_resolves_against_the_policy_folder(tmp_path: Path, doc: dict[str, Any]) -> None:
    doc["robot"]["description"] = "urdf/arm.urdf"
    path = write(tmp_path, yaml.safe_dump(doc), name="cell/policy.yaml")
    policy = load_policy(path)
    assert policy.robot.description == str((tmp_path / "cell" / "urdf" / "arm.urdf").resolve())


def test_absolute_description_is_kept(tmp_path: Path, doc: dict[str, Any]) -> None:
    doc["robot"]["description"] = str(tmp_path / "arm.urdf")
    policy = load_policy(write(tmp_path, yaml.safe_dump(doc), name="elsewhere/policy.yaml"))
    assert policy.robot.description == str(tmp_path / "arm.urdf")


def test_parse_policy_resolves_relative_description_only_with_a_base_dir(
    tmp_path: Path, doc: dict[str, Any]
) -> None:
    doc["robot"]["description"] = "arm.urdf"
    assert parse_policy(doc).robot.description == "arm.urdf"
    assert parse_policy(doc, base_dir=tmp_path).robot.description == str((tmp_path / "arm.urdf").resolve())


# ====================================================================== immutability and dry run


def test_policy_is_frozen() -> None:
    policy = load_policy(FR3_YAML)
    with pytest.raises(ValidationError):
        policy.dry_run = True  # type: ignore[misc]
    with pytest.raises(ValidationError):
        policy.motion.max_velocity_scaling = 1.0  # type: ignore[misc]
    with pytest.raises(TypeError):
        policy.rate_limits.per_tool["execute_plan"] = 1000  # type: ignore[index]
    with pytest.raises(TypeError):
        policy.robot.joint_limits["fr3_joint1"] = None  # type: ignore[index]
    assert isinstance(policy.robot.joint_names, tuple)
    assert isinstance(policy.workspace.keep_out, tuple)
    assert isinstance(policy.workspace.box.min, tuple)


def test_policy_can_be_copied_pickled_and_hashed() -> None:
    policy = load_policy(FR3_YAML)
    assert copy.deepcopy(policy) == policy
    assert pickle.loads(pickle.dumps(policy)) == policy
    assert hash(policy) == hash(load_policy(FR3_YAML))


def test_with_dry_run_returns_a_copy_with_dry_run_on() -> None:
    policy = load_policy(FR3_YAML)
    dry = policy.with_dry_run(True)
    assert dry.dry_run is True and policy.dry_run is False
    assert dry.model_copy(update={"dry_run": False}) == policy


def test_with_dry_run_false_never_turns_off_a_policy_dry_run(doc: dict[str, Any]) -> None:
    doc["dry_run"] = True
    policy = parse_policy(doc)
    assert policy.with_dry_run(False).dry_run is True
    assert parse_policy(full_mapping()).with_dry_run(False).dry_run is False


# ====================================================================== constants, summary, schema


def test_tool_groups_hold_the_22_tool_names() -> None:
    assert list(TOOL_GROUPS) == ["introspect", "perception", "motion", "gripper", "control", "safety"]
    assert len(ALL_TOOLS) == len(set(ALL_TOOLS)) == 23
    assert set(RATE_LIMIT_EXEMPT_TOOLS) <= set(TOOL_GROUPS["safety"])


def test_summary_states_the_facts_an_operator_checks() -> None:
    text = summarize_policy(load_policy(FR3_YAML))
    for fact in (
        "fr3",
        "builtin:fr3",
        "fr3_joint4",
        "-3.0421",
        "-174.3",  # degrees
        "motion",
        "execute_plan",
        "monitor",
        "camera_mast",
        "0.3",
        "30 N",
        "70 N",
        "outside_envelope",
        "Dry run: off",
        "estimated TCP force ≤ 30 N",
    ):
        assert fact in text, fact
    assert len(text.splitlines()) > 15


def test_summary_flags_dry_run_and_missing_gripper() -> None:
    text = summarize_policy(load_policy(READONLY_YAML).with_dry_run(True))
    assert "Dry run: ON" in text and "Gripper: none" in text


def test_summary_flags_self_approval_only_when_allowed(doc: dict[str, Any]) -> None:
    allowed = summarize_policy(parse_policy(set_at(doc, "approval.allow_self_approval", True)))
    default = summarize_policy(load_policy(FR3_YAML))

    assert "SELF-APPROVAL ALLOWED" in allowed
    assert "SELF-APPROVAL" not in default


@pytest.mark.parametrize(("channel", "where"), [("form", "the MCP client's form"), ("url", "the operator console"),
                                                ("both", "whichever answers first")])
def test_summary_says_where_a_human_answers_approvals(doc: dict[str, Any], channel: str, where: str) -> None:
    text = summarize_policy(parse_policy(set_at(doc, "approval.channel", channel)))
    approval = next(line for line in text.splitlines() if line.startswith("Approval:"))
    assert f"answered in: {channel} ({where}" in approval


def test_summary_says_self_approval_is_off_by_default() -> None:
    text = summarize_policy(load_policy(FR3_YAML))
    assert "self-approval off" in text


def test_summary_shows_the_collision_geometry_and_the_padding_of_each_link() -> None:
    text = summarize_policy(load_policy(FR3_YAML))
    assert "collision geometry: builtin:fr3" in text
    assert "fr3_leftfinger 0.002 m" in text and "fr3_rightfinger 0.002 m" in text


def test_json_schema_describes_every_field() -> None:
    schema = policy_json_schema()
    assert set(schema["required"]) == {"version", "robot", "workspace", "motion", "force"}
    missing = [
        f"{name}.{prop}"
        for name, definition in schema["$defs"].items()
        for prop, body in definition.get("properties", {}).items()
        if not body.get("description")
    ]
    missing += [prop for prop, body in schema["properties"].items() if not body.get("description")]
    assert missing == []
    assert all(d.get("additionalProperties") is False for d in schema["$defs"].values() if "properties" in d)


@pytest.mark.parametrize("field", ["global_per_minute", "default_per_minute"])
def test_a_rate_too_large_to_be_a_float_is_refused_at_load_not_at_serve(doc: dict[str, Any], field: str) -> None:
    """Found by review: 10**400 passed check-policy, then the limiter's float() overflowed at start-up."""
    doc["rate_limits"][field] = 10**400
    assert paths_of(doc) == [f"rate_limits.{field}"]


def test_a_finger_speed_below_the_floor_is_refused(doc: dict[str, Any]) -> None:
    doc["gripper"]["max_speed_mps"] = 0.0005
    assert paths_of(doc) == ["gripper.max_speed_mps"]
