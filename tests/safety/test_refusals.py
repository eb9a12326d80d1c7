"""The per-host limit on audit records of refused unauthenticated requests, shared by the stop
channel and the operator console."""

from __future__ import annotations

from armwarden.safety.refusals import RefusalReports
from tests.helpers import FakeClock


def test_the_first_refusal_of_a_host_is_reported() -> None:
    reports = RefusalReports(interval_s=1.0, clock=FakeClock(0.0))

    assert reports.admit("127.0.0.1") == 0


def test_refusals_within_the_interval_are_counted_into_the_next_report() -> None:
    clock = FakeClock(0.0)
    reports = RefusalReports(interval_s=1.0, clock=clock)
    reports.admit("127.0.0.1")

    left_out = [reports.admit("127.0.0.1") for _ in range(5)]
    clock.advance(1.0)

    assert left_out == [None] * 5
    assert reports.admit("127.0.0.1") == 5
    assert reports.admit("127.0.0.1") is None


def test_hosts_are_limited_separately() -> None:
    reports = RefusalReports(interval_s=1.0, clock=FakeClock(0.0))
    reports.admit("10.0.0.1")

    assert reports.admit("10.0.0.2") == 0


def test_the_table_of_hosts_is_bounded_and_forgets_the_longest_quiet_host() -> None:
    clock = FakeClock(0.0)
    reports = RefusalReports(interval_s=1.0, max_hosts=2, clock=clock)
    reports.admit("10.0.0.1")
    reports.admit("10.0.0.1")  # left out, counted
    clock.advance(0.1)
    reports.admit("10.0.0.2")
    clock.advance(0.1)

    assert reports.admit("10.0.0.3") == 0
    assert len(reports) == 2
    assert reports.admit("10.0.0.1") == 0  # forgotten: reported afresh


def test_a_burst_is_reported_in_full_then_one_per_interval() -> None:
    clock = FakeClock(0.0)
    reports = RefusalReports(interval_s=1.0, burst=3, clock=clock)

    first = [reports.admit("alice") for _ in range(5)]
    clock.advance(1.0)
    after_one_interval = [reports.admit("alice") for _ in range(2)]

    assert first == [0, 0, 0, None, None]
    assert after_one_interval == [2, None]


def test_a_quiet_key_gets_its_whole_burst_back() -> None:
    clock = FakeClock(0.0)
    reports = RefusalReports(interval_s=1.0, burst=3, clock=clock)
    for _ in range(4):
        reports.admit("alice")
    clock.advance(10.0)

    assert [reports.admit("alice") for _ in range(4)] == [1, 0, 0, None]
