"""Rate limits: token buckets with continuous refill, one global bucket and one per tool.

Why: a model in a loop can issue calls far faster than a human can follow them, and every
planning call costs real CPU (IK, dense geometry). The limits bound how fast any client can
drive the daemon, whatever the model does (docs/architecture.md, "Where each limit is enforced").

How: each bucket holds at most `capacity` tokens (the per-minute count) and refills
continuously at `capacity / 60` tokens per second, so a burst of `capacity` calls is possible
after a quiet minute and the long-run rate never exceeds the per-minute count. A call needs one
token from its tool's bucket *and* one from the global bucket; both are taken or neither is, so
a call refused by one bucket never drains the other. Tools that stop the robot or report its
safety state are exempt: stopping must always work, however busy the client has been.

The clock is injected (monotonic seconds) so tests never sleep. Not thread safe: the Guard
calls it from the event loop only, and only with the names of registered tools (a bucket is
created for each name the first time it is seen).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass
from typing import Literal

from armwarden.core.errors import ConfigurationError
from armwarden.policy import RATE_LIMIT_EXEMPT_TOOLS

__all__ = ["RateDecision", "RateLimiter", "RateScope"]

RateScope = Literal["global", "tool"]

#: floating-point slack when comparing a refilled bucket against one token
_EPSILON = 1e-9


@dataclass(frozen=True)
class RateDecision:
    """Whether a call may proceed; if not, which bucket refused it and when to retry [s]."""

    allowed: bool
    retry_after_s: float = 0.0
    scope: RateScope | None = None
    tool: str = ""
    #: the per-minute count of the refusing bucket (None when allowed)
    limit_per_minute: int | None = None

    @property
    def message(self) -> str:
        """One line for the model and the human (empty when allowed)."""
        if self.allowed:
            return ""
        which = "all tools together" if self.scope == "global" else f"{self.tool!r}"
        return (
            f"rate limit: {which} may be called at most {self.limit_per_minute} times per minute; "
            f"retry in {self.retry_after_s:.1f} s"
        )


@dataclass
class _Bucket:
    """One token bucket; `tokens` is exact as of `stamp` (monotonic seconds)."""

    per_minute: int
    tokens: float
    stamp: float

    @property
    def refill_per_s(self) -> float:
        return self.per_minute / 60.0

    def refill(self, now: float) -> None:
        elapsed = max(0.0, now - self.stamp)  # a clock that steps back never adds tokens
        self.tokens = min(float(self.per_minute), self.tokens + elapsed * self.refill_per_s)
        self.stamp = max(self.stamp, now)

    def has_token(self) -> bool:
        return self.tokens >= 1.0 - _EPSILON

    def wait_for_token_s(self) -> float:
        """Seconds until one whole token is available (0 if one is)."""
        missing = 1.0 - self.tokens
        return 0.0 if missing <= _EPSILON else missing / self.refill_per_s


def _check_rate(name: str, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ConfigurationError(f"rate limit {name} must be a positive integer (calls per minute), got {value!r}")
    return value


class RateLimiter:
    """One global bucket plus one bucket per tool; see the module docstring."""

    def __init__(
        self,
        global_per_minute: int,
        default_per_minute: int,
        per_tool: Mapping[str, int] | None = None,
        exempt: Collection[str] = RATE_LIMIT_EXEMPT_TOOLS,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._clock = clock
        self._default_per_minute = _check_rate("default_per_minute", default_per_minute)
        self._per_tool = {tool: _check_rate(f"per_tool[{tool!r}]", rate) for tool, rate in (per_tool or {}).items()}
        self._exempt = frozenset(exempt)
        per_minute = _check_rate("global_per_minute", global_per_minute)
        self._global = _Bucket(per_minute, float(per_minute), clock())
        self._tools: dict[str, _Bucket] = {}

    @classmethod
    def from_policy(cls, policy, clock: Callable[[], float] = time.monotonic) -> RateLimiter:
        limits = policy.rate_limits
        return cls(
            global_per_minute=limits.global_per_minute,
            default_per_minute=limits.default_per_minute,
            per_tool=dict(limits.per_tool),
            exempt=RATE_LIMIT_EXEMPT_TOOLS,
            clock=clock,
        )

    def limit_for(self, tool: str) -> int:
        """Calls per minute allowed for `tool` alone (its override, else the default)."""
        return self._per_tool.get(tool, self._default_per_minute)

    def is_exempt(self, tool: str) -> bool:
        return tool in self._exempt

    def try_acquire(self, tool: str) -> RateDecision:
        """Take one token from `tool`'s bucket and the global bucket, or neither."""
        return self._decide(tool, consume=True)

    def peek(self, tool: str) -> RateDecision:
        """What `try_acquire` would answer now, taking nothing (for side-effect-free pre-checks)."""
        return self._decide(tool, consume=False)

    def _decide(self, tool: str, consume: bool) -> RateDecision:
        if tool in self._exempt:
            return RateDecision(allowed=True, tool=tool)
        now = self._clock()
        bucket = self._tools.get(tool)
        if bucket is None:  # a tool's bucket starts full the first time it is used
            per_minute = self.limit_for(tool)
            bucket = self._tools[tool] = _Bucket(per_minute, float(per_minute), now)
        bucket.refill(now)
        self._global.refill(now)
        if bucket.has_token() and self._global.has_token():
            if consume:
                bucket.tokens = max(0.0, bucket.tokens - 1.0)
                self._global.tokens = max(0.0, self._global.tokens - 1.0)
            return RateDecision(allowed=True, tool=tool)
        # both buckets must have a token, so the call can proceed once the slower one has one
        tool_wait, global_wait = bucket.wait_for_token_s(), self._global.wait_for_token_s()
        if tool_wait >= global_wait:
            return RateDecision(False, tool_wait, "tool", tool, bucket.per_minute)
        return RateDecision(False, global_wait, "global", tool, self._global.per_minute)
