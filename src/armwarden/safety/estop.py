"""The e-stop latch: once tripped, motion stays refused until a human resets *that* trip.

Why: an e-stop must not be undone by accident or by a race. Every latch (the `estop` tool, a
force violation, a stop command that failed, a backend fault) creates a new numbered event,
also while already latched. A reset names the event it releases; the human is shown that
event, and if another latch happened while they were deciding, the reset is refused, so
nobody ever releases a stop they have not seen (docs/architecture.md, "Where each limit is
enforced": releasing an e-stop).

A release is recorded before it takes effect (`guard.stopping.Stopper.release`): the caller asks
`check_release`, writes the record, then `release` checks again; a release that cannot be
recorded does not happen. The caller runs one release at a time, so two releases of one event
never both write a record.

`generation` counts latches. The Guard records it before validating or asking and compares it
afterwards: anything that started before a latch must not run after the reset.

Reasons come from models and from hardware, so `flatten_reason` accepts any value and turns it
into one printable line of bounded length; it never raises.

The clocks are injected so tests never sleep. Latching and releasing are thread safe (the
independent stop channel and SIGUSR1 latch from their own thread while the event loop may be
busy); reads are single attribute loads.
"""

from __future__ import annotations

import reprlib
import threading
import time
import unicodedata
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

__all__ = ["NO_REASON", "REASON_LIMIT", "EStopEvent", "EStopLatch", "ReleaseResult", "flatten_reason"]

#: longest reason kept on an event [characters]
REASON_LIMIT = 500
#: the reason recorded when the caller gave none (or only whitespace/control characters)
NO_REASON = "(no reason given)"
_SOURCE_LIMIT = 64
_ELLIPSIS = "…"
# characters rendered as a space (separators) or dropped (controls, format chars such as bidi
# overrides, unpaired surrogates, private use, unassigned) so the text stays one honest, printable line
_SPACE_CATEGORIES = frozenset({"Zs", "Zl", "Zp"})
_DROP_CATEGORIES = frozenset({"Cc", "Cf", "Cs", "Co", "Cn"})
_WHITESPACE_CONTROLS = frozenset("\t\n\v\f\r\x1c\x1d\x1e\x1f\x85")

_repr = reprlib.Repr()
_repr.maxlevel = 3
_repr.maxdict = _repr.maxlist = _repr.maxtuple = _repr.maxset = _repr.maxfrozenset = _repr.maxdeque = 16
_repr.maxstring = _repr.maxother = _repr.maxlong = 200


def _to_text(value: object, budget: int) -> tuple[str, bool]:
    """`value` as text of at most `budget` characters, and whether it was cut."""
    if value is None:
        return "", False
    if isinstance(value, str):
        text = str.__str__(value)
    elif isinstance(value, (bytes, bytearray, memoryview)):
        view = memoryview(value)
        if view.format != "B" or view.ndim != 1:
            view = view.cast("B")
        raw = bytes(view[: budget * 4])  # UTF-8 needs at most 4 bytes per character
        cut = view.nbytes > len(raw)
        text = raw.decode("utf-8", errors="replace")
        return text[:budget], cut or len(text) > budget
    else:
        text = _repr.repr(value)
    return text[:budget], len(text) > budget


def _clean(text: str) -> str:
    out: list[str] = []
    for char in text:
        if char in _WHITESPACE_CONTROLS:
            out.append(" ")
            continue
        category = unicodedata.category(char)
        if category in _SPACE_CATEGORIES:
            out.append(" ")
        elif category not in _DROP_CATEGORIES:
            out.append(char)
    return " ".join("".join(out).split())


def flatten_reason(value: object, limit: int = REASON_LIMIT) -> str:
    """Any value as one printable line of at most `limit` characters. Never raises.

    Line breaks and other separators become single spaces, control and format characters are
    dropped, and text that does not fit is cut and ends with "…". Bytes are decoded as UTF-8
    (invalid sequences replaced); other objects are shown by a bounded `repr`.
    """
    try:
        limit = max(1, int(limit))
    except Exception:
        limit = REASON_LIMIT
    try:
        # cleaning can only shorten the text, but leave room to know whether it was cut
        raw, cut = _to_text(value, limit * 4)
        text = _clean(raw)
    except Exception:
        try:
            text, cut = _clean(f"<unprintable {type(value).__name__}>"), False
        except Exception:
            text, cut = "<unprintable>", False
    if cut or len(text) > limit:
        text = text[: limit - 1].rstrip() + _ELLIPSIS
    return text


@dataclass(frozen=True)
class EStopEvent:
    """One latch: its number (1, 2, ... for the life of the process), why, from where, and when."""

    number: int
    reason: str
    #: what latched: "estop" (the tool), "force_monitor", "stop_failed", "backend_fault", ...
    source: str
    wall_time: float
    mono_time: float
    #: the force monitor's finding (kind, forces, ...) when `source` is "force_monitor"
    force_violation: Mapping[str, Any] | None = field(default=None, compare=False, hash=False)


