"""Sanitising what goes into a record: strict JSON, bounded size, no pixels or raw bytes.

Tool arguments and results come from an untrusted model (and images from cameras), so a record
must never carry megabytes of base64, a NaN the strict JSON writer would refuse, or an object
whose ``repr`` raises. `sanitize` turns anything into a bounded, strict-JSON-safe value and never
raises.
"""

from __future__ import annotations

import datetime as _dt
import decimal
import enum
import itertools
import json
import math
import os
import uuid
from collections import deque
from collections.abc import Mapping
from dataclasses import fields, is_dataclass
from typing import Any

__all__ = ["Sanitizer", "sanitize"]

_IMAGE_KEYS = frozenset({"image", "png", "jpeg", "jpg", "image_bytes", "image_data", "image_base64"})
_IMAGE_KEY_MIN_CHARS = 64  # shorter strings under an image-ish key are names, not pixels


class Sanitizer:
    __slots__ = ("budget", "max_chars", "max_depth", "max_items")

    def __init__(self, max_chars: int, max_depth: int, max_items: int, max_nodes: int) -> None:
        self.max_chars = max(1, int(max_chars))
        self.max_depth = max(1, int(max_depth))
        self.max_items = max(1, int(max_items))
        self.budget = max(1, int(max_nodes))

    # -- scalars ---------------------------------------------------------------------------
    def text(self, s: str, limit: int | None = None) -> str:
        limit = self.max_chars if limit is None else limit
        s = str.__str__(s)  # plain str even for subclasses with a hostile __str__
        n = len(s)
        if n > limit:
            s = s[:limit]
        try:
            s.encode("utf-8")
        except UnicodeEncodeError:  # lone surrogates cannot be written as UTF-8
            s = s.encode("utf-8", "replace").decode("utf-8")
        if n > limit:
            s = f"{s}…[truncated {n - limit} chars]"
        return s

    @staticmethod
    def redacted(value: Any) -> str:
        try:
            if isinstance(value, memoryview):
                size = value.nbytes
            elif isinstance(value, str):
                size = len(value)
            else:
                size = len(value)
        except Exception:
            size = -1
        return f"<redacted {size} bytes>" if size >= 0 else "<redacted>"

    @staticmethod
    def type_name(value: Any) -> str:
        try:
            name = type(value).__qualname__
            return name if isinstance(name, str) else "object"
        except Exception:
            return "object"

    def repr_of(self, value: Any) -> str:
        try:
            r = repr(value)
            if not isinstance(r, str):
                raise TypeError
        except Exception:
            return f"<unrepresentable {self.type_name(value)}>"
        return self.text(r)

    # -- walk ------------------------------------------------------------------------------
    def walk(self, v: Any, depth: int) -> Any:
        try:
            return self._walk(v, depth)
        except Exception:  # never raise, whatever the object does
            return f"<unserializable {self.type_name(v)}>"

    def _walk(self, v: Any, depth: int) -> Any:
        self.budget -= 1
        if self.budget < 0:
            return "…[omitted: record size limit]"
        if v is None or v is True or v is False:
            return v
        if isinstance(v, bool):
            return bool(v)
        if isinstance(v, float):
            f = float.__float__(v)
            if math.isnan(f):
                return "nan"
            if math.isinf(f):
                return "inf" if f > 0 else "-inf"
            return f
        if isinstance(v, int):
            n = int.__index__(v)
            if n.bit_length() <= 128:
                return n
            return f"<int with {n.bit_length()} bits>"
        if isinstance(v, str):
            if v.startswith("data:image/"):
                return self.redacted(v)
            return self.text(v)
        if isinstance(v, (bytes, bytearray, memoryview)):
            return self.redacted(v)
        if isinstance(v, enum.Enum):
            return self.walk(v.value, depth)
        if isinstance(v, (_dt.datetime, _dt.date, _dt.time)):
            return self.text(v.isoformat())
        if isinstance(v, (uuid.UUID, decimal.Decimal)):
            return self.text(str(v))
        if isinstance(v, os.PathLike):
            p = os.fspath(v)
            return self.text(p) if isinstance(p, str) else self.redacted(p)
        if depth >= self.max_depth:
            return "…[max depth reached]"
        if isinstance(v, Mapping):
            return self.mapping(v, depth)
        if isinstance(v, (list, tuple, set, frozenset, deque)):
            return self.sequence(v, depth)
        return self.other(v, depth)

    def sequence(self, v: Any, depth: int) -> list[Any]:
        out: list[Any] = []
        total = len(v)
        for item in itertools.islice(v, self.max_items):
            if self.budget <= 0:
                break
            out.append(self.walk(item, depth + 1))
        if len(out) < total:
            out.append(f"…[{total - len(out)} more items]")
        return out

    def key(self, k: Any) -> str:
        if isinstance(k, str):
            return self.text(k)
        if k is None or isinstance(k, (bool, int, float)):
            s = self.walk(k, self.max_depth)
            return s if isinstance(s, str) else json.dumps(s)
        return self.repr_of(k)

    def mapping(self, v: Mapping[Any, Any], depth: int) -> dict[str, Any]:
        try:
            kind = v.get("type")
            mime = v.get("mimeType", v.get("mime_type"))
        except Exception:
            kind = mime = None
        image_dict = kind == "image" or (isinstance(mime, str) and mime.startswith("image/"))
        out: dict[str, Any] = {}
        total = len(v)
        taken = 0
        for k, val in itertools.islice(v.items(), self.max_items):
            if self.budget <= 0:
                break
            taken += 1
            key = self.key(k)
            base, n = key, 2
            while key in out:
                key, n = f"{base}#{n}", n + 1
            lowered = key.lower()
            if isinstance(val, (bytes, bytearray, memoryview)) or (
                isinstance(val, str)
                and (
                    (image_dict and lowered == "data")
                    or (lowered in _IMAGE_KEYS and len(val) >= _IMAGE_KEY_MIN_CHARS)
                )
            ):
                self.budget -= 1
                out[key] = self.redacted(val)
            else:
                out[key] = self.walk(val, depth + 1)
        if taken < total:
            out["…"] = f"[{total - taken} more keys]"
        return out

    def other(self, v: Any, depth: int) -> Any:
        mod = getattr(type(v), "__module__", "") or ""
        if mod.startswith("numpy"):
            dtype = getattr(v, "dtype", None)
            size = getattr(v, "size", 1)
            ndim = getattr(v, "ndim", 0)
            if ndim >= 2 and str(dtype) == "uint8":  # pixels
                return f"<redacted {int(getattr(v, 'nbytes', size))} bytes>"
            if ndim == 0 and hasattr(v, "item"):
                return self.walk(v.item(), depth)
            if isinstance(size, int) and size <= self.max_items * 4 and hasattr(v, "tolist"):
                return self.walk(v.tolist(), depth)
            return self.text(f"<ndarray shape={getattr(v, 'shape', '?')} dtype={dtype}>")
        dump = getattr(v, "model_dump", None)  # pydantic models (e.g. MCP ImageContent)
        if callable(dump) and not isinstance(v, type):
            return self.walk(dump(mode="python"), depth)
        if is_dataclass(v) and not isinstance(v, type):
            return self.walk({f.name: getattr(v, f.name, None) for f in fields(v)}, depth)
        return self.repr_of(v)


def sanitize(
    value: Any,
    *,
    max_string_chars: int = 500,
    max_depth: int = 8,
    max_items: int = 200,
    max_nodes: int = 2000,
) -> Any:
    """Return a strict-JSON-safe copy of ``value``; pure, never raises.

    Strings longer than ``max_string_chars`` are cut with ``…[truncated N chars]``; bytes and
    image payloads become ``"<redacted N bytes>"``; NaN/±Inf become ``"nan"``/``"inf"``/``"-inf"``;
    containers deeper than ``max_depth`` or longer than ``max_items`` are cut with a marker; the
    whole value is bounded by ``max_nodes``; unknown objects become their (truncated) ``repr``.
    """
    try:
        return Sanitizer(max_string_chars, max_depth, max_items, max_nodes).walk(value, 0)
    except BaseException as exc:
        if isinstance(exc, (KeyboardInterrupt, SystemExit, GeneratorExit)):
            raise
        return "<unserializable>"
