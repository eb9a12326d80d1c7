"""At most one audit record per host and interval for requests refused before anybody was
authenticated; the records left out are counted into that host's next one.

Why: every audit record is fsynced before its request is answered. A flood of refused requests
from nobody in particular (wrong tokens, missing CSRF tokens, malformed or too slow requests)
would otherwise buy one disk flush and one record each: 300 failed console sign-ins in half a
second wrote 136 KB. Each refusal is still answered; only its record is thinned, and the count
of those left out rides in the next record of the same host, so the log still says how many
there were. Refusals that name a principal are not this module's business: they are each
recorded by their callers.

One limiter per door (the stop channel on its own thread, the operator console on the event
loop); thread-safe all the same.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable

__all__ = ["MAX_HOSTS", "REPORT_INTERVAL_S", "RefusalReports"]

logger = logging.getLogger(__name__)

#: at most one report per host in this interval [s]
REPORT_INTERVAL_S = 1.0
#: hosts remembered; beyond, the one reported longest ago is forgotten (source addresses vary on 127/8)
MAX_HOSTS = 1024


class RefusalReports:
    """Which refusals of which host to record: `admit` per refusal."""

    def __init__(self, interval_s: float = REPORT_INTERVAL_S, max_hosts: int = MAX_HOSTS,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not interval_s > 0 or max_hosts < 1:
            raise ValueError(f"interval_s must be positive and max_hosts at least 1 (got {interval_s}, {max_hosts})")
        self._interval_s = interval_s
        self._max_hosts = max_hosts
        self._clock = clock
        self._hosts: OrderedDict[str, tuple[float, int]] = OrderedDict()  # host -> (last report, left out since)
        self._lock = threading.Lock()

    def admit(self, host: str) -> int | None:
        """None: leave this refusal of `host` out of the log (it is counted). Otherwise record it,
        with the returned number of `host`'s refusals left out since its last record."""
        now = self._clock()
        with self._lock:
            last, left_out = self._hosts.get(host, (float("-inf"), 0))
            if now - last < self._interval_s:
                self._hosts[host] = (last, left_out + 1)
                return None
            self._hosts[host] = (now, 0)
            self._hosts.move_to_end(host)
            while len(self._hosts) > self._max_hosts:
                forgotten, (_, lost) = self._hosts.popitem(last=False)
                if lost:
                    logger.warning("%d refused requests from %s were not recorded (too many hosts to count)", lost, forgotten)
        return left_out

    def __len__(self) -> int:
        """How many hosts are remembered."""
        with self._lock:
            return len(self._hosts)
