"""Reading a policy: bounded file read, YAML without duplicate keys, validation into a `Policy`."""

from __future__ import annotations

import copy
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from armwarden.core.errors import PolicyError
from armwarden.policy.constants import DOCUMENT_PATH, MAX_POLICY_BYTES
from armwarden.policy.messages import validation_errors
from armwarden.policy.models import Policy
from armwarden.robots import bundled_policies


def bundled_policy(name: str = "fr3") -> Path:
    """Path of a policy shipped inside the package, by name (`fr3`, `readonly`: each robot
    profile lists its own, `armwarden.robots`)."""
    policies = bundled_policies()
    if name not in policies:
        raise PolicyError(f"bundled policy {name!r}", [(DOCUMENT_PATH, f"no such bundled policy; bundled: {', '.join(sorted(policies))}")])
    return policies[name]


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
        document = yaml.load(text, Loader=_PolicyLoader)  # safe: _PolicyLoader is a SafeLoader
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

