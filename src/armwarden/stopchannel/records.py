"""What the stop channel reports to the audit log: each stop it issued and each request it refused.

Apart from the channel so that the other stop paths (SIGUSR1, the console) and the audit hooks
can name these records without the socket code.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["ChannelRefusal", "ChannelStop"]


@dataclass(frozen=True)
class ChannelStop:
    """One e-stop request handed to ``latch_and_stop``, for the audit log.

    `event` and `stop_issued_ms` are None, and `error` says why, when ``latch_and_stop`` raised.
    """

    principal: str
    reason: str
    peer: str
    event: int | None
    stop_issued_ms: float | None
    error: str | None = None


@dataclass(frozen=True)
class ChannelRefusal:
    """A request the channel refused (4xx/5xx), for the audit log; `suppressed` counts the refusals
    of the same host not reported since the last one (at most one report per host and second;
    counts left out otherwise are reported by the channel's `RefusalReports`)."""

    peer: str
    status: int
    message: str
    suppressed: int = 0