@dataclass(frozen=True)
class ReleaseResult:
    """The answer to a reset: released or not, why, and the event concerned (if any)."""

    released: bool
    message: str
    #: the released event, or (when refused) the event that is still latched
    event: EStopEvent | None = None


class EStopLatch:
    """The process-wide e-stop latch; see the module docstring."""

    def __init__(
        self, clock: Callable[[], float] = time.monotonic, wall_clock: Callable[[], float] = time.time
    ) -> None:
        self._clock = clock
        self._wall_clock = wall_clock
        self._generation = 0
        self._last: EStopEvent | None = None
        self._held: tuple[EStopEvent, ...] = ()  # every event latched since the last release, oldest first
        self._latches_by_source: dict[str, int] = {}
        self._releases = 0
        self._lock = threading.Lock()

    @property
    def is_latched(self) -> bool:
        return bool(self._held)

    @property
    def current_event(self) -> EStopEvent | None:
        """The newest latched event while latched, else None."""
        held = self._held
        return held[-1] if held else None

    @property
    def held_events(self) -> tuple[EStopEvent, ...]:
        """Every event latched since the last release, oldest first (empty when not latched): a
        release lets go of them all, so whoever approves it must see them all."""
        return self._held

    @property
    def last_event(self) -> EStopEvent | None:
        """The newest event ever latched (also after its release), else None."""
        return self._last

    @property
    def generation(self) -> int:
        """Number of latches so far; changes whenever anything latches."""
        return self._generation

    def tallies(self) -> tuple[dict[str, int], int]:
        """Latches so far by source, and releases: a copy for monitoring (`armwarden.metrics`
        reads it at scrape time, so nothing on the latching path calls metrics code)."""
        with self._lock:
            return dict(self._latches_by_source), self._releases

    def latch(self, reason: object, source: str, force_violation: Mapping[str, Any] | None = None) -> EStopEvent:
        """Latch (again): always a new event with the next number; never fails. Any thread."""
        with self._lock:
            return self._latch_locked(reason, source, force_violation)

    def _latch_locked(self, reason: object, source: str, force_violation: Mapping[str, Any] | None) -> EStopEvent:
        self._generation += 1
        event = EStopEvent(
            number=self._generation,
            reason=flatten_reason(reason) or NO_REASON,
            source=flatten_reason(source, _SOURCE_LIMIT) or "unknown",
            wall_time=self._wall_clock(),
            mono_time=self._clock(),
            force_violation=MappingProxyType(dict(force_violation)) if force_violation is not None else None,
        )
        self._last = event
        self._held = (*self._held, event)
        self._latches_by_source[event.source] = self._latches_by_source.get(event.source, 0) + 1
        return event

    def check_release(self, event_number: object) -> ReleaseResult:
        """What `release(event_number)` would answer now, without releasing anything: the caller
        records the release before it takes effect, then calls `release`, which checks again (a
        latch in between changes the newest event, so the release is then refused)."""
        with self._lock:
            return self._refusal_locked(event_number) or self._newest_releasable_locked("may be released")

    def release(self, event_number: object) -> ReleaseResult:
        """Release the latch if `event_number` is the newest latched event; otherwise refuse and say why."""
        with self._lock:
            refusal = self._refusal_locked(event_number)
            if refusal is not None:
                return refusal
            released = self._newest_releasable_locked("released")
            self._held = ()
            self._releases += 1
            return released

    def _newest_releasable_locked(self, verb: str) -> ReleaseResult:
        """The positive answer about the newest latched event, once `_refusal_locked` found none."""
        current = self.current_event
        assert current is not None
        return ReleaseResult(True, f"e-stop #{current.number} {verb}", current)

    def _refusal_locked(self, event_number: object) -> ReleaseResult | None:
        """Why `event_number` may not be released now, or None when it may."""
        current = self.current_event
        if current is None:
            done = f" (the last one, #{self._last.number}, was already reset)" if self._last is not None else ""
            return ReleaseResult(False, f"the e-stop is not latched; nothing to reset{done}")
        if isinstance(event_number, bool) or not isinstance(event_number, int):
            shown = flatten_reason(event_number, 40)
            return ReleaseResult(False, f"e-stop event number must be an integer (got {shown!r})", current)
        if event_number < current.number:
            return ReleaseResult(
                False,
                f"a newer e-stop (#{current.number}) was latched after #{event_number}; "
                f"review why #{current.number} latched and reset that one",
                current,
            )
        if event_number > current.number:
            return ReleaseResult(
                False, f"there is no e-stop #{event_number}; the latched e-stop is #{current.number}", current
            )
        return None
