"""The tool catalogue is the one list of tools: the server registers exactly its available records,
annotated and typed as they say, and every set of tool names in the daemon is derived from it."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import get_args

import pytest

from armwarden import results
from armwarden.approval.decision import approval_required
from armwarden.core.errors import ConfigurationError
from armwarden.guard.actions import ControlTool
from armwarden.guard.gripper import GripperTool
from armwarden.policy import ALL_TOOLS, APPROVAL_ACTIONS, RATE_LIMIT_EXEMPT_TOOLS, TOOL_GROUPS
from armwarden.server import registration
from armwarden.server.faces import GROUP_FACES, FaceContext
from armwarden.tools import TOOLS, ToolGroup, names, spec_of
from armwarden.transport.access import role_allows
from tests.server.harness import arm_harness, policy_with

pytestmark = pytest.mark.anyio
SRC = Path(__file__).resolve().parents[2] / "src" / "armwarden"


def test_every_tool_has_one_record_with_a_unique_name() -> None:
    assert len({spec.name for spec in TOOLS}) == len(TOOLS) == len(ALL_TOOLS)
    assert all(spec_of(spec.name) is spec for spec in TOOLS)
    assert spec_of("move_the_arm_anyway") is None


async def test_the_server_lists_exactly_the_records_its_backend_can_serve_in_their_order(tmp_path: Path) -> None:
    async with arm_harness(tmp_path) as arm, arm.client() as client:
        listed = [tool.name for tool in (await client.list_tools()).tools]
        capabilities = arm.guard.capabilities
    expected = [spec.name for spec in TOOLS if spec.capability is None or getattr(capabilities, spec.capability)]
    assert listed == expected
    assert "camera_snapshot" in listed and "gripper_grasp" in listed  # the fake has cameras and a gripper


async def test_a_backend_without_capabilities_gets_none_of_the_tools_that_need_one(tmp_path: Path) -> None:
    async with arm_harness(tmp_path, backend="minimal") as arm, arm.client() as client:
        listed = {tool.name for tool in (await client.list_tools()).tools}
    assert listed == {spec.name for spec in TOOLS if spec.capability is None}


async def test_a_group_the_policy_leaves_out_is_not_registered_but_safety_always_is(tmp_path: Path) -> None:
    async with arm_harness(tmp_path, policy_with(**{"tools.enabled": ["introspect"]})) as arm, arm.client() as client:
        listed = {tool.name for tool in (await client.list_tools()).tools}
    assert not listed & (names(group="motion") | names(group="gripper") | names(group="control"))
    assert names(group="safety") <= listed  # the fake has error recovery's capability


async def test_each_listed_tool_carries_its_records_annotations_and_result_schema(tmp_path: Path) -> None:
    async with arm_harness(tmp_path) as arm, arm.client() as client:
        tools = (await client.list_tools()).tools
    for tool in tools:
        spec = spec_of(tool.name)
        assert spec is not None and tool.annotations is not None
        hints = spec.hints
        assert (tool.annotations.read_only_hint, tool.annotations.destructive_hint, tool.annotations.idempotent_hint,
                tool.annotations.open_world_hint) == (hints.read_only, hints.destructive, hints.idempotent,
                                                       hints.open_world), tool.name
        assert tool.output_schema is not None and tool.output_schema["title"] == spec.result.__name__
        assert "$ref" not in repr(tool.output_schema)  # self-contained: clients validate without resolving


@pytest.mark.parametrize("group", get_args(ToolGroup))
async def test_each_group_has_a_face_for_every_record_and_no_other(tmp_path: Path, group: ToolGroup) -> None:
    async with arm_harness(tmp_path) as arm:
        context = FaceContext(arm.guard, arm.guard.policy, arm.guard.capabilities, [], registration.ToolBuilder(arm.guard).answer)
        faces = GROUP_FACES[group](context)
    assert set(faces) == names(group=group)


async def test_a_face_that_returns_another_result_than_its_record_says_stops_the_server_from_starting(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    wrong = tuple(dataclasses.replace(spec, result=results.StopResult) if spec.name == "get_robot_state" else spec
                  for spec in TOOLS)
    async with arm_harness(tmp_path) as arm:
        monkeypatch.setattr(registration, "TOOLS", wrong)
        with pytest.raises(ConfigurationError, match="get_robot_state returns RobotState, its record says StopResult"):
            registration.ToolBuilder(arm.guard).build()


def test_the_policys_groups_and_approvable_actions_come_from_the_records() -> None:
    assert list(TOOL_GROUPS) == list(get_args(ToolGroup))
    assert tuple(spec.name for spec in TOOLS) == ALL_TOOLS
    assert set(RATE_LIMIT_EXEMPT_TOOLS) == {"stop_motion", "estop", "get_safety_status"}
    assert {spec.approval for spec in TOOLS if spec.approval} == set(APPROVAL_ACTIONS)


def test_the_guards_tool_literals_match_the_records() -> None:
    assert set(get_args(GripperTool)) == names(group="gripper")
    assert set(get_args(ControlTool)) == names(lambda spec: spec.approval == spec.name and spec.backend_call == spec.name)


def test_reset_estop_always_needs_a_human_whatever_the_policy_says() -> None:
    policy = policy_with(**{"approval.mode": "never"})
    spec = spec_of("reset_estop")
    assert spec is not None and spec.approval == "reset_estop"
    assert approval_required(policy, "reset_estop")


@pytest.mark.parametrize("tool", [spec.name for spec in TOOLS])
def test_an_observer_may_call_a_tool_exactly_when_its_record_says_so(tool: str) -> None:
    spec = spec_of(tool)
    assert spec is not None
    assert role_allows("observer", tool) == (spec.observer or spec.group in ("introspect", "perception"))
    assert role_allows("operator", tool) and role_allows("agent", tool)


def test_no_module_names_the_sdks_private_tool_manager() -> None:
    offenders = [str(path.relative_to(SRC)) for path in SRC.rglob("*.py") if "_tool_manager" in path.read_text()]
    assert offenders == []


def test_no_module_outside_the_catalogue_lists_tool_names_as_a_set() -> None:
    """A set or tuple of two or more tool names is a parallel list the catalogue replaces (a
    `Literal[...]` type is checked against the records instead: see the test above)."""
    tool = "|".join(re.escape(name) for name in ALL_TOOLS)
    listing = re.compile(rf'(?<!Literal)[({{\[]\s*"({tool})"\s*,\s*"({tool})"')
    offenders = [str(path.relative_to(SRC)) for path in SRC.rglob("*.py")
                 if path.parent.name != "tools" and listing.search(path.read_text())]
    assert offenders == []


def test_the_backend_contract_tries_every_tool_that_needs_a_capability() -> None:
    from tests.backends.contract import OPTIONAL_CALLS

    assert set(OPTIONAL_CALLS) == names(lambda spec: spec.capability is not None)


def test_the_records_say_which_tools_stop_observe_and_move_exactly() -> None:
    """The sets the daemon treats specially, spelled out: a flag flipped on one record fails here."""
    assert names(lambda spec: spec.observer_may_call) == {
        "get_robot_state", "get_safety_envelope", "lookup_transform", "list_controllers", "list_ros_graph",
        "get_audit_tail", "camera_snapshot", "stop_motion", "estop", "get_safety_status"}
    assert names(lambda spec: spec.stops_on_read) == {"stop_motion", "estop"}
    assert names(lambda spec: spec.rate_exempt) == {"stop_motion", "estop", "get_safety_status"}
    assert names(lambda spec: spec.answers_unrecorded) == {"stop_motion", "estop", "reset_estop", "get_safety_status"}
    assert names(lambda spec: spec.moves) == {"execute_plan", "gripper_move", "gripper_grasp", "gripper_home"}
    assert names(lambda spec: not spec.records_result) == {
        "get_robot_state", "get_safety_envelope", "lookup_transform", "list_controllers", "list_ros_graph",
        "get_audit_tail", "camera_snapshot", "get_plan", "get_motion_status", "get_safety_status"}
    assert names(lambda spec: not spec.hints.read_only) == {
        "execute_plan", "gripper_move", "gripper_grasp", "gripper_home", "switch_controllers",
        "set_collision_thresholds", "stop_motion", "estop", "reset_estop", "error_recovery"}
