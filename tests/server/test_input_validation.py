"""Argument fuzzing on every registered tool, through the official MCP SDK client, both protocol modes.

NaN/Inf, huge numbers, numbers as strings, booleans, 100 000-character strings, deeply nested and
huge lists, wrong lengths and unknown keys (top level and inside nested objects): every call is an
`isError` result (the e-stop instead always latches), nothing reaches the backend's actuating
methods, and the server keeps serving afterwards.

Two SDK behaviours shape the generators:
* a *string holding JSON* is parsed before validation (`'["a"]'` becomes a list, `"null"` becomes
  null), so such strings are not invalid input and the strategies leave them out;
* the client serialises NaN/±Inf as JSON `null` (JSON has no NaN), so for an *optional* number the
  server sees "not given" and uses the policy default. Real NaN/Inf are therefore also sent straight
  to the tool layer (`MCPServer.call_tool`, no transport), where every numeric slot refuses them.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path
from typing import Any

import anyio
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from armwarden.audit import read_tail, verify_file
from armwarden.safety.estop import REASON_LIMIT
from tests.helpers import HOME, text_of
from tests.server.harness import MODES, approve, arm_harness, policy_with

NAN, INF = float("nan"), float("inf")
HUGE_TEXT = "x" * 100_000
POINT = {"x": 0.4, "y": 0.1, "z": 0.35}


def nested(depth: int = 60) -> Any:
    value: Any = [0.1]
    for _ in range(depth):
        value = [value]
    return value


NESTED = nested()
HUGE_LIST = [[0.1] * 7] * 5_000  # 35 000 numbers

#: a valid call per tool; each fuzz case breaks exactly one argument of it
BASELINE: dict[str, dict[str, Any]] = {
    "get_robot_state": {},
    "get_safety_envelope": {},
    "lookup_transform": {"target_frame": "fr3_link0", "source_frame": "fr3_hand_tcp"},
    "list_controllers": {},
    "list_ros_graph": {},
    "get_audit_tail": {"n": 5},
    "camera_snapshot": {"camera": "wrist"},
    "plan_to_joints": {"joint_positions": [0.1, *HOME[1:]]},
    "plan_to_pose": {"position": POINT},
    "plan_cartesian_path": {"waypoints": [{"position": {"x": 0.35, "y": 0.0, "z": 0.45}}]},
    "get_plan": {"plan_id": "plan_from_the_baseline_test"},
    "execute_plan": {"plan_id": "plan_from_the_baseline_test"},
    "get_motion_status": {},
    "gripper_move": {"width_m": 0.04},
    "gripper_grasp": {"width_m": 0.02, "force_n": 20.0},
    "gripper_home": {},
    "switch_controllers": {"activate": ["joint_impedance_controller"], "deactivate": ["fr3_arm_controller"]},
    "set_collision_thresholds": {"force_n": 20.0, "torque_nm": 5.0},
    "stop_motion": {},
    "estop": {"reason": "fuzz"},
    "reset_estop": {},
    "error_recovery": {},
    "get_safety_status": {},
}

#: every argument of every tool, by the kind of bad input it gets
FIELDS: dict[str, dict[str, str]] = {
    "lookup_transform": {"target_frame": "name", "source_frame": "name"},
    "get_audit_tail": {"n": "count"},
    "camera_snapshot": {"camera": "name"},
    "plan_to_joints": {"joint_positions": "joints", "velocity_scaling": "scaling",
                       "acceleration_scaling": "scaling", "preview": "flag"},
    "plan_to_pose": {"position": "point", "orientation": "quaternion", "frame_id": "frame",
                     "velocity_scaling": "scaling", "acceleration_scaling": "scaling", "preview": "flag",
                     "free_yaw": "flag"},
    "plan_cartesian_path": {"waypoints": "waypoints", "frame_id": "frame", "velocity_scaling": "scaling",
                            "acceleration_scaling": "scaling", "preview": "flag"},
    "execute_plan": {"plan_id": "name"},
    "get_plan": {"plan_id": "name"},
    "gripper_move": {"width_m": "number", "speed_mps": "speed"},
    "gripper_grasp": {"width_m": "number", "force_n": "number", "speed_mps": "speed",
                      "epsilon_inner_m": "number", "epsilon_outer_m": "number"},
    "switch_controllers": {"activate": "names", "deactivate": "names"},
    "set_collision_thresholds": {"force_n": "number", "torque_nm": "number"},
    "estop": {"reason": "anything"},  # accepts anything: fuzzed separately, must always latch
}

_NUMBER_JUNK = ["0.3", "1", "NaN", "Infinity", "-inf", "1e999", True, False, 1e308, -1e308, 1e6, -1e6,
                HUGE_TEXT, [0.03], {"value": 0.03}, NESTED]
BAD_VALUES: dict[str, list[Any]] = {
    "number": [*_NUMBER_JUNK, NAN, INF, -INF, None],  # NaN/Inf arrive as null: refused, the value is required
    "optional_number": _NUMBER_JUNK,  # NaN/Inf arrive as null = "use the default": see the direct test
    # and below the floor: a motion that would take hours and grow without bound (waypoints ∝ 1/scaling)
    "scaling": [*_NUMBER_JUNK, 0.0, -0.1, 0.0099, 1e-4, 1e-300, 5e-324],
    # and below the floor: a gripper call that would take hours and hold every other one off (found by review)
    "speed": [*_NUMBER_JUNK, 0.0, -0.1, 0.00099, 1e-6, 1e-300, 5e-324],
    "flag": [1, 0, 0.0, NAN, "yes", "True", [True], {"on": True}, HUGE_TEXT, None],
    "count": ["5", 5.0, 5.5, True, NAN, INF, -INF, 10**30, -1, 0, 101, [5], {"n": 5}, HUGE_TEXT, None],
    "name": ["", HUGE_TEXT, 42, 0.3, True, NAN, ["wrist"], {"name": "wrist"}, "no such thing \u202e\n", None, NESTED],
    "frame": ["world", HUGE_TEXT, 42, True, ["fr3_link0"], {"frame": "fr3_link0"}, "fr3_link0 ", NESTED],
    "joints": [[0.0] * 6, [*HOME, 0.0], [], [NAN, *HOME[1:]], [*HOME[:6], INF], [*HOME[:6], -INF],
               [*HOME[:6], 1e308], ["0.0"] * 7, [True] * 7, [None] * 7, [HOME], HUGE_LIST, [0.1] * 100_000,
               NESTED, "0.0", 0.0, {"fr3_joint1": 0.0}, HUGE_TEXT, None],
    "point": [{**POINT, "w": 1.0}, {"x": 0.4, "y": 0.1}, {**POINT, "x": NAN}, {**POINT, "z": INF},
              {**POINT, "x": "0.4"}, {**POINT, "y": True}, {**POINT, "x": 1e308}, {**POINT, "x": {"x": 0.4}},
              {**POINT, "frame": "world"}, [0.4, 0.1, 0.35], "0.4, 0.1, 0.35", 0.4, HUGE_TEXT, NESTED, None],
    "quaternion": [{"x": 0, "y": 0, "z": 0, "w": 0}, {"x": 1, "y": 1, "z": 1, "w": 1},
                   {"x": 1, "y": 0, "z": 0, "w": 0, "extra": 1}, {"x": NAN, "y": 0, "z": 0, "w": 1},
                   {"x": 1, "y": 0, "z": 0}, {"x": "1", "y": 0, "z": 0, "w": 0}, [0, 0, 0, 1], "identity",
                   {"x": INF, "y": 0, "z": 0, "w": 0}, HUGE_TEXT, NESTED],
    "waypoints": [[], [{"position": POINT}] * 51, [{"position": {**POINT, "w": 1.0}}],
                  [{"position": POINT, "speed": 1.0}], [{"position": {**POINT, "x": NAN}}],
                  [{"position": POINT, "orientation": {"x": 0, "y": 0, "z": 0, "w": 0}}], [POINT], [[POINT]],
                  [{"position": POINT}] * 10_000, {"position": POINT}, NESTED, HUGE_TEXT, None],
    "names": [[""], [HUGE_TEXT], [1], [True], [None], [["joint_impedance_controller"]],
              ["fr3_arm_controller"] * 17, "joint_impedance_controller", 7, {"a": 1}, ["name"] * 10_000,
              ["evil_controller"], NESTED],
}


def fuzz_policy():
    """The FR3 policy with rate limits out of the way (a flood must be refused for its content)."""
    return policy_with(**{"rate_limits.global_per_minute": 1_000_000, "rate_limits.default_per_minute": 1_000_000,
                          "rate_limits.per_tool": {}})


def _is_json(text: str) -> bool:
    try:
        json.loads(text)
    except ValueError:
        return False
    return True


def _shown(value: Any) -> str:
    return repr(value)[:120]


# ---------------------------------------------------------------------------------------------- coverage
@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_the_fuzz_tables_cover_every_registered_tool_and_argument_and_the_baselines_are_valid(tmp_path, mode) -> None:
    """Guards the fuzzing below: a new tool or argument must be added here, and each baseline call
    is accepted, so every refusal below is caused by the one broken argument."""

    async with arm_harness(tmp_path, fuzz_policy(), speedup=50.0) as arm, arm.client(mode, approve()) as client:
        tools = (await client.list_tools()).tools
        assert {tool.name for tool in tools} == set(BASELINE)
        for tool in tools:
            assert set(tool.input_schema.get("properties", {})) == set(FIELDS.get(tool.name, {})), tool.name
        planned = await client.call_tool("plan_to_joints", BASELINE["plan_to_joints"])
        plan_id = planned.structured_content["plan_id"]
        calls = dict(BASELINE, get_plan={"plan_id": plan_id}, execute_plan={"plan_id": plan_id})  # read, then run
        del calls["estop"], calls["reset_estop"]  # checked elsewhere (latching changes everything after)
        for name, arguments in calls.items():
            result = await client.call_tool(name, arguments)
            assert not result.is_error, f"{name}: {text_of(result)[:300]}"
        orientation = await client.call_tool("plan_to_pose", {"position": POINT, "orientation": None})
        assert not orientation.is_error


# ---------------------------------------------------------------------------------------------- table-driven fuzz
@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_bad_arguments_on_every_tool_are_refused_and_nothing_actuates(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, fuzz_policy(), speedup=50.0) as arm, arm.client(mode, approve()) as client:
        accepted: list[str] = []
        calls = 0
        for tool, fields in FIELDS.items():
            if tool == "estop":
                continue
            for field, kind in fields.items():
                for bad in BAD_VALUES[kind]:
                    arguments = dict(BASELINE[tool], **{field: bad})
                    result = await client.call_tool(tool, arguments)
                    calls += 1
                    if not result.is_error:
                        accepted.append(f"{tool}.{field}={_shown(bad)}: {text_of(result)[:150]}")
        assert accepted == [], "\n".join(accepted)
        assert arm.actuations == []
        # refused before any tool body ran, and every one of them is in the audit log
        arm.audit.flush()  # read-only calls' records are group-committed
        records = [r for r in read_tail(arm.audit_path, 1000) if r["event"] == "tool_call"]
        assert len(records) == calls
        assert all(r["outcome"] in ("invalid", "refused") for r in records)
        assert sum(r["outcome"] == "invalid" for r in records) > calls // 2
        status = await client.call_tool("get_safety_status", {})
        assert not status.is_error and status.structured_content["estopped"] is False
    assert verify_file(arm.audit_path).ok


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_unknown_and_missing_arguments_are_refused_on_every_tool(tmp_path, mode) -> None:
    async with arm_harness(tmp_path, fuzz_policy(), speedup=50.0) as arm, arm.client(mode, approve()) as client:
        tools = (await client.list_tools()).tools
        for tool in tools:
            junk = dict(BASELINE[tool.name], dry_run=True, approval={"approve": True}, unexpected=[NAN])
            result = await client.call_tool(tool.name, junk)
            if tool.name in ("stop_motion", "estop"):
                assert not result.is_error, text_of(result)  # stopping works whatever it is sent
                continue
            assert result.is_error, f"{tool.name} accepted unknown arguments: {text_of(result)[:200]}"
            assert "INVALID_ARGUMENTS" in text_of(result) and "dry_run" in text_of(result)
            for required in tool.input_schema.get("required", []):
                missing = {k: v for k, v in BASELINE[tool.name].items() if k != required}
                result = await client.call_tool(tool.name, missing)
                assert result.is_error and required in text_of(result), text_of(result)[:200]
        assert arm.actuations == []
        unknown = await client.call_tool("no_such_tool", {"x": 1})
        assert unknown.is_error
        invalid = [r for r in read_tail(arm.audit_path, 1000) if r["outcome"] == "invalid"]
        assert {r["tool"] for r in invalid} >= {"execute_plan", "gripper_home", "reset_estop", "no_such_tool"}
        assert not (await client.call_tool("get_safety_status", {})).is_error
    assert verify_file(arm.audit_path).ok


# ---------------------------------------------------------------------------------------------- hypothesis
_not_json_text = st.text(max_size=40).filter(lambda s: not _is_json(s))
_huge_float = st.one_of(st.floats(min_value=1e6, allow_infinity=False), st.floats(max_value=-1e6, allow_infinity=False))
_bad_float = st.one_of(st.sampled_from([NAN, INF, -INF]), _huge_float)
_junk = st.one_of(
    _not_json_text,
    st.booleans(),
    st.lists(st.floats(), min_size=1, max_size=4),
    st.dictionaries(st.text(max_size=6), st.floats(), min_size=1, max_size=3),
    st.just(HUGE_TEXT),
)
_valid_names = {"", "wrist", "scene", "fr3_arm_controller", "joint_impedance_controller"}
_bad_name_text = _not_json_text.filter(lambda s: s not in _valid_names and not s.startswith("fr3_") and s.strip() == s
                                       and s != "plan_from_the_baseline_test")


def _bad_point(keys: str) -> st.SearchStrategy[Any]:
    good = dict.fromkeys(keys, 0.0)
    return st.one_of(
        st.builds(lambda k, v: {**good, k: v}, st.sampled_from(list(keys)), st.one_of(_bad_float, _junk, st.none())),
        st.builds(lambda k, v: {**good, k: v}, st.text(min_size=1, max_size=8).filter(lambda k: k not in keys), st.floats()),
        st.builds(lambda k: {key: value for key, value in good.items() if key != k}, st.sampled_from(list(keys))),
        _huge_float, _not_json_text, st.lists(st.floats(), max_size=5),  # (NaN would arrive as null = omitted)
    )


STRATEGIES: dict[str, st.SearchStrategy[Any]] = {
    "number": st.one_of(_bad_float, _junk, st.none()),
    "optional_number": st.one_of(_huge_float, _junk),
    "scaling": st.one_of(_huge_float, _junk, st.floats(min_value=-1.0, max_value=0.0099)),
    "speed": st.one_of(_huge_float, _junk, st.floats(min_value=-1.0, max_value=0.00099)),
    "flag": st.one_of(st.integers(), st.floats(), _not_json_text, st.lists(st.booleans(), min_size=1, max_size=2),
                      st.none()),
    "count": st.one_of(st.floats(), st.integers(min_value=101), st.integers(max_value=0), _junk, st.none()),
    "name": st.one_of(_bad_name_text, st.integers(), st.floats(), st.booleans(), st.lists(st.text(), min_size=1, max_size=3),
                      st.just(HUGE_TEXT), st.none()),
    "frame": st.one_of(_bad_name_text, st.integers(), st.floats(allow_nan=False, allow_infinity=False), st.booleans(),
                       st.just(HUGE_TEXT)),
    "joints": st.one_of(
        st.lists(st.floats(-1.0, 1.0), max_size=20).filter(lambda q: len(q) != 7),
        st.lists(st.one_of(_bad_float, _not_json_text, st.booleans(), st.none()), min_size=7, max_size=7),
        _bad_float, _not_json_text, st.none(),
    ),
    "point": st.one_of(_bad_point("xyz"), st.none()),
    "quaternion": _bad_point("xyzw"),
    "waypoints": st.one_of(
        st.just([]),
        st.lists(st.builds(lambda p: {"position": p}, _bad_point("xyz")), min_size=1, max_size=4),
        st.lists(st.just({"position": POINT}), min_size=51, max_size=60),
        _bad_float, _not_json_text, st.none(),
    ),
    "names": st.one_of(
        st.lists(_bad_name_text, min_size=1, max_size=4),
        st.lists(st.one_of(st.integers(), st.floats(), st.booleans(), st.none()), min_size=1, max_size=3),
        st.lists(st.just("fr3_arm_controller"), min_size=17, max_size=30),
        st.integers(), _not_json_text.filter(lambda s: s not in _valid_names),
    ),
}
FUZZ_TARGETS = [(tool, field, kind) for tool, fields in FIELDS.items() for field, kind in fields.items() if tool != "estop"]
_cases = st.lists(
    st.sampled_from(FUZZ_TARGETS).flatmap(lambda t: st.tuples(st.just(t), STRATEGIES[t[2]])), min_size=1, max_size=8
)


@pytest.mark.parametrize("mode", MODES)
@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(cases=_cases)
def test_random_bad_arguments_are_refused_and_nothing_actuates(mode, cases) -> None:
    async def scenario(directory: Path) -> None:
        async with arm_harness(directory, fuzz_policy(), speedup=50.0) as arm, arm.client(mode, approve()) as client:
            for (tool, field, _), bad in cases:
                result = await client.call_tool(tool, dict(BASELINE[tool], **{field: bad}))
                assert result.is_error, f"{tool}.{field}={_shown(bad)} was accepted: {text_of(result)[:200]}"
            assert arm.actuations == []
            assert not (await client.call_tool("get_safety_status", {})).is_error

    # sync on purpose: hypothesis does not run async tests; each example runs its own event loop
    with tempfile.TemporaryDirectory() as directory:
        anyio.run(scenario, Path(directory))


_any_json = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=200)),
    lambda inner: st.one_of(st.lists(inner, max_size=6), st.dictionaries(st.text(max_size=10), inner, max_size=6)),
    max_leaves=30,
)


@pytest.mark.parametrize("mode", MODES)
@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(reasons=st.lists(st.one_of(_any_json, st.just(HUGE_TEXT), st.just(NESTED), st.just(HUGE_LIST)), min_size=1, max_size=5))
def test_any_estop_input_latches_and_records_a_one_line_reason(mode, reasons) -> None:
    async def scenario(directory: Path) -> None:
        async with arm_harness(directory, fuzz_policy(), speedup=50.0) as arm, arm.client(mode) as client:
            for number, reason in enumerate(reasons, start=1):
                result = await client.call_tool("estop", {"reason": reason})
                assert not result.is_error, text_of(result)[:300]
                event = result.structured_content["estop_event"]
                assert event["number"] == number
                assert 0 < len(event["reason"]) <= REASON_LIMIT and event["reason"].isprintable()
            status = await client.call_tool("get_safety_status", {})
            assert status.structured_content["estopped"] is True
            assert arm.actuations == []
        assert verify_file(arm.audit_path).ok

    # sync on purpose: hypothesis does not run async tests; each example runs its own event loop
    with tempfile.TemporaryDirectory() as directory:
        anyio.run(scenario, Path(directory))


def _numeric_slots() -> list[tuple[str, dict[str, Any]]]:
    """Every numeric slot of every tool, top level and nested, with a placeholder to fill."""
    slots: list[tuple[str, dict[str, Any]]] = []
    for tool, fields in FIELDS.items():
        for field, kind in fields.items():
            if kind in ("number", "optional_number", "count"):
                slots.append((tool, dict(BASELINE[tool], **{field: "<bad>"})))
    slots.append(("plan_to_joints", {"joint_positions": [*HOME[:3], "<bad>", *HOME[4:]]}))
    for axis in "xyz":
        slots.append(("plan_to_pose", {"position": {**POINT, axis: "<bad>"}}))
        slots.append(("plan_cartesian_path", {"waypoints": [{"position": {**POINT, axis: "<bad>"}}]}))
    for axis in "xyzw":
        slots.append(("plan_to_pose", {"position": POINT, "orientation": {"x": 1.0, "y": 0.0, "z": 0.0, "w": 0.0, axis: "<bad>"}}))
    return slots


def _fill(value: Any, bad: float) -> Any:
    if value == "<bad>":
        return bad
    if isinstance(value, dict):
        return {k: _fill(v, bad) for k, v in value.items()}
    if isinstance(value, list):
        return [_fill(v, bad) for v in value]
    return value


@pytest.mark.anyio
async def test_real_nan_and_inf_reaching_the_tool_layer_are_refused_in_every_numeric_slot(tmp_path) -> None:
    """No transport in between (so NaN is not turned into null): the tool's own validation refuses."""
    from mcp.server.mcpserver.exceptions import ToolError

    async with arm_harness(tmp_path, fuzz_policy(), speedup=50.0) as arm:
        accepted = []
        for tool, template in _numeric_slots():
            for bad in (NAN, INF, -INF):
                arguments = _fill(template, bad)
                try:
                    result = await arm.server.mcp.call_tool(tool, arguments)
                except ToolError as exc:
                    refused = str(exc)
                    result = None
                if result is None:
                    assert "finite" in refused or "integer" in refused, refused[:300]
                    continue
                if not getattr(result, "is_error", False):
                    accepted.append(f"{tool} {_shown(arguments)}")
        assert accepted == [], "\n".join(accepted)
        estop = await arm.server.mcp.call_tool("estop", {"reason": NAN})  # the e-stop takes anything
        assert not estop.is_error and arm.guard.latch.is_latched
        assert arm.actuations == []


@pytest.mark.anyio
@pytest.mark.parametrize("mode", MODES)
async def test_a_huge_joint_target_is_refused_up_front_and_the_server_keeps_serving(tmp_path, mode) -> None:
    """Regression: a 1e6 rad joint target used to reach the time parameterisation, which subdivided
    the path until the daemon was OOM-killed (e-stop gone with it). Now the schema bounds it."""

    async with arm_harness(tmp_path, fuzz_policy(), speedup=50.0) as arm, arm.client(mode) as client:
        for value in (1e6, -1e6, 1e20, 11.0):
            result = await client.call_tool("plan_to_joints", {"joint_positions": [*HOME[:6], value]})
            assert result.is_error
            assert "joint_positions" in text_of(result) and "10" in text_of(result), text_of(result)[:300]
        status = await client.call_tool("get_safety_status", {})
        assert not status.is_error
        assert arm.actuations == []
