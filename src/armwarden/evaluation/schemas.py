"""Hypothesis strategies from the tools' own input schemas: valid arguments, and invalid ones.

Why a small mapper of our own rather than `hypothesis-jsonschema`: that package is not in the
project's dependencies nor its wheelhouse, its last release (0.23.1) is from February 2024, and it
only generates *valid* instances, while the fuzz needs invalid ones just as much. The schemas the
daemon lists (`tools/list`, pydantic-made) use a small subset of JSON Schema, and this module maps
exactly that subset: `type` (object, string, number, integer, boolean, array, null, or a list of
them), `properties`, `required`, `additionalProperties: false`, `$ref` into `$defs`, `anyOf`,
`minimum`, `maximum`, `exclusiveMinimum`, `exclusiveMaximum`, `minLength`, `maxLength`, `items`,
`minItems`, `maxItems`, `enum`, `const`, and an empty schema (any JSON value). A keyword outside that subset
raises `UnsupportedSchema` so a new tool cannot silently be fuzzed with the wrong shapes.

Validity is the server's contract, not bare JSON Schema (`conforms`): a tool refuses argument
names it does not declare (`ArmWardenServer._unknown_arguments`), so objects are closed; and
JSON has no NaN or infinity, so a non-finite float never conforms (jsonschema itself lets NaN pass
`minimum`/`maximum`, as every comparison with NaN is false).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import jsonschema
from hypothesis import strategies as st

__all__ = ["MUTATIONS", "UnsupportedSchema", "closed", "conforms", "invalid_arguments", "valid_arguments"]

#: keywords the mapper understands; annotations (title, description, default) change nothing
_KNOWN = frozenset({
    "type", "properties", "required", "additionalProperties", "$ref", "$defs", "anyOf", "minimum", "maximum",
    "exclusiveMinimum", "exclusiveMaximum", "minLength", "maxLength", "items", "minItems", "maxItems", "enum",
    "const", "title", "description", "default", "examples",
})
#: the longest string a valid value gets (a schema's maxLength may be larger: long strings are the
#: invalid mode's job, and short ones keep the valid calls quick)
VALID_TEXT_MAX = 64
#: sizes of the huge strings of the invalid mode, as JSON text [bytes]: the last is the issue's
#: "1 MB string", kept under both transports' documented request limits (HTTP: a body over 1 MiB
#: is refused with 413; stdio: a line over 4 MiB is dropped, so its id cannot be answered) — a
#: request over them is a malformed request, the unsafe scenarios' business, not a tool call
HUGE_BYTES = (4_096, 65_536, 1_000_000)
#: the characters a huge string repeats, with their size in JSON text [bytes]
HUGE_CHARS = {"x": 1, "\u00e9": 2, "\x00": 6, "\u2028": 3}
#: control characters and look-alikes a string may carry: C0, DEL, C1, line/paragraph separators,
#: bidi overrides, zero-width joiner, BOM
CONTROL_CHARS = "".join(chr(c) for c in range(0x20)) + "\x7f\x85\x9b\u2028\u2029\u202e\u2066\u200d\ufeff"
#: how deep the invalid mode nests lists and objects: below the depth the SDK's JSON parser reads
#: (between 130 and 200 levels with the request's envelope), so every call reaches the daemon's
#: tools; a deeper request is unreadable JSON, the malformed-input scenario's business
MAX_NESTING = 120
#: the invalid mutations, each named in a finding's report
MUTATIONS = ("wrong_type", "non_finite", "out_of_range", "huge_string", "control_characters", "deep_nesting",
             "unknown_key", "missing_required")


class UnsupportedSchema(ValueError):
    """A schema uses a keyword this mapper does not map (see the module docstring)."""


def closed(schema: Mapping[str, Any]) -> dict[str, Any]:
    """`schema` with every object closed (`additionalProperties: false`): the server's contract."""

    def close(node: Any) -> Any:
        if isinstance(node, dict):
            out = {key: close(value) for key, value in node.items()}
            if out.get("type") == "object" or "properties" in out:
                out.setdefault("additionalProperties", False)
            return out
        if isinstance(node, list):
            return [close(value) for value in node]
        return node

    return close(dict(schema))


def _finite(value: Any) -> bool:
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, dict):
        return all(_finite(v) for v in value.values())
    if isinstance(value, list):
        return all(_finite(v) for v in value)
    return True


def conforms(schema: Mapping[str, Any], value: Any) -> bool:
    """Whether `value` is valid arguments for a tool with input `schema` (closed objects, finite numbers)."""
    return _finite(value) and jsonschema.Draft202012Validator(closed(schema)).is_valid(value)


