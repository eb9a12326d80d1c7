#!/usr/bin/env python3
"""Generate docs/policy.md and docs/tools.md from the code, so the reference can never drift.

* docs/policy.md comes from the pydantic policy models (`armwarden.policy.Policy` and every
  section model): each field with its YAML path, type, default, constraints and description, plus
  the cross-field rules each section enforces. Types and bounds come from the models' JSON schema;
  defaults (including `default_factory` ones) from `model_fields`.
* docs/tools.md comes from the tools the server really registers: the bundled FR3 policy on the
  fake backend, listed through the official MCP SDK client in memory (`tools/list`), exactly as a
  client sees them — names, group, annotations, parameters with their published bounds, result
  fields and descriptions.

Usage::

    python scripts/gen_docs.py           # rewrite both files
    python scripts/gen_docs.py --check   # exit 1 if either file is stale (CI, tests/test_docs.py)

The output is deterministic: no timestamps, fixed ordering, no machine-specific paths.
"""

from __future__ import annotations

import argparse
import inspect
import json
import logging
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from pydantic import BaseModel

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT / "src") not in sys.path:  # run from a checkout without installing
    sys.path.insert(0, str(ROOT / "src"))

from armwarden import policy as policy_module  # noqa: E402 - needs the sys.path set-up above
from armwarden.guard.order import GATES  # noqa: E402 - needs the sys.path set-up above
from armwarden.policy import TOOL_GROUPS, Policy  # noqa: E402 - needs the sys.path set-up above

POLICY_DOC = ROOT / "docs" / "policy.md"
TOOLS_DOC = ROOT / "docs" / "tools.md"
REGENERATE = "python scripts/gen_docs.py"

__all__ = ["POLICY_DOC", "REGENERATE", "TOOLS_DOC", "render_policy_doc", "render_tools_doc", "stale_docs"]


# ====================================================================== JSON-schema rendering helpers


def _escape(text: str) -> str:
    """Make text safe inside a Markdown table cell (one line, no stray pipes)."""
    return " ".join(str(text).split()).replace("|", "\\|")


def _code(value: str) -> str:
    return f"`{value}`" if "`" not in value else f"`` {value} ``"


