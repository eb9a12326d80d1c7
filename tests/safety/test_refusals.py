"""The limit on audit records of refused requests, per key (a host, a principal) and overall,
shared by the stop channel, the operator console and the MCP transports; what it leaves out is
counted, and every count is reported (issue 24, review 2, item 5)."""

from __future__ import annotations

import threading
from typing import Any

from armwarden.safety.refusals import LeftOut, RefusalReports
from tests.helpers import FakeClock


class Reported(list[LeftOut]):
    """Collects the left-out counts a `RefusalReports` reports; `arrived` is set on each."""

    def __init__(self) -> None:
        super().__init__()
        self.arrived = threading.Event()

    def __call__(self, left_out: LeftOut) -> None:
        self.append(left_out)
        self.arrived.set()

    def total(self) -> int:
        return sum(left_out.count for left_out in self)


def by_hand(clock: FakeClock, reported: Reported | None = None, **options: Any) -> RefusalReports:
    """A limiter on `clock` whose quiet counts the test flushes itself (no timer thread)."""
    return RefusalReports(clock=clock, on_left_out=reported if reported is not None else Reported(),
                          flush_on_a_timer=False, **options)


def test_the_first_refusal_of_a_host_is_reported() -> None:
    reports = by_hand(FakeClock(0.0), interval_s=1.0)

    assert reports.admit("127.0.0.1") == 0


def test_refusals_within_the_interval_are_counted_into_the_next_report() -> None:
    clock = FakeClock(0.0)
    reports = by_hand(clock, interval_s=1.0)
    reports.admit("127.0.0.1")

    left_out = [reports.admit("127.0.0.1") for _ in range(5)]
    clock.advance(1.0)

    assert left_out == [None] * 5
    assert reports.admit("127.0.0.1") == 5
    assert reports.admit("127.0.0.1") is None


def test_hosts_are_limited_separately() -> None:
    reports = by_hand(FakeClock(0.0), interval_s=1.0)
    reports.admit("10.0.0.1")

    assert reports.admit("10.0.0.2") == 0


def test_the_table_of_hosts_is_bounded_and_forgets_the_longest_quiet_host() -> None:
    clock = FakeClock(0.0)
    reports = by_hand(clock, interval_s=1.0, max_hosts=2)
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
    reports = by_hand(clock, interval_s=1.0, burst=3)

    first = [reports.admit("alice") for _ in range(5)]
    clock.advance(1.0)
    after_one_interval = [reports.admit("alice") for _ in range(2)]

    assert first == [0, 0, 0, None, None]
    assert after_one_interval == [2, None]


def test_a_quiet_key_gets_its_whole_burst_back() -> None:
    clock = FakeClock(0.0)
    reports = by_hand(clock, interval_s=1.0, burst=3)
    for _ in range(4):
        reports.admit("alice")
    clock.advance(10.0)

    assert [reports.admit("alice") for _ in range(4)] == [1, 0, 0, None]


# ------------------------------------------------------------------ no count is ever dropped
def test_a_burst_then_silence_is_reported_once_its_key_is_quiet() -> None:
    clock, reported = FakeClock(0.0), Reported()
    reports = by_hand(clock, reported, interval_s=1.0)
    for _ in range(100):
        reports.admit("127.9.9.9")

    reports.flush_due()  # not yet: the key's next record is not due
    assert reported == []
    clock.advance(1.0)
    reports.flush_due()

    assert reported == [LeftOut("127.9.9.9", 99, 1, "quiet")]
    assert reports.admit("127.9.9.9") is None  # the flush was the key's record of this interval
    clock.advance(1.0)
    assert reports.admit("127.9.9.9") == 1


def test_a_forgotten_keys_count_is_reported_as_it_leaves_the_table() -> None:
    clock, reported = FakeClock(0.0), Reported()
    reports = by_hand(clock, reported, interval_s=1.0, max_hosts=2)
    for _ in range(5):
        reports.admit("127.9.9.9")  # one recorded, four counted
    reports.admit("127.50.0.1")

    reports.admit("127.50.0.2")  # pushes the attacker's entry out

    assert reported == [LeftOut("127.9.9.9", 4, 1, "forgotten")]


