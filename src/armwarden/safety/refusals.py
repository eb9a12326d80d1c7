"""At most a burst, then one audit record per key (a host, or an authenticated principal) and
interval for refused requests; the records left out are counted into that key's next one.

Why: every audit record is fsynced before its request is answered. A flood of refused requests
(wrong tokens, missing CSRF tokens, malformed, too slow or too large requests) would otherwise buy
one disk flush and one record each: 300 failed console sign-ins in half a second wrote 136 KB,
1000 POSTs that only declared a body over the limit 463 KB in 2.4 s. Each refusal is still
answered; only its record is thinned, and the count of those left out rides in the next record of
the same key, so the log still says how many there were. A refusal that did something — a stop
request held the robot, an e-stop latched — is not this module's business: its callers record
every one of those.

The limit is a token bucket in its GCRA form (one "theoretical arrival time" per key): `burst`
records in a row, then one per `interval_s`; with `burst` 1, at most one per interval. One
limiter per door (the stop channel on its own thread, the operator console and the MCP
transports on the event loop); thread-safe all the same.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable

__all__ = ["MAX_HOSTS", "REPORT_INTERVAL_S", "RefusalReports"]

logger = logging.getLogger(__name__)

#: at most one report per key in this interval, once a burst is spent [s]
REPORT_INTERVAL_S = 1.0
#: keys remembered; beyond, the one reported longest ago is forgotten (source addresses vary on 127/8)
MAX_HOSTS = 1024


class RefusalReports:
    """Which refusals of which key (a host, a principal) to record: `admit` per refusal."""

    def __init__(self, interval_s: float = REPORT_INTERVAL_S, max_hosts: int = MAX_HOSTS,
                 clock: Callable[[], float] = time.monotonic, burst: int = 1) -> None:
        if not interval_s > 0 or max_hosts < 1 or burst < 1:
            raise ValueError(f"interval_s must be positive, max_hosts and burst at least 1 "
                             f"(got {interval_s}, {max_hosts}, {burst})")
        self._interval_s = interval_s
        self._max_hosts = max_hosts
        self._clock = clock
        #: how far ahead of now a key's next report may be booked and still be admitted [s]
        self._slack_s = (burst - 1) * interval_s
        self._hosts: OrderedDict[str, tuple[float, int]] = OrderedDict()  # key -> (next report due, left out since)
        self._lock = threading.Lock()

    def admit(self, host: str) -> int | None:
        """None: leave this refusal of `host` (any key) out of the log (it is counted). Otherwise
        record it, with the returned number of `host`'s refusals left out since its last record."""
        now = self._clock()
        with self._lock:
            due, left_out = self._hosts.get(host, (now, 0))
            due = max(due, now)
            if due - now > self._slack_s:
                self._hosts[host] = (due, left_out + 1)
                return None
            self._hosts[host] = (due + self._interval_s, 0)
            self._hosts.move_to_end(host)
            while len(self._hosts) > self._max_hosts:
                forgotten, (_, lost) = self._hosts.popitem(last=False)
                if lost:
                    logger.warning("%d refused requests from %s were not recorded (too many hosts to count)", lost, forgotten)
        return left_out

    def __len__(self) -> int:
        """How many keys are remembered."""
        with self._lock:
            return len(self._hosts)
