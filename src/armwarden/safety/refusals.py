"""At most a burst, then one audit record per key (a host, or an authenticated principal) and
interval for refused requests, and at most an overall budget of such records across all keys;
every refusal left out is counted, and every count reaches the log.

Why: every audit record is fsynced before its request is answered. A flood of refused requests
(wrong tokens, missing CSRF tokens, malformed, too slow or too large requests) would otherwise buy
one disk flush and one record each: 300 failed console sign-ins in half a second wrote 136 KB,
1000 POSTs that only declared a body over the limit 463 KB in 2.4 s. Each refusal is still
answered; only its record is thinned. A refusal that did something — a stop request held the
robot, an e-stop latched — is not this module's business: its callers record every one of those.

Two limits, each a token bucket in its GCRA form (one "theoretical arrival time"):
- per key: `burst` records in a row, then one per `interval_s`; a refusal over it is counted
  for its key, and that count rides in the key's next record (`admit` returns it);
- overall: `overall_burst` records, then `overall_per_s`, across all keys, so sources that rotate
  (any 127.x.y.z on loopback) cannot buy a record each; a refusal over it is counted in the
  aggregate, reported once per interval as one record for all the sources behind it.

No count is ever dropped (`LeftOut`, handed to `on_left_out`): a key that went quiet has its count
reported on a timer (a thread that lives only while counts are held), a key pushed out of the
table as it leaves, and everything still held at `close` (the daemon's shutdown). Those reports
are records too: they spend the overall budget, or join the aggregate. After `close` every
refusal is recorded (`admit` always says so). One limiter per door (the stop channel on its own
thread, the operator console and the MCP transports on the event loop); thread-safe.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = [
    "MAX_HOSTS",
    "OVERALL_BURST",
    "OVERALL_RECORDS_PER_S",
    "REPORT_INTERVAL_S",
    "LeftOut",
    "RefusalReports",
    "left_out_recorder",
]

logger = logging.getLogger(__name__)

#: at most one report per key in this interval, once a burst is spent [s]
REPORT_INTERVAL_S = 1.0
#: keys remembered; beyond, the one reported longest ago is forgotten (its count reported)
MAX_HOSTS = 1024
#: records of refusals across all keys, once `OVERALL_BURST` is spent [1/s]
OVERALL_RECORDS_PER_S = 10.0
#: records of refusals across all keys in a row (two transport principals' bursts fit)
OVERALL_BURST = 40
#: sources an aggregate report names with their counts (more than one), the largest first
LARGEST_SOURCES = 5

QUIET, FORGOTTEN, CLOSING, OVER_BUDGET = "quiet", "forgotten", "closing", "over the overall budget"


@dataclass(frozen=True)
class LeftOut:
    """Refusals counted but not recorded one by one, reported on their own.

    `source`: the key (None: the aggregate of refusals over the overall budget); `count`: how
    many; `sources`: distinct keys behind them (1 for a key; for the aggregate at most
    `MAX_HOSTS` are told apart); `why`: the key went quiet, was forgotten, the limiter closed, or
    the overall budget was spent; `largest`: for the aggregate, the sources that contributed most
    and how much (so a flooder hiding among rotating sources is still named).
    """

    source: str | None
    count: int
    sources: int
    why: str
    largest: tuple[tuple[str, int], ...] = ()

    def describe(self, door: str) -> str:
        whom = f"from {self.source}" if self.source is not None else f"from {self.sources} source(s)"
        most = "".join(f"; {count} from {source}" for source, count in self.largest)
        return f"{self.count} refused request(s) {whom} not recorded one by one at the {door} ({self.why}{most})"


def _log_left_out(left_out: LeftOut) -> None:
    logger.warning("%s", left_out.describe("door"))


class RefusalReports:
    """Which refusals of which key (a host, a principal) to record: `admit` per refusal."""

    def __init__(self, interval_s: float = REPORT_INTERVAL_S, max_hosts: int = MAX_HOSTS,
                 clock: Callable[[], float] = time.monotonic, burst: int = 1, *,
                 overall_per_s: float = OVERALL_RECORDS_PER_S, overall_burst: int = OVERALL_BURST,
                 on_left_out: Callable[[LeftOut], None] = _log_left_out, flush_on_a_timer: bool = True) -> None:
        """`on_left_out` records a count left out (any thread; it must not wait). Without
        `flush_on_a_timer` only `flush_due` and `close` report quiet keys (tests on a fake clock)."""
        if not interval_s > 0 or max_hosts < 1 or burst < 1 or not overall_per_s > 0 or overall_burst < 1:
            raise ValueError(f"interval_s and overall_per_s must be positive, max_hosts, burst and overall_burst "
                             f"at least 1 (got {interval_s}, {overall_per_s}, {max_hosts}, {burst}, {overall_burst})")
        self._interval_s = interval_s
        self._max_hosts = max_hosts
        self._clock = clock
        #: how far ahead of now a key's next report may be booked and still be admitted [s]
        self._slack_s = (burst - 1) * interval_s
        self._hosts: OrderedDict[str, tuple[float, int]] = OrderedDict()  # key -> (next report due, left out since)
        self._overall_interval_s = 1.0 / overall_per_s
        self._overall_slack_s = (overall_burst - 1) * self._overall_interval_s
        self._overall_due = clock()
        self._aggregate_count = 0
        self._aggregate_sources: dict[str, int] = {}  # source -> its count in the aggregate
        self._aggregate_due = clock()
        self._on_left_out = on_left_out
        self._timer = flush_on_a_timer
        self._flusher: threading.Thread | None = None
        self._closed = False
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)

    # ------------------------------------------------------------------ admitting
    def admit(self, host: str) -> int | None:
        """None: leave this refusal of `host` (any key) out of the log (it is counted). Otherwise
        record it, with the returned number of `host`'s refusals left out since its last record."""
        now = self._clock()
        reports: list[LeftOut] = []
        with self._lock:
            if self._closed:  # nothing would report a count any more: record each
                _, left_out = self._hosts.pop(host, (now, 0))
                return left_out
            due, left_out = self._hosts.get(host, (now, 0))
            due = max(due, now)
            if due - now > self._slack_s:
                self._hosts[host] = (due, left_out + 1)
                self._start_flusher()
                return None
            if not self._spend_overall(now):
                self._aggregate(host, 1)
                return None
            self._hosts[host] = (due + self._interval_s, 0)
            self._hosts.move_to_end(host)
            while len(self._hosts) > self._max_hosts:
                forgotten, (_, lost) = self._hosts.popitem(last=False)
                if lost:
                    reports.extend(self._report_or_aggregate(forgotten, lost, FORGOTTEN, now))
        self._emit(reports)
        return left_out

    def _spend_overall(self, now: float) -> bool:
        """Take one record from the overall budget if there is one left (under the lock)."""
        due = max(self._overall_due, now)
        if due - now > self._overall_slack_s:
            return False
        self._overall_due = due + self._overall_interval_s
        return True

    def _aggregate(self, source: str, count: int) -> None:
        """Count `count` refusals of `source` into the aggregate (under the lock)."""
        self._aggregate_count += count
        told_apart = self._aggregate_sources
        if source in told_apart or len(told_apart) < self._max_hosts:
            told_apart[source] = told_apart.get(source, 0) + count
        elif count > 1:  # a key's own count (rare: at most a budget's worth a second) displaces the smallest
            smallest = min(told_apart, key=told_apart.__getitem__)
            if told_apart[smallest] < count:
                del told_apart[smallest]
                told_apart[source] = count
        self._start_flusher()

    def _report_or_aggregate(self, source: str, count: int, why: str, now: float) -> list[LeftOut]:
        """A report of `source`'s own if the overall budget allows one, else into the aggregate."""
        if self._spend_overall(now):
            return [LeftOut(source, count, 1, why)]
        self._aggregate(source, count)
        return []

    # ------------------------------------------------------------------ reporting what was left out
    def flush_due(self) -> None:
        """Report the count of every key that went quiet (its next record is due and none came)
        and, once per interval, the aggregate. The timer calls this; so may a caller."""
        self._emit(self._collect(self._clock(), closing=False))

    def close(self) -> None:
        """Report everything still counted, stop the timer; from now on every refusal is recorded.
        Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            flusher = self._flusher
            self._wake.notify_all()
        if flusher is not None and flusher is not threading.current_thread():
            flusher.join(timeout=5.0)
        self._emit(self._collect(self._clock(), closing=True))

    def _collect(self, now: float, *, closing: bool) -> list[LeftOut]:
        reports: list[LeftOut] = []
        with self._lock:
            for host, (due, left_out) in list(self._hosts.items()):
                if left_out and (closing or max(due, now) - now <= self._slack_s):
                    # the report is the key's record of this interval
                    self._hosts[host] = (max(due, now) + self._interval_s, 0)
                    reports.extend(self._report_or_aggregate(host, left_out, CLOSING if closing else QUIET, now))
            if self._aggregate_count and (closing or now >= self._aggregate_due):
                repeated = [item for item in self._aggregate_sources.items() if item[1] > 1]
                largest = sorted(repeated, key=lambda item: -item[1])[:LARGEST_SOURCES]
                reports.append(LeftOut(None, self._aggregate_count, len(self._aggregate_sources), OVER_BUDGET,
                                       tuple(largest)))
                self._aggregate_count, self._aggregate_sources = 0, {}
                self._aggregate_due = now + self._interval_s
        return reports

    def _holds_counts(self) -> bool:
        return bool(self._aggregate_count) or any(left_out for _, left_out in self._hosts.values())

    def _start_flusher(self) -> None:
        """Start the timer thread if counts are held and none runs (under the lock)."""
        if not self._timer or self._closed or self._flusher is not None:
            return
        self._flusher = threading.Thread(target=self._flush_on_a_timer, name="armwarden-refusal-reports", daemon=True)
        self._flusher.start()

    def _flush_on_a_timer(self) -> None:
        """Once per interval, `flush_due`; ends when nothing is held any more (or at `close`)."""
        while True:
            with self._lock:
                self._wake.wait(self._interval_s)
                if self._closed:
                    self._flusher = None
                    return
            try:
                self.flush_due()
            except Exception:  # the timer must go on: a count it cannot report now, it reports later
                logger.exception("refusal reports: reporting the counts left out failed")
            with self._lock:
                if self._closed or not self._holds_counts():
                    self._flusher = None
                    return

    def _emit(self, reports: list[LeftOut]) -> None:
        for left_out in reports:
            try:
                self._on_left_out(left_out)
            except Exception:
                logger.exception("refusal reports: %s", left_out.describe("door"))

    def __len__(self) -> int:
        """How many keys are remembered."""
        with self._lock:
            return len(self._hosts)


def left_out_recorder(audit: Any, door: str) -> Callable[[LeftOut], None]:
    """`on_left_out` for a door ("stop_channel", "console", "transport"): a `refusals_left_out`
    record handed to `audit` (an `AuditLog`) without waiting; a log that cannot take it is said
    loudly on stderr. None: stderr only (a console without an audit log)."""
    from armwarden.audit import AuditWriteError

    def record(left_out: LeftOut) -> None:
        detail = left_out.describe(door.replace("_", " "))
        if audit is None:
            logger.warning("%s", detail)
            return
        try:
            audit.submit("refusals_left_out", outcome="refused", detail=detail,
                         extra={"door": door, "source": left_out.source, "count": left_out.count,
                                "sources": left_out.sources, "why": left_out.why,
                                **({"largest": dict(left_out.largest)} if left_out.largest else {})})
        except AuditWriteError as exc:
            logger.critical("refusals_left_out not audited (%s): %s", exc, detail)

    return record
