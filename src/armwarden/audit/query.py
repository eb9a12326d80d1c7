"""Finding records without writing a script: the filters of `armwarden audit tail`.

A record matches when it passes every filter given (AND); an unset filter matches everything:

- ``tool``: the tool name, exactly (``plan_to_pose``);
- ``principal``: the HTTP token's name, exactly;
- ``status``: the record's ``outcome`` (``ok``, ``refused``, ``invalid``, ``error``, ``cancelled``,
  ``input_required``, ...) *or* the status of the result it recorded (a plan's ``ok`` /
  ``needs_approval`` / ``rejected``, an execution's ``succeeded`` / ``aborted`` / ``dry_run``), so
  ``--status rejected`` finds rejected plans and ``--status refused`` refused calls;
- ``since``: records written at or after an ISO 8601 time (UTC unless it names a zone; a date alone
  means its midnight UTC).
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass
from typing import Any


def parse_since(text: str) -> _dt.datetime:
    """An aware UTC datetime from ISO 8601 text (``2026-11-24``, ``2026-11-24T04:10``, ``...Z``,
    ``...+02:00``). Raises ValueError naming the expected form."""
    text = text.strip()
    if text[-1:] in ("Z", "z"):  # Python 3.10's fromisoformat does not read the "Z" suffix
        text = text[:-1] + "+00:00"
    try:
        moment = _dt.datetime.fromisoformat(text)
    except ValueError as exc:
        raise ValueError(f"--since must be an ISO 8601 time such as 2026-11-24T04:10:00Z, got {text!r}") from exc
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=_dt.timezone.utc)
    return moment.astimezone(_dt.timezone.utc)


@dataclass(frozen=True)
class RecordFilter:
    """The filters of one query; see the module docstring."""

    tool: str | None = None
    principal: str | None = None
    status: str | None = None
    since: _dt.datetime | None = None

    @property
    def empty(self) -> bool:
        return self.tool is None and self.principal is None and self.status is None and self.since is None

    def matches(self, record: dict[str, Any]) -> bool:
        if self.tool is not None and record.get("tool") != self.tool:
            return False
        if self.principal is not None and record.get("principal") != self.principal:
            return False
        if self.status is not None and self.status not in statuses_of(record):
            return False
        if self.since is not None:
            written = _written_at(record)
            if written is None or written < self.since:
                return False
        return True


def statuses_of(record: dict[str, Any]) -> set[str]:
    """The record's outcome and the status of the result it carries (if any)."""
    found = {record["outcome"]} if isinstance(record.get("outcome"), str) else set()
    extra = record.get("extra")
    result = extra.get("result") if isinstance(extra, dict) else None
    if isinstance(result, dict) and isinstance(result.get("status"), str):
        found.add(result["status"])
    return found


def _written_at(record: dict[str, Any]) -> _dt.datetime | None:
    wall = record.get("wall_time")
    if not isinstance(wall, str):
        return None
    try:
        return parse_since(wall)
    except ValueError:
        return None
