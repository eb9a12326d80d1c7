"""Tick timing of a periodic control thread: how regularly it runs, without keeping every stamp.

The servo thread records each tick's start (its scheduled time and when it really began); readers
on other threads take a `TickReport`. Intervals between tick starts go into a fixed histogram
(`BIN_S` wide bins), so hours of ticks cost constant memory and the recording costs a few
arithmetic operations under an uncontended lock. A *deadline miss* is a tick that began more than
one period after it was scheduled. Used by benchmarks (scripts/_bench/can_loop.py), never by
control decisions.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

#: histogram bin width [s]
BIN_S = 10e-6
#: intervals at or beyond this many bins land in the last one (1 s at 10 µs bins)
BINS = 100_000


@dataclass(frozen=True)
class TickReport:
    """What the ticks since the last reset looked like (times in seconds)."""

    period_s: float
    ticks: int
    elapsed_s: float  # from the first recorded tick start to the last
    deadline_misses: int  # ticks that began more than one period after they were scheduled
    max_lateness_s: float
    interval_p50_s: float
    interval_p99_s: float
    interval_max_s: float
    jitter_p99_s: float  # 99th percentile of |interval − period|, to the histogram's resolution

    @property
    def rate_hz(self) -> float:
        """Achieved tick rate: intervals per second between the first and the last tick."""
        return (self.ticks - 1) / self.elapsed_s if self.ticks > 1 and self.elapsed_s > 0 else 0.0

    @property
    def miss_ratio(self) -> float:
        return self.deadline_misses / self.ticks if self.ticks else 0.0


class TickTiming:
    """Written by the control thread (`record`), read from anywhere (`report`, `reset`)."""

    def __init__(self, period_s: float) -> None:
        self.period_s = float(period_s)
        self._lock = threading.Lock()
        self._counts = [0] * BINS
        self._jitter = [0] * BINS
        self._ticks = 0
        self._first: float | None = None
        self._last: float | None = None
        self._misses = 0
        self._max_lateness = 0.0
        self._max_interval = 0.0

    def reset(self) -> None:
        with self._lock:
            self._counts, self._jitter = [0] * BINS, [0] * BINS
            self._ticks, self._first, self._last = 0, None, None
            self._misses, self._max_lateness, self._max_interval = 0, 0.0, 0.0

    def record(self, started: float, scheduled: float) -> None:
        """A tick began at `started`, scheduled for `scheduled` (same clock, seconds)."""
        lateness = started - scheduled
        with self._lock:
            if self._last is not None:
                interval = started - self._last
                self._counts[_bin(interval)] += 1
                self._jitter[_bin(abs(interval - self.period_s))] += 1
                self._max_interval = max(self._max_interval, interval)
            else:
                self._first = started
            self._last = started
            self._ticks += 1
            if lateness > self.period_s:
                self._misses += 1
            self._max_lateness = max(self._max_lateness, lateness)

    def totals(self) -> tuple[int, int, float, float]:
        """(ticks, deadline misses, max lateness [s], max interval [s]) since the last reset: the
        cheap part of `report` (no histogram copy), for monitoring scrapes while the loop runs."""
        with self._lock:
            return self._ticks, self._misses, self._max_lateness, self._max_interval

    def report(self) -> TickReport:
        with self._lock:
            counts, jitter, ticks = list(self._counts), list(self._jitter), self._ticks
            first, last = self._first, self._last
            misses, lateness, longest = self._misses, self._max_lateness, self._max_interval
        return TickReport(self.period_s, ticks, (last - first) if first is not None and last is not None else 0.0,
                          misses, lateness, _quantile(counts, 0.5), _quantile(counts, 0.99), longest,
                          _quantile(jitter, 0.99))


def _bin(seconds: float) -> int:
    return min(BINS - 1, max(0, int(seconds / BIN_S)))


def _quantile(counts: list[int], q: float) -> float:
    """The middle of the bin holding quantile `q` of the histogram [s]; 0 if empty."""
    total = sum(counts)
    if total == 0:
        return 0.0
    target, seen = q * total, 0
    for index, count in enumerate(counts):
        seen += count
        if seen >= target:
            return (index + 0.5) * BIN_S
    return BINS * BIN_S


__all__ = ["BIN_S", "TickReport", "TickTiming"]
