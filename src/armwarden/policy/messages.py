"""Error messages for the person editing the YAML file: each pydantic error at its YAML path.

Reusable for any strict YAML config built the same way (e.g. a backend config).
"""

from __future__ import annotations

import difflib
import math
import types
import typing
from collections.abc import Mapping, Sequence
from typing import Annotated, Any, Union

from pydantic import BaseModel, ValidationError

from armwarden.policy.constants import DOCUMENT_PATH
from armwarden.policy.fields import RuleViolations


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
        if isinstance(rule, RuleViolations):
            errors.extend((format_path(loc + relative), message) for relative, message in rule.violations)
        elif error["type"] == "missing" and loc and isinstance(loc[-1], int):
            # a fixed-length list (e.g. [x, y, z]) that is too short: one error for the list itself
            items = typing.get_args(_type_at(root, loc[:-1]))
            errors.append((format_path(loc[:-1]), f"must have exactly {len(items)} items (too few given)"))
        else:
            errors.append((format_path(loc), _humanise(error, root)))
    return list(dict.fromkeys(errors))  # drop repeats, keep order


def show_value(value: Any) -> str:
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


_BOUND_WORDS = {
    "greater_than": ("gt", "greater than"),
    "greater_than_equal": ("ge", "at least"),
    "less_than": ("lt", "less than"),
    "less_than_equal": ("le", "at most"),
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
        return f"must be {_TYPE_WORDS[kind]} (got {show_value(value)})"
    if kind == "finite_number":
        return f"must be a finite number (got {show_value(value)})"
    if kind == "literal_error":
        expected = str(error["ctx"]["expected"])
        choice = "one of " if " or " in expected else ""
        return f"must be {choice}{expected} (got {show_value(value)})"
    if kind == "string_pattern_mismatch":
        return f"must be a name without whitespace (got {show_value(value)})"
    if kind == "string_too_short":
        return "must not be empty"
    if kind in _BOUND_WORDS:
        key, words = _BOUND_WORDS[kind]
        field = _field_at(root, loc)
        about = f" ({field.description})" if field is not None and field.description else ""
        return f"must be {words} {error['ctx'][key]} (got {show_value(value)}){about}"
    if kind == "value_error":
        return str(error["msg"]).removeprefix("Value error, ")
    message = str(error["msg"]).replace("Input should", "must").replace("Tuple should", "must")
    message = message.replace("String should", "must").replace("Dictionary should", "must")
    if not isinstance(value, (Mapping, list, tuple)):
        message += f" (got {show_value(value)})"
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