def _resolve(node: Mapping[str, Any], root: Mapping[str, Any]) -> Mapping[str, Any]:
    ref = node.get("$ref")
    if ref is None:
        return node
    prefix = "#/$defs/"
    if not isinstance(ref, str) or not ref.startswith(prefix) or ref[len(prefix):] not in root.get("$defs", {}):
        raise UnsupportedSchema(f"unresolvable $ref {ref!r}")
    return _resolve(root["$defs"][ref[len(prefix):]], root)


def _json_values() -> st.SearchStrategy[Any]:
    """Any JSON value (small): what an empty schema accepts."""
    scalars = st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False, allow_infinity=False) | st.text(max_size=16)
    return st.recursive(scalars, lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=8), inner, max_size=3),
                        max_leaves=6)


def _types_of(node: Mapping[str, Any]) -> list[str]:
    kind = node.get("type")
    if kind is None:
        return []
    return [kind] if isinstance(kind, str) else list(kind)


def _valid(node: Mapping[str, Any], root: Mapping[str, Any]) -> st.SearchStrategy[Any]:
    node = _resolve(node, root)
    unknown = set(node) - _KNOWN
    if unknown:
        raise UnsupportedSchema(f"schema keywords not mapped: {sorted(unknown)}")
    if "const" in node:
        return st.just(node["const"])
    if "enum" in node:
        return st.sampled_from(list(node["enum"]))
    if "anyOf" in node:
        return st.one_of([_valid(option, root) for option in node["anyOf"]])
    kinds = _types_of(node)
    if not kinds:
        return _json_values()
    return st.one_of([_valid_of_type(kind, node, root) for kind in kinds])


def _valid_of_type(kind: str, node: Mapping[str, Any], root: Mapping[str, Any]) -> st.SearchStrategy[Any]:
    if kind == "null":
        return st.none()
    if kind == "boolean":
        return st.booleans()
    if kind == "integer":
        low, high = node.get("minimum"), node.get("maximum")
        if "exclusiveMinimum" in node:
            low = math.floor(node["exclusiveMinimum"]) + 1
        if "exclusiveMaximum" in node:
            high = math.ceil(node["exclusiveMaximum"]) - 1
        return st.integers(None if low is None else math.ceil(low), None if high is None else math.floor(high))
    if kind == "number":
        low, high = node.get("minimum"), node.get("maximum")
        exclude_low = exclude_high = False
        if "exclusiveMinimum" in node:
            low, exclude_low = node["exclusiveMinimum"], True
        if "exclusiveMaximum" in node:
            high, exclude_high = node["exclusiveMaximum"], True
        return st.floats(low, high, exclude_min=exclude_low, exclude_max=exclude_high, allow_nan=False,
                         allow_infinity=False)
    if kind == "string":
        low = int(node.get("minLength", 0))
        high = max(low, min(int(node.get("maxLength", VALID_TEXT_MAX)), VALID_TEXT_MAX))
        ordinary = st.text(min_size=low, max_size=high)  # any Unicode but surrogates, controls included
        hostile = st.text(st.sampled_from(CONTROL_CHARS), min_size=max(low, 1), max_size=high) if high >= 1 else ordinary
        return ordinary | hostile
    if kind == "array":
        items = node.get("items", {})
        return st.lists(_valid(items, root), min_size=int(node.get("minItems", 0)),
                        max_size=int(node.get("maxItems", max(int(node.get("minItems", 0)), 8))))
    if kind == "object":
        properties = node.get("properties", {})
        required = set(node.get("required", ()))
        return st.fixed_dictionaries(
            {name: _valid(sub, root) for name, sub in properties.items() if name in required},
            optional={name: _valid(sub, root) for name, sub in properties.items() if name not in required},
        )
    raise UnsupportedSchema(f"type {kind!r} not mapped")


def valid_arguments(schema: Mapping[str, Any]) -> st.SearchStrategy[dict[str, Any]]:
    """Arguments that conform to a tool's input `schema` (an object schema)."""
    return _valid(schema, schema)


