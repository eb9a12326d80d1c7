"""Force monitor: limits, baseline allowance, and fail-closed on missing/slow/frozen/invalid wrench."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import anyio
import anyio.lowlevel
import numpy as np
import pytest

from armwarden.core.errors import BackendError, ConfigurationError
from armwarden.core.state import Wrench
from armwarden.policy import Policy
from armwarden.safety.force import ForceLimits, ForceMonitor, ForceViolation
from tests.helpers import FakeClock

LIMITS = ForceLimits(max_force_n=20.0, max_torque_nm=3.0, monitor_rate_hz=1000.0, wrench_timeout_s=0.05)


def wrench(force_z: float = 0.0, torque_z: float = 0.0, stamp: float = 0.0) -> Wrench:
    return Wrench(np.array([0.0, 0.0, force_z]), np.array([0.0, 0.0, torque_z]), stamp)


class WrenchScript:
    """A fake async wrench source: each read advances the fake clock by `dt_s` and returns the next sample.

    Samples are `(force_z, torque_z)` pairs stamped with the fake time, or ready-made values
    (None, a Wrench, an exception to raise, a callable to await); after the script the last
    entry repeats.
    """

    def __init__(self, clock: FakeClock, script: Sequence[object], dt_s: float = 0.005) -> None:
        self.clock, self.script, self.dt_s, self.reads = clock, list(script), dt_s, 0

    async def __call__(self) -> Wrench | None:
        item = self.script[min(self.reads, len(self.script) - 1)]
        self.reads += 1
        self.clock.now += self.dt_s
        if isinstance(item, BaseException):
            raise item
        if callable(item):
            return await item()
        if isinstance(item, tuple):
            return wrench(item[0], item[1], stamp=self.clock.now)
        return item  # type: ignore[return-value]


def monitor(
    script: Sequence[object], limits: ForceLimits = LIMITS, dt_s: float = 0.005
) -> tuple[ForceMonitor, WrenchScript]:
    clock = FakeClock(10.0)
    source = WrenchScript(clock, script, dt_s)
    return ForceMonitor(limits, source, clock=clock), source


async def run_until_violation(mon: ForceMonitor, on_violation: Callable | None = None) -> ForceViolation:
    with anyio.fail_after(5):  # a safety net for the test itself, never reached when correct
        return await mon.run(on_violation)


@pytest.mark.anyio
async def test_stops_when_force_exceeds_the_limit() -> None:
    mon, source = monitor([(5.0, 0.0), (19.9, 0.0), (20.5, 0.0)])
    violation = await run_until_violation(mon)
    assert violation.kind == "force_limit" and violation.force_n == pytest.approx(20.5)
    assert "20.50 N" in violation.detail and "limit of 20 N" in violation.detail
    assert source.reads == 3
    assert violation.at_mono == pytest.approx(10.015)


@pytest.mark.anyio
async def test_stops_when_torque_exceeds_the_limit() -> None:
    mon, _ = monitor([(1.0, 1.0), (1.0, 3.5)])
    violation = await run_until_violation(mon)
    assert violation.kind == "torque_limit" and violation.torque_nm == pytest.approx(3.5)


@pytest.mark.anyio
async def test_tracks_the_largest_force_and_torque_observed() -> None:
    mon, _ = monitor([(3.0, 0.5), (12.0, 0.1), (7.0, 2.0), None])
    await run_until_violation(mon)
    assert mon.max_observed_force_n == pytest.approx(12.0)
    assert mon.max_observed_torque_nm == pytest.approx(2.0)
    assert mon.samples == 3


@pytest.mark.anyio
async def test_calls_on_violation_before_returning() -> None:
    mon, _ = monitor([(25.0, 0.0)])
    seen: list[ForceViolation] = []

    async def on_violation(violation: ForceViolation) -> None:
        await anyio.lowlevel.checkpoint()
        seen.append(violation)

    violation = await run_until_violation(mon, on_violation)
    assert seen == [violation]


@pytest.mark.anyio
async def test_on_violation_completes_even_if_the_monitor_is_cancelled_meanwhile() -> None:
    mon, _ = monitor([(25.0, 0.0)])
    finished: list[str] = []

    async def slow_stop(_violation: ForceViolation) -> None:
        await anyio.sleep(0.02)
        finished.append("stopped")

    async with anyio.create_task_group() as tg:
        tg.start_soon(mon.run, slow_stop)
        await anyio.sleep(0.005)
        tg.cancel_scope.cancel()  # e.g. the execution finished at the same moment
    assert finished == ["stopped"]


@pytest.mark.anyio
async def test_runs_until_cancelled_when_everything_is_fine() -> None:
    mon, source = monitor([(2.0, 0.1)])

    with anyio.move_on_after(0.05):
        await mon.run()
        pytest.fail("the monitor returned without a violation")
    assert source.reads > 3


@pytest.mark.anyio
async def test_missing_wrench_fails_closed() -> None:
    mon, _ = monitor([(1.0, 0.0), None])
    violation = await run_until_violation(mon)
    assert violation.kind == "wrench_missing" and violation.force_n is None


@pytest.mark.anyio
async def test_failing_wrench_read_fails_closed_as_missing() -> None:
    mon, _ = monitor([(1.0, 0.0), BackendError("sensor bus down\nretrying")])
    violation = await run_until_violation(mon)
    assert violation.kind == "wrench_missing" and "BackendError: sensor bus down retrying" in violation.detail


@pytest.mark.anyio
async def test_slow_wrench_read_fails_closed_as_timeout() -> None:
    async def hang() -> Wrench:
        await anyio.sleep_forever()
        raise AssertionError("unreachable")

    mon, _ = monitor([(1.0, 0.0), hang])
    violation = await run_until_violation(mon)
    assert violation.kind == "wrench_timeout" and "0.05 s" in violation.detail


@pytest.mark.anyio
async def test_frozen_stamp_fails_closed_once_older_than_the_timeout() -> None:
    frozen = wrench(1.0, 0.0, stamp=10.02)  # fresh when first read, then never again
    mon, source = monitor([frozen], dt_s=0.02)  # 20 ms per read, timeout 50 ms
    violation = await run_until_violation(mon)
    assert violation.kind == "wrench_frozen"
    assert source.reads == 4  # first read sets the stamp; 20, 40 ms are tolerated; 60 ms is not
    assert violation.force_n == pytest.approx(1.0)


@pytest.mark.anyio
async def test_fresh_samples_read_slowly_are_neither_frozen_nor_stale() -> None:
    mon, _ = monitor([(1.0, 0.0)] * 30 + [None], dt_s=0.04)  # each stamped at its read, 40 ms apart
    violation = await run_until_violation(mon)
    assert violation.kind == "wrench_missing"  # only the scripted end


@pytest.mark.anyio
async def test_a_stamp_that_keeps_advancing_but_lags_the_clock_is_stale() -> None:
    stamps = iter(np.arange(0.0, 1.0, 0.001))  # advancing, but seconds behind the monotonic clock
    mon, _ = monitor([lambda: _async(wrench(1.0, 0.0, float(next(stamps))))] * 30 + [None], dt_s=0.04)
    violation = await run_until_violation(mon)
    assert violation.kind == "wrench_stale" and "s old" in violation.detail


@pytest.mark.anyio
async def test_a_baseline_read_from_an_old_sample_is_refused() -> None:
    mon, _ = monitor([wrench(1.0, 0.0, stamp=5.0)])  # 5 s old at the first read
    refused = await mon.baseline()
    assert isinstance(refused, ForceViolation) and refused.kind == "wrench_stale"


@pytest.mark.anyio
async def test_an_above_limit_baseline_cannot_ratchet_up_across_executions() -> None:
    # resting on a surface above the limit: the first motion may rise 1 N; the next one, starting
    # higher, is held to the first one's ceiling
    first, _ = monitor([(LIMITS.max_force_n + 4.0, 0.0)])
    await first.baseline()
    ceiling = first.contact_ceiling
    assert ceiling[0] == pytest.approx(LIMITS.max_force_n + 5.0) and ceiling[1] is None
    clock = FakeClock(10.0)
    later = ForceMonitor(LIMITS, WrenchScript(clock, [(LIMITS.max_force_n + 4.9, 0.0)]), clock=clock,
                         carried_ceiling=ceiling)
    await later.baseline()
    assert later.force_threshold_n == pytest.approx(LIMITS.max_force_n + 5.0)  # not 4.9 + 1


@pytest.mark.anyio
async def test_a_baseline_far_above_the_limit_is_excessive() -> None:
    mon, _ = monitor([(3.0 * LIMITS.max_force_n, 0.0)])
    await mon.baseline()
    assert mon.baseline_excessive


@pytest.mark.anyio
async def test_check_once_catches_a_crossing_after_the_last_poll() -> None:
    mon, _ = monitor([(LIMITS.max_force_n + 3.0, 0.0)])
    violation = await mon.check_once()
    assert violation is not None and violation.kind == "force_limit"


async def _async(value: Wrench) -> Wrench:
    return value


@pytest.mark.anyio
@pytest.mark.parametrize(
    "bad",
    [
        wrench(float("nan")),
        wrench(0.0, float("inf")),
        Wrench(np.array([1.0, 2.0]), np.zeros(3), 0.0),
        Wrench(np.zeros(3), np.zeros(3), float("nan")),
        "not a wrench",
    ],
)
async def test_invalid_wrench_fails_closed(bad: object) -> None:
    mon, _ = monitor([(1.0, 0.0), bad])
    violation = await run_until_violation(mon)
    assert violation.kind == "wrench_invalid"


@pytest.mark.anyio
async def test_baseline_reads_one_wrench() -> None:
    mon, source = monitor([(4.0, 0.2)])
    base = await mon.baseline()
    assert base is not None and base.force_norm_n == pytest.approx(4.0)
    assert mon.baseline_wrench is base and source.reads == 1
    assert mon.force_threshold_n == LIMITS.max_force_n  # a baseline below the limit changes nothing


@pytest.mark.anyio
@pytest.mark.parametrize("bad", [None, wrench(float("nan")), BackendError("x")])
async def test_baseline_is_the_violation_when_the_wrench_is_unusable(bad: object) -> None:
    mon, _ = monitor([bad])
    refused = await mon.baseline()
    assert isinstance(refused, ForceViolation) and refused.kind in ("wrench_missing", "wrench_invalid")
    assert mon.baseline_wrench is None


@pytest.mark.anyio
async def test_baseline_above_the_limit_allows_moving_but_not_pushing_more_than_1_n() -> None:
    mon, _ = monitor([(25.0, 0.0), (25.9, 0.0), (24.0, 0.0), (26.1, 0.0)])
    await mon.baseline()
    violation = await mon.run()
    assert mon.force_threshold_n == pytest.approx(26.0)
    assert violation.kind == "force_limit" and violation.force_n == pytest.approx(26.1)
    assert "baseline above the 20 N limit" in violation.detail


@pytest.mark.anyio
async def test_baseline_above_the_torque_limit_allows_a_rise_of_0_2_nm() -> None:
    mon, _ = monitor([(0.0, 4.0), (0.0, 4.15), (0.0, 4.25)])
    await mon.baseline()
    violation = await mon.run()
    assert mon.torque_threshold_nm == pytest.approx(4.2)
    assert violation.kind == "torque_limit" and violation.torque_nm == pytest.approx(4.25)


@pytest.mark.anyio
async def test_polls_at_the_configured_rate() -> None:
    slow = ForceLimits(max_force_n=20.0, max_torque_nm=3.0, monitor_rate_hz=50.0, wrench_timeout_s=0.05)
    mon, source = monitor([(1.0, 0.0)], limits=slow)

    with anyio.move_on_after(0.1):
        await mon.run()
    assert 2 <= source.reads <= 7  # 50 Hz for 0.1 s, with generous slack for a busy machine


def test_limits_from_policy(fr3_policy: Policy) -> None:
    limits = ForceLimits.from_policy(fr3_policy)
    force = fr3_policy.force
    assert (limits.max_force_n, limits.max_torque_nm) == (force.max_contact_force_n, force.max_contact_torque_nm)
    assert limits.monitor_rate_hz == force.monitor_rate_hz and limits.wrench_timeout_s == force.wrench_timeout_s
    assert limits.require_wrench == force.require_wrench


@pytest.mark.parametrize("field", ["max_force_n", "max_torque_nm", "monitor_rate_hz", "wrench_timeout_s"])
@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_limits_reject_non_positive_or_non_finite_values(field: str, bad: float) -> None:
    values = {"max_force_n": 20.0, "max_torque_nm": 3.0, "monitor_rate_hz": 100.0, "wrench_timeout_s": 0.1}
    values[field] = bad
    with pytest.raises(ConfigurationError, match=field):
        ForceLimits(**values)


@pytest.mark.anyio
async def test_violation_converts_to_plain_data_for_the_estop_event() -> None:
    mon, _ = monitor([(30.0, 0.0)])
    data = (await run_until_violation(mon)).to_dict()
    assert data["kind"] == "force_limit" and data["force_n"] == pytest.approx(30.0)
    assert set(data) == {"kind", "detail", "force_n", "torque_nm", "at_mono"}
