"""Rate limiter: token buckets with continuous refill, global + per tool, atomic, exemptions."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from armwarden.core.errors import ConfigurationError
from armwarden.policy import RATE_LIMIT_EXEMPT_TOOLS, Policy
from armwarden.safety.ratelimit import RateLimiter
from tests.helpers import FakeClock


def limiter(clock: FakeClock, *, global_pm: int = 1000, default_pm: int = 60, **per_tool: int) -> RateLimiter:
    return RateLimiter(global_pm, default_pm, per_tool, exempt=RATE_LIMIT_EXEMPT_TOOLS, clock=clock)


def test_allows_a_burst_of_capacity_then_refuses_with_retry_time() -> None:
    clock = FakeClock(1000.0)
    rl = limiter(clock, plan_to_pose=6)
    assert all(rl.try_acquire("plan_to_pose").allowed for _ in range(6))
    refused = rl.try_acquire("plan_to_pose")
    assert not refused.allowed
    assert refused.scope == "tool"
    assert refused.retry_after_s == pytest.approx(10.0)  # 6/min → one token every 10 s
    assert "plan_to_pose" in refused.message and "6 times per minute" in refused.message


def test_refills_continuously_one_token_per_period() -> None:
    clock = FakeClock(1000.0)
    rl = limiter(clock, default_pm=60)
    for _ in range(60):
        rl.try_acquire("get_robot_state")
    clock.advance(0.5)
    assert not rl.try_acquire("get_robot_state").allowed
    clock.advance(0.5)
    assert rl.try_acquire("get_robot_state").allowed
    assert not rl.try_acquire("get_robot_state").allowed


def test_refill_never_exceeds_capacity_after_a_long_pause() -> None:
    clock = FakeClock(1000.0)
    rl = limiter(clock, default_pm=5)
    clock.advance(3600)
    assert sum(rl.try_acquire("lookup_transform").allowed for _ in range(20)) == 5


def test_tools_have_separate_buckets() -> None:
    clock = FakeClock(1000.0)
    rl = limiter(clock, default_pm=2)
    assert rl.try_acquire("a").allowed and rl.try_acquire("a").allowed
    assert not rl.try_acquire("a").allowed
    assert rl.try_acquire("b").allowed


def test_global_bucket_limits_all_tools_together() -> None:
    clock = FakeClock(1000.0)
    rl = limiter(clock, global_pm=3, default_pm=60)
    assert [rl.try_acquire(tool).allowed for tool in ("a", "b", "c", "d")] == [True, True, True, False]
    refused = rl.try_acquire("e")
    assert refused.scope == "global"
    assert refused.retry_after_s == pytest.approx(20.0)
    assert "all tools together" in refused.message


def test_a_call_refused_by_the_global_bucket_leaves_the_tool_bucket_untouched() -> None:
    clock = FakeClock(1000.0)
    rl = limiter(clock, global_pm=1, default_pm=2)
    assert rl.try_acquire("other").allowed  # drains the global bucket
    for _ in range(5):
        assert rl.try_acquire("plan_to_joints").scope == "global"
    clock.advance(120)  # global refilled (capacity 1); the tool bucket was never touched anyway
    assert rl.try_acquire("plan_to_joints").allowed


def test_a_call_refused_by_the_tool_bucket_leaves_the_global_bucket_untouched() -> None:
    clock = FakeClock(1000.0)
    rl = limiter(clock, global_pm=3, default_pm=1)
    assert rl.try_acquire("execute_plan").allowed
    for _ in range(10):
        assert rl.try_acquire("execute_plan").scope == "tool"
    assert rl.try_acquire("a").allowed and rl.try_acquire("b").allowed  # 2 global tokens remain


def test_reports_the_longer_wait_when_both_buckets_are_empty() -> None:
    clock = FakeClock(1000.0)
    rl = limiter(clock, global_pm=1, default_pm=1)
    assert rl.try_acquire("a").allowed
    refused = rl.try_acquire("a")
    assert not refused.allowed and refused.retry_after_s == pytest.approx(60.0)


@pytest.mark.parametrize("tool", RATE_LIMIT_EXEMPT_TOOLS)
def test_exempt_tools_are_always_allowed_and_consume_nothing(tool: str) -> None:
    clock = FakeClock(1000.0)
    rl = limiter(clock, global_pm=1, default_pm=1)
    assert all(rl.try_acquire(tool).allowed for _ in range(1000))
    assert rl.try_acquire("get_robot_state").allowed  # the global token is still there
    assert rl.try_acquire(tool).allowed  # and still allowed with every bucket empty


def test_a_clock_stepping_back_adds_no_tokens() -> None:
    clock = FakeClock(1000.0)
    rl = limiter(clock, default_pm=1)
    assert rl.try_acquire("a").allowed
    clock.advance(-500)
    assert not rl.try_acquire("a").allowed
    clock.advance(500 + 30)
    assert not rl.try_acquire("a").allowed  # only 30 s of refill since the newest reading


def test_from_policy_uses_overrides_and_exemptions(fr3_policy: Policy) -> None:
    clock = FakeClock(1000.0)
    policy = fr3_policy.model_copy(
        update={"rate_limits": fr3_policy.rate_limits.model_copy(update={"per_tool": {"plan_to_pose": 2}})}
    )
    rl = RateLimiter.from_policy(policy, clock=clock)
    assert rl.limit_for("plan_to_pose") == 2
    assert rl.limit_for("get_robot_state") == policy.rate_limits.default_per_minute
    assert rl.is_exempt("estop") and not rl.is_exempt("execute_plan")
    assert [rl.try_acquire("plan_to_pose").allowed for _ in range(3)] == [True, True, False]


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "10"])
def test_rejects_invalid_rates(bad: object) -> None:
    with pytest.raises(ConfigurationError, match="positive integer"):
        RateLimiter(bad, 10, {})  # type: ignore[arg-type]
    with pytest.raises(ConfigurationError, match="per_tool"):
        RateLimiter(10, 10, {"x": bad})  # type: ignore[dict-item]


@settings(max_examples=200, deadline=None)
@given(
    per_minute=st.integers(min_value=1, max_value=120),
    gaps=st.lists(st.floats(min_value=0.0, max_value=5.0, allow_nan=False), min_size=1, max_size=300),
    window_s=st.floats(min_value=0.1, max_value=120.0),
)
def test_never_allows_more_than_capacity_plus_refill_in_any_window(
    per_minute: int, gaps: list[float], window_s: float
) -> None:
    clock = FakeClock(0.0)
    rl = limiter(clock, global_pm=10_000, default_pm=per_minute)
    allowed_at: list[float] = []
    for gap in gaps:
        clock.advance(gap)
        if rl.try_acquire("plan_to_pose").allowed:
            allowed_at.append(clock.now)
    bound = math.floor(per_minute + per_minute * window_s / 60.0 + 1e-6)
    for i, start in enumerate(allowed_at):
        in_window = sum(1 for t in allowed_at[i:] if t - start <= window_s)
        assert in_window <= bound


@settings(max_examples=100, deadline=None)
@given(
    global_pm=st.integers(min_value=1, max_value=30),
    calls=st.lists(st.tuples(st.sampled_from(["a", "b", "c", "estop"]), st.floats(0.0, 3.0)), max_size=200),
)
def test_global_count_never_exceeds_its_bucket(global_pm: int, calls: list[tuple[str, float]]) -> None:
    clock = FakeClock(0.0)
    rl = limiter(clock, global_pm=global_pm, default_pm=60)
    allowed = 0
    for tool, gap in calls:
        clock.advance(gap)
        allowed += rl.try_acquire(tool).allowed and tool != "estop"
    assert allowed <= math.floor(global_pm + global_pm * clock.now / 60.0 + 1e-6)


def test_peek_answers_like_try_acquire_without_taking_a_token() -> None:
    from armwarden.safety.ratelimit import RateLimiter

    limiter = RateLimiter(global_per_minute=100, default_per_minute=1, clock=lambda: 0.0)
    assert limiter.peek("plan_to_pose").allowed
    assert limiter.peek("plan_to_pose").allowed
    assert limiter.try_acquire("plan_to_pose").allowed
    assert not limiter.peek("plan_to_pose").allowed
    assert not limiter.try_acquire("plan_to_pose").allowed
