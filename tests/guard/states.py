"""Guard states with one thing broken, for the tests of the flows' gates."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

from armwarden.guard.gates import GuardState

#: an audit log whose last write failed: nothing may actuate (it could not be recorded)
BROKEN_LOG = SimpleNamespace(unusable="audit log 'audit.jsonl' is unusable after a failed write: disk full")


def with_broken_log(state: GuardState) -> GuardState:
    """`state` with an audit log that cannot be written (the flows read only its `unusable`)."""
    return dataclasses.replace(state, audit=BROKEN_LOG)  # type: ignore[arg-type] - only `unusable` is read