def _wrong_type_values(node: Mapping[str, Any]) -> st.SearchStrategy[Any]:
    """Values of a JSON type `node` does not allow (none for an untyped node: `conforms` filters)."""
    allowed = set(_types_of(node))
    if "anyOf" in node:
        allowed |= {kind for option in node["anyOf"] for kind in _types_of(option) if isinstance(option, Mapping)}
    candidates: dict[str, st.SearchStrategy[Any]] = {
        "string": st.text(max_size=8),
        "integer": st.integers(),
        "number": st.floats(allow_nan=False, allow_infinity=False).filter(lambda x: not x.is_integer()),
        "boolean": st.booleans(),
        "null": st.none(),
        "array": st.lists(st.integers(), max_size=3),
        "object": st.dictionaries(st.text(max_size=4), st.integers(), max_size=2),
    }
    if "number" in allowed:
        allowed.add("integer")  # an integer is a number
    options = [strategy for kind, strategy in candidates.items() if kind not in allowed]
    return st.one_of(options) if options else st.nothing()


def _nested(depth: int) -> Any:
    value: Any = 0
    for level in range(depth):
        value = [value] if level % 2 else {"n": value}
    return value


@st.composite
def _mutated(draw: st.DrawFn, schema: Mapping[str, Any], mutation: str) -> dict[str, Any]:
    """A valid object of `schema` with one `mutation` applied (it may still conform: `invalid_arguments` filters)."""
    arguments: dict[str, Any] = dict(draw(valid_arguments(schema)))
    properties: dict[str, Any] = {name: dict(_resolve(sub, schema)) for name, sub in schema.get("properties", {}).items()}
    names = _typed(schema)
    if mutation == "unknown_key" or (not names and mutation != "missing_required"):
        key = draw(st.text(min_size=1, max_size=16) | st.text(st.sampled_from(CONTROL_CHARS), min_size=1, max_size=8))
        arguments[key if key not in properties else key + "_unknown"] = draw(_json_values())
        return arguments
    if mutation == "missing_required":
        required = sorted(schema.get("required", ()))
        if required:
            arguments.pop(draw(st.sampled_from(required)), None)
        else:  # nothing to leave out: an undeclared name instead
            arguments["unknown_" + draw(st.text("abcdef", min_size=1, max_size=6))] = 1
        return arguments
    name = draw(st.sampled_from(names))
    target = properties[name]
    if mutation == "wrong_type":
        arguments[name] = draw(_wrong_type_values(target))
    elif mutation == "non_finite":
        bad = draw(st.sampled_from([math.nan, math.inf, -math.inf]))
        current = arguments.get(name)
        if isinstance(current, list) and current:  # one element of an array (joint positions)
            index = draw(st.integers(0, len(current) - 1))
            arguments[name] = [*current[:index], bad, *current[index + 1:]]
        else:
            arguments[name] = bad
    elif mutation == "out_of_range":
        arguments[name] = draw(st.sampled_from([-1e308, -1e6, -11.0, -1.0, 0.0, 101.0, 1e6, 1e308, 2**63, -(2**63)]))
    elif mutation == "huge_string":
        size, char = draw(st.sampled_from(HUGE_BYTES)), draw(st.sampled_from(sorted(HUGE_CHARS)))
        arguments[name] = char * (size // HUGE_CHARS[char])
    elif mutation == "control_characters":
        low = int(target.get("maxLength", 0)) + 1
        arguments[name] = draw(st.text(st.sampled_from(CONTROL_CHARS), min_size=low, max_size=low + 16))
    elif mutation == "deep_nesting":
        arguments[name] = _nested(draw(st.integers(2, MAX_NESTING)))
    return arguments


def _typed(schema: Mapping[str, Any]) -> list[str]:
    """The property names whose schema constrains the value (an untyped one accepts anything)."""
    return sorted(name for name, sub in schema.get("properties", {}).items()
                  if _types_of(_resolve(sub, schema)) or "anyOf" in sub or "$ref" in sub)


def invalid_arguments(schema: Mapping[str, Any],
                      only: Sequence[str] | None = None) -> st.SearchStrategy[tuple[str, dict[str, Any]]]:
    """(mutation, arguments) where the arguments do not conform to `schema`: one of `MUTATIONS`
    (or of `only`, a subset of them) applied to valid arguments (a property mutation only where
    some property is typed); a mutation that happened to conform is drawn again."""
    mutations = MUTATIONS if _typed(schema) else ("unknown_key", "missing_required")
    if only is not None:
        unknown = sorted(set(only) - set(MUTATIONS))
        if unknown:
            raise ValueError(f"unknown mutations {unknown}; known: {', '.join(MUTATIONS)}")
        mutations = tuple(m for m in mutations if m in only)
    options = [_mutated(schema, mutation).map(lambda value, m=mutation: (m, value)) for mutation in mutations]
    return st.one_of(options).filter(lambda pair: not conforms(schema, pair[1]))
