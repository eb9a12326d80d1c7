"""What a caller records (`AuditEntry`) and how it becomes the chain's next line (`RecordMaker`).

Apart from the log's file and threads so that what a record holds (sanitised, bounded fields;
seq, times and the chain added) is read in one place, next to `chain`'s hashing.
"""

from __future__ import annotations

import json
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from armwarden.audit.chain import AuditRecord, canonical_json, digest, utc_now, with_hash
from armwarden.audit.sanitise import Sanitizer, sanitize

__all__ = ["MAX_EVENT_CHARS", "AuditEntry", "RecordMaker", "entry_of"]

MAX_EVENT_CHARS = 64


@dataclass(frozen=True, slots=True)
class AuditEntry:
    """What a caller records: the event and its context. The log adds seq, times and the chain.

    Values are sanitised on write (`sanitize`), so anything may be passed; `AuditLog.append`
    also takes the same fields as keywords after the event name.
    """

    event: str
    session: str | None = None
    principal: str | None = None
    tool: str | None = None
    arguments: Any = None
    outcome: str | None = None
    detail: str | None = None
    operator: str | None = None
    extra: Mapping[str, Any] | None = None


def entry_of(entry: AuditEntry | str, fields: Mapping[str, Any]) -> AuditEntry:
    """`append(AuditEntry(...))` or `append("event", tool=..., ...)`, never a mix of both."""
    if isinstance(entry, AuditEntry):
        if fields:
            raise TypeError(f"pass either an AuditEntry or an event name with keywords, not both: {sorted(fields)}")
        return entry
    return AuditEntry(entry, **fields)


@dataclass(frozen=True)
class RecordMaker:
    """Turns entries into hashed records of one log: its key (None: plain SHA-256) and its bound
    on string fields. Stateless: the log passes the chain's head in."""

    key: bytes | None
    max_chars: int
    _texter: Sanitizer = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_texter", Sanitizer(self.max_chars, 1, 1, 1))  # text() only; stateless

    def _text_field(self, value: Any) -> str | None:
        if value is None:
            return None
        if not isinstance(value, str):
            value = sanitize(value, max_string_chars=self.max_chars)
            if not isinstance(value, str):
                value = json.dumps(value, ensure_ascii=False, allow_nan=False)
        return self._texter.text(value)

    def build(self, entry: AuditEntry, seq: int, prev: str) -> tuple[AuditRecord, bytes]:
        """The record after the one numbered `seq` with hash `prev`, and its line (newline ended)."""
        event = entry.event
        if not isinstance(event, str) or not event or len(event) > MAX_EVENT_CHARS:
            raise ValueError(f"audit event must be a non-empty str of at most {MAX_EVENT_CHARS} chars")
        event = self._texter.text(event, MAX_EVENT_CHARS)
        extra: Any = entry.extra
        if extra is not None:
            extra = sanitize(extra, max_string_chars=self.max_chars)
            if not isinstance(extra, dict):
                extra = {"value": extra}
        body: dict[str, Any] = {
            "seq": seq + 1,
            "wall_time": utc_now(),
            "mono_time": time.monotonic(),
            "event": event,
            "session": self._text_field(entry.session),
            "principal": self._text_field(entry.principal),
            "tool": self._text_field(entry.tool),
            "arguments": sanitize(entry.arguments, max_string_chars=self.max_chars),
            "outcome": self._text_field(entry.outcome),
            "detail": self._text_field(entry.detail),
            "operator": self._text_field(entry.operator),
            "extra": extra,
            "prev": prev,
        }
        body_json = canonical_json(body)
        body["hash"] = digest(body_json, self.key)
        line = with_hash(body_json, body["hash"]) + b"\n"
        return AuditRecord(**body), line