def test_closing_reports_every_count_still_held() -> None:
    clock, reported = FakeClock(0.0), Reported()
    reports = by_hand(clock, reported, interval_s=1.0)
    for _ in range(3):
        reports.admit("10.0.0.1")
    for _ in range(2):
        reports.admit("alice")

    reports.close()
    reports.close()  # twice is safe

    assert sorted(reported, key=lambda left_out: str(left_out.source)) == [
        LeftOut("10.0.0.1", 2, 1, "closing"), LeftOut("alice", 1, 1, "closing")]


def test_after_closing_every_refusal_is_recorded() -> None:
    reports = by_hand(FakeClock(0.0), interval_s=1.0)
    reports.close()

    assert [reports.admit("10.0.0.1") for _ in range(3)] == [0, 0, 0]


def test_the_timer_reports_a_quiet_keys_count_without_another_refusal() -> None:
    clock, reported = FakeClock(0.0), Reported()
    reports = RefusalReports(interval_s=0.05, clock=clock, on_left_out=reported)  # the timer waits 50 ms of real time
    try:
        for _ in range(10):
            reports.admit("127.9.9.9")
        clock.advance(1.0)

        assert reported.arrived.wait(30.0), "the quiet key's count was never reported"
        assert reported == [LeftOut("127.9.9.9", 9, 1, "quiet")]
    finally:
        reports.close()
    assert reported.total() == 9  # and closing had nothing more to say


# ------------------------------------------------------------------ the overall budget
def test_rotating_sources_get_no_more_records_than_the_overall_budget_and_are_counted_together() -> None:
    clock, reported = FakeClock(0.0), Reported()
    reports = by_hand(clock, reported, interval_s=1.0, overall_per_s=10.0, overall_burst=5)

    admitted = [reports.admit(f"127.50.{i // 250}.{i % 250 + 1}") for i in range(1100)]
    clock.advance(1.0)
    reports.flush_due()

    assert admitted.count(0) == 5 and admitted.count(None) == 1095
    [aggregate] = reported
    assert (aggregate.source, aggregate.count, aggregate.why) == (None, 1095, "over the overall budget")
    assert aggregate.sources == 1024  # told apart: at most the table's size


def test_the_aggregate_names_the_sources_that_contributed_most() -> None:
    clock, reported = FakeClock(0.0), Reported()
    reports = by_hand(clock, reported, interval_s=1.0, max_hosts=4, overall_per_s=10.0, overall_burst=1)
    for _ in range(100):
        reports.admit("127.9.9.9")  # one recorded, 99 counted for the attacker
    clock.advance(1.0)
    for i in range(20):
        reports.admit(f"127.50.0.{i + 1}")  # one recorded (the budget), 19 counted in the aggregate

    reports.flush_due()  # the attacker is quiet, but the budget is spent: its count joins the aggregate

    [aggregate] = reported
    assert (aggregate.source, aggregate.count, aggregate.sources) == (None, 118, 4)  # four told apart, all counted
    assert aggregate.largest[0] == ("127.9.9.9", 99)



def test_under_a_flood_of_rotating_sources_every_refusal_is_recorded_or_counted_and_records_stay_in_budget() -> None:
    clock, reported = FakeClock(0.0), Reported()
    reports = by_hand(clock, reported, interval_s=1.0, max_hosts=8, overall_per_s=10.0, overall_burst=5)
    for _ in range(100):
        reports.admit("127.9.9.9")  # one recorded, 99 counted

    recorded = 1
    for i in range(1100):  # 11 s of 100 sources a second; the table holds 8: the attacker's entry is pushed out
        recorded += reports.admit(f"127.50.{i // 250}.{i % 250 + 1}") is not None
        clock.advance(0.01)
        if i % 100 == 99:
            reports.flush_due()  # as the timer does, once a second
    reports.close()

    assert recorded + reported.total() == 1200  # nothing lost
    keyed = [left_out for left_out in reported if left_out.source is not None]
    assert recorded + len(keyed) <= 5 + 10 * 11 + 1  # the overall budget: a burst, then 10 a second
    assert len(reported) - len(keyed) <= 11 + 1  # and one aggregate a second, and the last at closing