def _number(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return repr(value) if isinstance(value, float) else str(value)


def _flow(value: Any) -> str:
    """A value as it would be written in the YAML file (flow style, `null`, `true`)."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return _number(value)
    if isinstance(value, str):
        return value if value and value.strip() == value and not any(c in value for c in ":#[]{},'\"") else json.dumps(value)
    if isinstance(value, BaseModel):
        return _flow(value.model_dump(mode="json"))
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_flow(v) for v in value) + "]"
    if hasattr(value, "items"):
        return "{" + ", ".join(f"{_flow(k)}: {_flow(v)}" for k, v in value.items()) + "}"
    return str(value)


class SchemaText:
    """Turns JSON-schema nodes into short human-readable types and constraint lists."""

    def __init__(self, defs: dict[str, Any], *, link_refs: bool = False, root: dict[str, Any] | None = None) -> None:
        self.defs = defs
        self.root = root if root is not None else {}  # the schema the `$defs` belong to
        self.link_refs = link_refs  # render `$ref`s as links to a "### Name" heading

    def ref_name(self, node: dict[str, Any]) -> str | None:
        ref = node.get("$ref")
        return ref.rsplit("/", 1)[-1] if isinstance(ref, str) else None

    def resolve(self, node: dict[str, Any]) -> dict[str, Any]:
        name = self.ref_name(node)
        return self.defs[name] if name is not None else node

    def object_name(self, node: dict[str, Any]) -> str | None:
        """The name of a structured object: a `$ref`, or an inline object schema with properties."""
        if (name := self.ref_name(node)) is not None:
            return name
        if node.get("type") == "object" and isinstance(node.get("properties"), dict):
            return str(node.get("title") or "object")
        return None

    @staticmethod
    def split_nullable(node: dict[str, Any]) -> tuple[dict[str, Any], bool]:
        """(the non-null branch, whether null is allowed) for `anyOf: [X, null]`."""
        options = node.get("anyOf")
        if isinstance(options, list):
            real = [o for o in options if o.get("type") != "null"]
            if len(real) == 1 and len(real) < len(options):
                merged = {k: v for k, v in node.items() if k != "anyOf"} | real[0]
                return merged, True
        return node, False

    def type_of(self, node: dict[str, Any]) -> str:
        node, nullable = self.split_nullable(node)
        text = self._type_of(node)
        return f"{text} or null" if nullable else text

    def _type_of(self, node: dict[str, Any]) -> str:
        if (name := self.object_name(node)) is not None:
            return f"mapping ({self._ref_text(name)})"
        if "const" in node:
            return f"{node.get('type', 'value')} {_code(_flow(node['const']))}"
        if "enum" in node:
            return "one of " + ", ".join(_code(_flow(v)) for v in node["enum"])
        if "anyOf" in node:
            return " or ".join(self.type_of(option) for option in node["anyOf"])
        kind = node.get("type")
        if kind == "array":
            if "prefixItems" in node:
                return "[" + ", ".join(self._type_of(item) for item in node["prefixItems"]) + "]"
            items = node.get("items", {})
            return f"list of {self._plural(items)}"
        if kind == "object":
            values = node.get("additionalProperties")
            if not isinstance(values, dict):
                pattern = node.get("patternProperties") or {}
                values = next(iter(pattern.values()), None)
            if isinstance(values, dict):
                return f"mapping of name → {self._type_of(values)}"
            return "mapping"
        if kind == "number":
            return "number"
        return str(kind) if kind else "any"

    def _ref_text(self, name: str) -> str:
        return f"[{name}](#{name.lower()})" if self.link_refs else name

    def _plural(self, items: dict[str, Any]) -> str:
        if (name := self.object_name(items)) is not None:
            return f"mappings ({self._ref_text(name)})"
        if "enum" in items:
            return "names from " + ", ".join(_code(_flow(v)) for v in items["enum"])
        text = self._type_of(items)
        plurals = {"string": "strings", "number": "numbers", "integer": "integers", "boolean": "booleans",
                   "mapping": "mappings"}
        return plurals.get(text, text)

    def constraints(self, node: dict[str, Any]) -> list[str]:
        node, _ = self.split_nullable(node)
        out: list[str] = []
        bounds = [("exclusiveMinimum", ">"), ("minimum", "≥"), ("exclusiveMaximum", "<"), ("maximum", "≤")]
        out += [f"{sign} {_number(node[key])}" for key, sign in bounds if key in node]
        if "maxLength" in node:
            out.append(f"length {node.get('minLength', 0)}..{node['maxLength']}")
        elif node.get("minLength", 0) >= 1:
            out.append("non-empty" if node["minLength"] == 1 else f"length ≥ {node['minLength']}")
        if "pattern" in node:
            out.append("no whitespace" if node["pattern"] == r"^\S+$" else f"matches {_code(node['pattern'])}")
        if node.get("type") == "array":
            lo, hi = node.get("minItems"), node.get("maxItems")
            if "prefixItems" not in node:
                if lo is not None and lo == hi:
                    out.append(f"exactly {lo} items")
                elif lo is not None and hi is not None:
                    out.append(f"{lo}..{hi} items")
                elif lo is not None:
                    out.append(f"at least {lo} item{'s' if lo != 1 else ''}")
                elif hi is not None:
                    out.append(f"at most {hi} items")
            items = node.get("items")
            if isinstance(items, dict) and self.ref_name(items) is None:
                inner = self.constraints(items)
                if inner:
                    out.append("each " + ", ".join(inner))
        if node.get("type") == "object":
            values = node.get("additionalProperties")
            if not isinstance(values, dict):
                values = next(iter((node.get("patternProperties") or {}).values()), None)
            if isinstance(values, dict) and self.ref_name(values) is None:
                inner = self.constraints(values)
                if inner:
                    out.append("each value " + ", ".join(inner))
        return out


# ====================================================================== docs/policy.md


def _policy_models() -> dict[str, type[BaseModel]]:
    return {
        obj.__name__: obj
        for obj in vars(policy_module).values()
        if isinstance(obj, type) and issubclass(obj, BaseModel) and obj.__module__.startswith(policy_module.__name__ + ".")
    }


def _nested(schema: SchemaText, node: dict[str, Any]) -> tuple[str, str] | None:
    """If the field holds a section model: (model name, path suffix: '', '[]' or '.<name>')."""
    node, _ = schema.split_nullable(node)
    if (name := schema.ref_name(node)) is not None:
        return name, ""
    items = node.get("items")
    if node.get("type") == "array" and isinstance(items, dict) and (name := schema.ref_name(items)) is not None:
        return name, "[]"
    if node.get("type") == "object":
        values = node.get("additionalProperties")
        if not isinstance(values, dict):
            values = next(iter((node.get("patternProperties") or {}).values()), None)
        if isinstance(values, dict) and (name := schema.ref_name(values)) is not None:
            return name, ".<name>"
    return None


def _rules_of(model: type[BaseModel]) -> list[str]:
    """The cross-field rules and normalisations a model applies, from its private methods."""
    out = []
    for attr, value in model.__dict__.items():
        if not attr.startswith("_") or attr.startswith("__") or attr == "_rules":
            continue
        fn = getattr(value, "__func__", value)
        fn = getattr(fn, "wrapped", fn)
        if not inspect.isfunction(fn):
            continue
        doc = inspect.getdoc(fn)
        title = attr.strip("_").replace("_", " ")
        out.append(f"- *{title}*" + (f": {_escape(doc.splitlines()[0])}" if doc else ""))
    return out


def _default_text(field: Any) -> str:
    if field.is_required():
        return "**required**"
    value = field.get_default(call_default_factory=True)
    if isinstance(value, BaseModel):
        return "section defaults"
    return _code(_flow(value))


def _field_rows(schema: SchemaText, models: dict[str, type[BaseModel]], name: str, prefix: str,
                sections: list[tuple[str, str, type[BaseModel], dict[str, Any]]]) -> list[str]:
    model = models[name]
    definition = schema.defs.get(name, schema.root)
    rows = []
    for field_name, field in model.model_fields.items():
        node = definition["properties"][field_name]
        path = f"{prefix}{field_name}"
        nested = _nested(schema, node)
        if nested is not None:
            child, suffix = nested
            sections.append((f"{path}{suffix}", child, models[child], schema.defs[child]))
        constraints = ", ".join(schema.constraints(node)) or "–"
        type_text = schema.type_of(node)
        if nested is not None:
            type_text += f", see [{_code(path + nested[1])}](#{_anchor(path + nested[1])})"
        rows.append(
            f"| {_code(path)} | {_escape(type_text)} | {_escape(_default_text(field))} | {_escape(constraints)} "
            f"| {_escape(field.description or '')} |"
        )
    return rows


def _anchor(path: str) -> str:
    """GitHub's heading anchor for a heading that is just `path` in backticks."""
    keep = [c for c in path.lower() if c.isalnum() or c in "-_ "]
    return "".join(keep).replace(" ", "-")


TABLE_HEAD = ["| YAML path | type | default | constraints | description |", "|---|---|---|---|---|"]


def render_policy_doc() -> str:
    """The full text of docs/policy.md."""
    root = Policy.model_json_schema(mode="validation")
    schema = SchemaText(root.get("$defs", {}), root=root)
    models = _policy_models()
    lines = [
        "# Policy reference",
        "",
        f"<!-- Generated by `{REGENERATE}` from `armwarden.policy.Policy`. Do not edit by hand. -->",
        "",
        "The safety policy is one YAML file, loaded once at start-up and immutable while the daemon runs.",
        "It is validated strictly: unknown keys, duplicate keys, wrong types (`true` for a number, `\"0.3\"`",
        "for a number), NaN and infinity are all errors, and every problem is reported with its YAML path.",
        "Run `armwarden check-policy FILE` to validate a file and print what it allows. The bundled",
        "`src/armwarden/robots/fr3/policy.yaml` is a fully commented example.",
        "",
        "Units are SI: metres, radians, seconds, newtons. Positions are in `robot.base_frame`. Numbers are",
        "finite; integers are accepted where a number is expected. In paths, `[]` stands for any list item",
        "and `<name>` for any mapping key (a joint or tool name).",
        "",
        "Hardware wiring (ROS names, CAN ids, MuJoCo scene) is not part of the policy: it lives in the",
        "separate `--backend-config` file.",
        "",
    ]
    sections: list[tuple[str, str, type[BaseModel], dict[str, Any]]] = []
    top_rows = _field_rows(schema, models, "Policy", "", sections)
    lines += ["## Top level", "", _escape(Policy.__doc__ or ""), "", *TABLE_HEAD, *top_rows, ""]
    rules = _rules_of(Policy)
    if rules:
        lines += ["Rules checked across sections:", "", *rules, ""]
    while sections:
        path, name, model, _definition = sections.pop(0)
        nested: list[tuple[str, str, type[BaseModel], dict[str, Any]]] = []
        prefix = f"{path}." if not path.endswith(".") else path
        rows = _field_rows(schema, models, name, prefix, nested)
        depth = "##" if "." not in path and "[" not in path else "###"
        lines += [f"{depth} {_code(path)}", "", f"{_escape(model.__doc__ or '')} (model `{name}`)", "", *TABLE_HEAD, *rows, ""]
        rules = _rules_of(model)
        if rules:
            lines += ["Rules:", "", *rules, ""]
        sections[0:0] = nested  # depth first: a section's sub-sections follow it
    lines += [
        "## Tool groups",
        "",
        "`tools.enabled` takes these groups; `safety` is always registered. A tool whose backend lacks the",
        "capability (no gripper, no camera, no controllers) is not registered either.",
        "",
        "| group | tools |",
        "|---|---|",
        *[f"| `{group}` | {', '.join(_code(t) for t in tools)} |" for group, tools in TOOL_GROUPS.items()],
        "",
    ]
    return "\n".join(lines).rstrip("\n") + "\n"


# ====================================================================== docs/tools.md


async def list_registered_tools() -> list[dict[str, Any]]:
    """`tools/list` of the server built from the bundled FR3 policy on the fake backend.

    Built like the daemon builds it (`armwarden.assembly`: real Guard, real ArmWardenServer), but
    without an audit log: listing tools writes nothing.
    """
    from mcp import Client

    from armwarden.assembly import build_backend, build_guard
    from armwarden.policy import bundled_policy, load_policy
    from armwarden.server.app import ArmWardenServer

    policy = load_policy(bundled_policy("fr3"))
    fake = build_backend("fake", policy, config={"speedup": 10.0})
    await fake.open()
    try:
        guard = build_guard(policy, fake, None)
        server = ArmWardenServer(guard)
        async with Client(server.mcp, mode="legacy") as client:
            result = await client.list_tools()
        return [tool.model_dump(by_alias=True, exclude_none=True, mode="json") for tool in result.tools]
    finally:
        await fake.close()


def _tool_order(tools: list[dict[str, Any]]) -> list[dict[str, Any]]:
    order = {name: i for i, name in enumerate(t for group in TOOL_GROUPS.values() for t in group)}
    return sorted(tools, key=lambda t: (order.get(t["name"], len(order)), t["name"]))


def _group_of(name: str) -> str:
    return next((group for group, tools in TOOL_GROUPS.items() if name in tools), "?")


def _parameter_rows(schema: SchemaText, node: dict[str, Any], prefix: str, required: set[str]) -> Iterator[str]:
    for name, prop in node.get("properties", {}).items():
        path = f"{prefix}{name}"
        inner, _nullable = schema.split_nullable(prop)
        if name in required:
            default = "**required**"
        elif "default" in prop:
            default = _code(_flow(prop["default"]))
        else:
            default = "optional"
        type_text = schema.type_of(prop)
        constraints = ", ".join(schema.constraints(prop)) or "–"
        description = prop.get("description", "")
        if description == "":
            resolved = schema.resolve(inner)
            description = resolved.get("description", "") if resolved is not inner else ""
        yield (f"| {_code(path)} | {_escape(type_text)} | {_escape(default)} | {_escape(constraints)} "
               f"| {_escape(description)} |")
        # expand nested objects (a Point, a list of Waypoints) so every bound is visible
        target, suffix = inner, ""
        if inner.get("type") == "array" and isinstance(inner.get("items"), dict) and schema.object_name(inner["items"]):
            target, suffix = inner["items"], "[]"
        if schema.object_name(target) is not None:
            sub = schema.resolve(target)
            yield from _parameter_rows(schema, sub, f"{path}{suffix}.", set(sub.get("required", [])))


ANNOTATION_KEYS = [("readOnlyHint", "read-only"), ("destructiveHint", "destructive"),
                   ("idempotentHint", "idempotent"), ("openWorldHint", "open-world")]


def _annotations_text(annotations: dict[str, Any]) -> str:
    parts = []
    for key, label in ANNOTATION_KEYS:
        if key in annotations:
            parts.append(f"{label}: {'yes' if annotations[key] else 'no'}")
    return ", ".join(parts) or "none"


def _result_defs(tools: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Every named object type nested in an output schema (`$defs` entries and inline objects)."""
    defs: dict[str, dict[str, Any]] = {}

    def visit(node: Any, schema: SchemaText, top: bool) -> None:
        if isinstance(node, list):
            for item in node:
                visit(item, schema, False)
            return
        if not isinstance(node, dict):
            return
        name = schema.object_name(node)
        if name is not None and not top:
            resolved = schema.resolve(node)
            if name not in defs:
                defs[name] = resolved
                visit(resolved, schema, True)
        for key, value in node.items():
            if key != "$defs":
                visit(value, schema, False)

    for tool in tools:
        output = tool.get("outputSchema") or {}
        schema = SchemaText(output.get("$defs", {}))
        visit(output, schema, True)
        for definition in output.get("$defs", {}).values():
            visit(definition, schema, False)
    return dict(sorted(defs.items()))


def _output_rows(schema: SchemaText, node: dict[str, Any]) -> Iterator[str]:
    required = set(node.get("required", []))
    for name, prop in node.get("properties", {}).items():
        optional = "" if name in required else " (optional)"
        yield f"| {_code(name)} | {_escape(schema.type_of(prop))}{optional} | {_escape(prop.get('description', ''))} |"


def render_tools_doc(tools: list[dict[str, Any]] | None = None) -> str:
    """The full text of docs/tools.md (lists the tools itself unless `tools` is given)."""
    if tools is None:
        import anyio

        tools = anyio.run(list_registered_tools)
    tools = _tool_order(tools)
    lines = [
        "# Tool reference",
        "",
        f"<!-- Generated by `{REGENERATE}` from the server's own `tools/list`. Do not edit by hand. -->",
        "",
        "These are the tools ArmWarden registers with the bundled FR3 policy (`fr3.yaml`, every group",
        "enabled) on the fake backend, exactly as an MCP client receives them from `tools/list`. Another",
        "policy registers only the groups it enables (`safety` always), a backend without a capability",
        "(gripper, cameras, controllers, error recovery) drops those tools, and the bounds below (joint",
        "count and limits, gripper ranges, force caps, scaling caps) are the policy's, so they change",
        "with it.",
        "",
        "Units: metres, radians, seconds, newtons; positions in the robot base frame; quaternions xyzw.",
        "Every tool returns `structuredContent` matching its output schema; `plan_*` also return a PNG",
        "preview and `camera_snapshot` the image. A refusal is an `isError` result whose text starts",
        "with `REFUSED [CODE]` and says what a human must do.",
        "",
        "| tool | group | read-only | destructive | idempotent | open-world |",
        "|---|---|---|---|---|---|",
    ]
    for tool in tools:
        ann = tool.get("annotations", {})
        cells = ["yes" if ann.get(key) else "no" for key, _ in ANNOTATION_KEYS]
        lines.append(f"| [{_code(tool['name'])}](#{tool['name']}) | {_group_of(tool['name'])} | " + " | ".join(cells) + " |")
    lines.append("")
    current_group = None
    for tool in tools:
        group = _group_of(tool["name"])
        if group != current_group:
            lines += [f"## Group `{group}`", ""]
            current_group = group
        input_schema = tool.get("inputSchema") or {}
        schema = SchemaText(input_schema.get("$defs", {}))
        lines += [
            f"### {tool['name']}",
            "",
            _escape(tool.get("description", "")),
            "",
            f"Annotations: {_annotations_text(tool.get('annotations', {}))}.",
            "",
        ]
        if tool["name"] in GATES:
            lines += ["Gates, in order (the first that fails refuses; `guard/order.py`): "
                      + " → ".join(gate.name for gate in GATES[tool["name"]]) + ".", ""]
        rows = list(_parameter_rows(schema, input_schema, "", set(input_schema.get("required", []))))
        if rows:
            lines += ["Parameters:", "", "| parameter | type | default | bounds | description |",
                      "|---|---|---|---|---|", *rows, ""]
        else:
            lines += ["Parameters: none.", ""]
        output = tool.get("outputSchema")
        if output:
            out_schema = SchemaText(output.get("$defs", {}), link_refs=True)
            lines += [f"Result ({_code(output.get('title', 'result'))}):", "", "| field | type | description |",
                      "|---|---|---|", *_output_rows(out_schema, output), ""]
    defs = _result_defs(tools)
    if defs:
        lines += ["## Result types", "", "Nested types used in the results above.", ""]
        for name, definition in defs.items():
            schema = SchemaText(defs, link_refs=True)
            lines += [f"### {name}", ""]
            if definition.get("enum"):
                lines += [f"One of {', '.join(_code(_flow(v)) for v in definition['enum'])}.", ""]
                continue
            if definition.get("description"):
                lines += [_escape(definition["description"]), ""]
            lines += ["| field | type | description |", "|---|---|---|", *_output_rows(schema, definition), ""]
    return "\n".join(lines).rstrip("\n") + "\n"


# ====================================================================== command line


def stale_docs() -> list[Path]:
    """The generated files whose content differs from what the code produces now."""
    stale = []
    for path, text in ((POLICY_DOC, render_policy_doc()), (TOOLS_DOC, render_tools_doc())):
        if not path.exists() or path.read_text(encoding="utf-8") != text:
            stale.append(path)
    return stale


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").strip().splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if a generated file is stale; write nothing")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr)
    if args.check:
        stale = stale_docs()
        for path in stale:
            print(f"stale: {path.relative_to(ROOT)} (regenerate with `{REGENERATE}`)", file=sys.stderr)
        return 1 if stale else 0
    for path, text in ((POLICY_DOC, render_policy_doc()), (TOOLS_DOC, render_tools_doc())):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
        print(f"wrote {path.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
