"""The schema→strategy mapper (`armwarden.evaluation.schemas`) on the tools' own input schemas, as
the in-memory server lists them: valid mode conforms, invalid mode does not."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, cast

import anyio
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from armwarden.evaluation.schemas import MUTATIONS, closed, conforms, invalid_arguments, valid_arguments
from tests.server.harness import arm_harness

SETTINGS = settings(max_examples=30, database=None, derandomize=True, deadline=None, phases=[Phase.generate],
                    suppress_health_check=cast("list[HealthCheck]", list(HealthCheck)))


def _tool_schemas(tmp_path: Path) -> dict[str, dict[str, Any]]:
    """The input schemas as the daemon lists them (`tools/list`), from the in-memory server."""

    async def listed() -> dict[str, dict[str, Any]]:
        async with arm_harness(tmp_path) as harness, harness.client() as client:
            return {tool.name: dict(tool.input_schema) for tool in (await client.list_tools()).tools}

    return anyio.run(listed)


@pytest.fixture(scope="module")
def schemas(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict[str, Any]]:
    return _tool_schemas(tmp_path_factory.mktemp("schemas"))


def test_the_tools_use_schema_features_the_mapper_covers(schemas) -> None:
    assert {"plan_to_joints", "plan_cartesian_path", "execute_plan", "estop"} <= set(schemas)
    for schema in schemas.values():
        valid_arguments(schema)  # raises UnsupportedSchema for a keyword it does not map
        invalid_arguments(schema)


def _check_modes(name: str, schema: dict[str, Any], seen: set[str], only: tuple[str, ...] | None = None) -> None:
    @SETTINGS
    @given(valid_arguments(schema), invalid_arguments(schema, only))
    def check(valid: dict[str, Any], invalid: tuple[str, dict[str, Any]]) -> None:
        assert conforms(schema, valid), (name, valid)
        mutation, arguments = invalid
        assert mutation in MUTATIONS
        assert not conforms(schema, arguments), (name, mutation, arguments)
        seen.add(mutation)

    check()


def test_valid_mode_conforms_and_invalid_mode_does_not(schemas) -> None:
    for name, schema in sorted(schemas.items()):
        seen: set[str] = set()
        _check_modes(name, schema, seen)
        assert seen, name
    # the property mutations reach a tool with typed arguments: each drawn on its own (from all of
    # them, 30 examples can miss one, and which one depends on hypothesis's version)
    for mutation in ("wrong_type", "non_finite", "out_of_range", "unknown_key"):
        seen = set()
        _check_modes("gripper_grasp", schemas["gripper_grasp"], seen, only=(mutation,))
        assert seen == {mutation}, (mutation, seen)


def test_conforms_is_the_servers_contract() -> None:
    schema = {"type": "object", "properties": {"x": {"type": "number", "minimum": -1, "maximum": 1}}}
    assert conforms(schema, {"x": 0.5})
    assert not conforms(schema, {"x": math.nan})  # no NaN in JSON (jsonschema alone would pass it)
    assert not conforms(schema, {"x": math.inf})
    assert not conforms(schema, {"x": 0.5, "y": 1})  # undeclared names are refused by the server
    assert closed(schema)["additionalProperties"] is False


@SETTINGS
@given(st.data())
def test_every_mutation_breaks_a_typed_schema(data) -> None:
    schema = {"type": "object", "required": ["width_m"], "properties": {
        "width_m": {"type": "number", "minimum": 0.0, "maximum": 0.08},
        "name": {"type": "string", "minLength": 1, "maxLength": 8}}}
    mutation, arguments = data.draw(invalid_arguments(schema))
    assert not conforms(schema, arguments), (mutation, arguments)
