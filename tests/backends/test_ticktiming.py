"""Tick timing: counts, rate, deadline misses and jitter from given tick stamps (no clocks read)."""

from __future__ import annotations

import pytest

from armwarden.backends.ticktiming import BIN_S, TickTiming


def test_regular_ticks_have_the_nominal_rate_no_misses_and_no_jitter():
    timing = TickTiming(0.002)
    for k in range(101):
        timing.record(k * 0.002 + 1e-7, k * 0.002)
    report = timing.report()
    assert report.ticks == 101 and report.deadline_misses == 0
    assert report.rate_hz == pytest.approx(500.0)
    assert report.interval_p50_s == pytest.approx(0.002, abs=BIN_S)
    assert report.jitter_p99_s <= BIN_S


def test_a_tick_later_than_one_period_is_a_deadline_miss_and_shows_as_jitter():
    timing = TickTiming(0.001)
    stamps = [0.0, 0.001, 0.002, 0.0045, 0.005]  # the fourth began 1.5 ms after its schedule (0.003)
    for k, started in enumerate(stamps):
        timing.record(started, k * 0.001)
    report = timing.report()
    assert report.deadline_misses == 1 and report.miss_ratio == pytest.approx(0.2)
    assert report.max_lateness_s == pytest.approx(0.0015)
    assert report.interval_max_s == pytest.approx(0.0025)
    assert report.jitter_p99_s == pytest.approx(0.0015, abs=BIN_S)


def test_reset_forgets_every_tick():
    timing = TickTiming(0.001)
    timing.record(0.0, 0.0)
    timing.record(0.01, 0.001)
    timing.reset()
    report = timing.report()
    assert (report.ticks, report.deadline_misses, report.rate_hz) == (0, 0, 0.0)
