"""E-stop latch: numbered events, release only of the newest, generation, reason flattening."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from armwarden.safety.estop import NO_REASON, REASON_LIMIT, EStopLatch, flatten_reason
from tests.helpers import FakeClock


def make_latch() -> tuple[EStopLatch, FakeClock, FakeClock]:
    mono, wall = FakeClock(50.0), FakeClock(1_700_000_000.0)
    return EStopLatch(clock=mono, wall_clock=wall), mono, wall


def test_starts_unlatched_with_no_events() -> None:
    latch, _, _ = make_latch()
    assert not latch.is_latched
    assert latch.current_event is None and latch.last_event is None
    assert latch.generation == 0


def test_latch_records_number_reason_source_and_both_clocks() -> None:
    latch, mono, wall = make_latch()
    event = latch.latch("operator pressed stop", "estop")
    assert (event.number, event.reason, event.source) == (1, "operator pressed stop", "estop")
    assert (event.mono_time, event.wall_time) == (mono.now, wall.now)
    assert latch.is_latched and latch.current_event is event and latch.last_event is event


def test_latching_while_latched_creates_a_newer_event_and_stays_latched() -> None:
    latch, _, _ = make_latch()
    first = latch.latch("a", "estop")
    second = latch.latch("b", "force_monitor")
    assert second.number == first.number + 1
    assert latch.is_latched and latch.current_event is second


def test_release_of_the_current_event_unlatches_and_keeps_the_last_event() -> None:
    latch, _, _ = make_latch()
    event = latch.latch("x", "estop")
    result = latch.release(event.number)
    assert result.released and result.event is event
    assert not latch.is_latched and latch.current_event is None and latch.last_event is event


def test_release_of_an_older_event_is_refused_naming_the_newer_one() -> None:
    latch, _, _ = make_latch()
    latch.latch("a", "estop")
    latch.latch("b", "estop")
    newest = latch.latch("c", "backend_fault")
    result = latch.release(2)
    assert not result.released
    assert "a newer e-stop (#3) was latched after #2" in result.message
    assert result.event is newest and latch.is_latched


def test_release_of_a_future_event_number_is_refused() -> None:
    latch, _, _ = make_latch()
    latch.latch("a", "estop")
    result = latch.release(7)
    assert not result.released and "no e-stop #7" in result.message and latch.is_latched


@pytest.mark.parametrize("bad", [None, "1", 1.0, True, [1]])
def test_release_with_a_non_integer_number_is_refused(bad: object) -> None:
    latch, _, _ = make_latch()
    latch.latch("a", "estop")
    result = latch.release(bad)
    assert not result.released and "integer" in result.message and latch.is_latched


def test_release_when_not_latched_is_refused() -> None:
    latch, _, _ = make_latch()
    assert not latch.release(1).released
    event = latch.latch("a", "estop")
    assert latch.release(event.number).released
    again = latch.release(event.number)
    assert not again.released and "not latched" in again.message and "#1" in again.message


def test_event_numbers_keep_increasing_across_releases() -> None:
    latch, _, _ = make_latch()
    numbers = []
    for _ in range(5):
        event = latch.latch("r", "estop")
        numbers.append(event.number)
        assert latch.release(event.number).released
    assert numbers == [1, 2, 3, 4, 5]


def test_generation_changes_on_every_latch_but_not_on_release() -> None:
    latch, _, _ = make_latch()
    before = latch.generation
    event = latch.latch("a", "stop_failed")
    assert latch.generation == before + 1
    latch.release(event.number)
    assert latch.generation == before + 1  # a queued action from before the latch still sees the change
    latch.latch("b", "estop")
    assert latch.generation == before + 2


def test_force_violation_detail_is_kept_read_only_on_the_event() -> None:
    latch, _, _ = make_latch()
    detail = {"kind": "force_limit", "force_n": 42.0}
    event = latch.latch("contact force 42 N", "force_monitor", force_violation=detail)
    detail["kind"] = "changed"
    assert event.force_violation == {"kind": "force_limit", "force_n": 42.0}
    with pytest.raises(TypeError):
        event.force_violation["kind"] = "x"  # type: ignore[index]
    assert latch.latch("plain", "estop").force_violation is None


def test_empty_or_unprintable_reason_is_recorded_as_no_reason() -> None:
    latch, _, _ = make_latch()
    assert latch.latch(None, "estop").reason == NO_REASON
    assert latch.latch(" \n\t\x00\u202e ", "estop").reason == NO_REASON


def test_source_is_flattened_and_bounded() -> None:
    latch, _, _ = make_latch()
    event = latch.latch("r", "force\nmonitor" + "x" * 500)
    assert "\n" not in event.source and len(event.source) <= 64


def test_flatten_reason_joins_lines_and_drops_controls() -> None:
    assert flatten_reason("stop\r\nnow\t\x07please\u2028\u202eok") == "stop now please ok"
    assert flatten_reason("a\x00b") == "ab"
    assert flatten_reason("  line one\n\n line two  ") == "line one line two"


def test_flatten_reason_truncates_with_an_ellipsis() -> None:
    text = flatten_reason("y" * 10_000)
    assert len(text) == REASON_LIMIT and text.endswith("…")
    assert flatten_reason("short", limit=10) == "short"
    assert flatten_reason("exactly ten", limit=11) == "exactly ten"


def test_flatten_reason_reports_truncation_even_when_whitespace_collapses() -> None:
    assert flatten_reason("z" + " " * 10_000 + "tail", limit=20) == "z…"


def test_flatten_reason_handles_non_strings() -> None:
    assert flatten_reason(None) == ""
    assert flatten_reason(12.5) == "12.5"
    assert flatten_reason(b"caf\xc3\xa9 \xff") == "café \ufffd"
    assert flatten_reason({"why": "bump\nagain"}) == "{'why': 'bump\\nagain'}"
    assert len(flatten_reason(list(range(100_000)))) <= REASON_LIMIT
    assert flatten_reason(memoryview(b"abc")) == "abc"


def test_flatten_reason_survives_objects_whose_repr_raises() -> None:
    class Hostile:
        def __repr__(self) -> str:
            raise RuntimeError("nope")

    class HostileStr(str):
        def __str__(self) -> str:
            raise RuntimeError("nope")

    assert "Hostile" in flatten_reason(Hostile())
    assert flatten_reason(HostileStr("fine")) == "fine"


def _is_one_clean_line(text: str, limit: int) -> bool:
    return (
        isinstance(text, str)
        and len(text) <= limit
        and len(text.splitlines()) <= 1
        and all(ch.isprintable() or ch == " " for ch in text)
        and text == text.strip()
    )


_anything = st.recursive(
    st.none()
    | st.booleans()
    | st.integers()
    | st.floats()
    | st.text()
    | st.binary()
    | st.complex_numbers(),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=5), inner, max_size=5),
    max_leaves=20,
)


@settings(max_examples=300, deadline=None)
@given(value=_anything, limit=st.integers(min_value=1, max_value=600))
def test_flatten_reason_never_raises_and_returns_one_bounded_line(value: object, limit: int) -> None:
    assert _is_one_clean_line(flatten_reason(value, limit), limit)


@settings(max_examples=100, deadline=None)
@given(text=st.text(min_size=0, max_size=3000))
def test_flatten_reason_on_any_text_fits_the_default_limit(text: str) -> None:
    out = flatten_reason(text)
    assert _is_one_clean_line(out, REASON_LIMIT)
    if len(text) <= REASON_LIMIT and not any(not ch.isprintable() for ch in text):
        assert out == " ".join(text.split())


def test_flatten_reason_with_a_silly_limit_still_returns_something_short() -> None:
    assert len(flatten_reason("abc", limit=0)) == 1
    assert flatten_reason(math.nan) == "nan"


def test_the_events_held_since_the_last_release_are_all_kept_until_it() -> None:
    latch = EStopLatch()
    first = latch.latch("force", "force_monitor", force_violation={"detail": "95 N"})
    second = latch.latch("pause", "estop")
    assert latch.held_events == (first, second)
    assert latch.release(second.number).released
    assert latch.held_events == ()
    third = latch.latch("again", "estop")
    assert latch.held_events == (third,)


def test_check_release_answers_like_release_without_releasing() -> None:
    latch, _, _ = make_latch()
    latch.latch("a", "estop")
    newest = latch.latch("b", "estop")
    allowed = latch.check_release(newest.number)
    assert allowed.released and allowed.event is newest and latch.is_latched
    for number in (1, 3, "2", None):
        checked, released = latch.check_release(number), latch.release(number)
        assert not checked.released and checked.message == released.message and latch.is_latched


def test_a_latch_after_the_check_makes_the_release_refused() -> None:
    latch, _, _ = make_latch()
    event = latch.latch("a", "estop")
    assert latch.check_release(event.number).released  # the caller records the release now ...
    latch.latch("b", "stop_channel")  # ... while another thread latches again
    result = latch.release(event.number)
    assert not result.released and "a newer e-stop (#2)" in result.message and latch.is_latched
