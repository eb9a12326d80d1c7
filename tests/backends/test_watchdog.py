"""The watchdog's verdict (`armwarden.backends.watchdog`), on a clock stepped by hand: a counter
that moves, however unevenly, within its deadline is never a hang; one that stays still past it is
one hang, reported once; time the watchdog itself was not scheduled is not held against a worker.
The deadlines stay within the Guard's state max age, and a backend watches every thread of its own
or does not open."""

from __future__ import annotations

import pytest

from armwarden.backends.fake.backend import FakeBackend
from armwarden.backends.watchdog import (
    MIN_STALL_DEADLINE_S,
    STALL_LIMIT_S,
    Heartbeat,
    WorkerWatchdog,
    stall_deadline_s,
)
from armwarden.core.errors import BackendError
from armwarden.guard import MAX_STATE_AGE_S


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class Worker:
    def __init__(self) -> None:
        self.ticks = 0


def watch(worker: Worker, clock: Clock, deadline_s: float = 0.25) -> WorkerWatchdog:
    return WorkerWatchdog([Heartbeat("servo", lambda: worker.ticks, deadline_s)], lambda *_: None, clock=clock)


def test_a_loop_whose_ticks_take_three_periods_now_and_then_is_never_a_hang() -> None:
    clock, worker = Clock(), Worker()
    period = 0.01
    watchdog = watch(worker, clock, stall_deadline_s(period))
    start = clock.now
    next_tick, next_check, checks = start, start, 0
    for step in range(1, 20_001):  # 20 s in 1 ms steps: a 10 ms loop, every fifth tick three periods long
        clock.now = start + step * 1e-3
        if clock.now >= next_tick:
            worker.ticks += 1
            next_tick += 3 * period if worker.ticks % 5 == 0 else period
        if clock.now >= next_check:  # the watchdog samples on its own schedule
            assert watchdog.check() == []
            checks += 1
            next_check += watchdog.check_period_s
    assert worker.ticks > 1000 and checks > 500


def test_a_counter_still_past_its_deadline_is_one_hang_reported_once() -> None:
    clock, worker = Clock(), Worker()
    watchdog = watch(worker, clock)
    step = watchdog.check_period_s
    found = []
    for _ in range(100):
        clock.now += step
        found += watchdog.check()
    assert len(found) == 1
    worker_name, stalled_s, deadline_s = found[0]
    assert worker_name == "servo" and deadline_s == 0.25 and stalled_s > deadline_s


def test_a_counter_is_not_hung_before_its_deadline() -> None:
    clock, worker = Clock(), Worker()
    watchdog = watch(worker, clock)
    step = watchdog.check_period_s
    for _ in range(int(0.25 / step) - 1):
        clock.now += step
        assert watchdog.check() == []
    assert watchdog.quiet_s("servo") > 0
    worker.ticks += 1  # it moves on: the stall starts over
    assert watchdog.quiet_s("servo") == 0.0
    for _ in range(int(0.25 / step) - 1):
        clock.now += step
        assert watchdog.check() == []


def test_time_the_watchdog_was_not_scheduled_is_not_held_against_a_worker() -> None:
    clock, worker = Clock(), Worker()
    watchdog = watch(worker, clock)
    clock.now += 10.0  # the whole process stalled (a loaded host, a paused VM): the worker may too
    assert watchdog.check() == []
    worker.ticks += 1
    clock.now += watchdog.check_period_s
    assert watchdog.check() == []
    found = []
    for _ in range(100):  # still from now on, while the watchdog runs on time: a hang
        clock.now += watchdog.check_period_s
        found += watchdog.check()
    assert [f[0] for f in found] == ["servo"]


def test_moved_since_waits_for_every_worker() -> None:
    clock, fast, slow = Clock(), Worker(), Worker()
    watchdog = WorkerWatchdog([Heartbeat("a", lambda: fast.ticks, 0.25), Heartbeat("b", lambda: slow.ticks, 0.25)],
                              lambda *_: None, clock=clock)
    counts = watchdog.counts()
    fast.ticks += 1
    assert not watchdog.moved_since(counts)
    slow.ticks += 1
    assert watchdog.moved_since(counts)


def test_the_deadline_is_twenty_periods_at_least_a_quarter_second_and_never_past_the_state_max_age() -> None:
    assert stall_deadline_s(0.001) == MIN_STALL_DEADLINE_S == 0.25
    assert stall_deadline_s(0.02) == pytest.approx(0.4)
    assert stall_deadline_s(0.025) == pytest.approx(0.5)
    with pytest.raises(ValueError, match=r"above the 0\.5 s limit"):
        stall_deadline_s(0.03)
    with pytest.raises(ValueError, match="outside"):
        Heartbeat("servo", lambda: 0, 0.6)
    assert STALL_LIMIT_S == MAX_STATE_AGE_S  # a hung thread is named before its stale state refuses


def test_a_watchdog_refuses_no_heartbeat_and_a_worker_named_twice() -> None:
    with pytest.raises(ValueError, match="at least one"):
        WorkerWatchdog([], lambda *_: None)
    with pytest.raises(ValueError, match="twice"):
        WorkerWatchdog([Heartbeat("a", lambda: 0, 0.25), Heartbeat("a", lambda: 0, 0.25)], lambda *_: None)


@pytest.mark.anyio
async def test_a_backend_with_a_thread_nobody_watches_refuses_to_open() -> None:
    class Unwatched(FakeBackend):
        def _worker_heartbeats(self) -> tuple[Heartbeat, ...]:
            return ()

    backend = Unwatched()
    with pytest.raises(BackendError, match="every thread of its own must be watched"):
        await backend.open()
    assert not backend.is_open
    thread = backend.servo.thread
    assert thread is not None and not thread.is_alive()  # closed again: the servo thread ended


def test_each_servo_loop_deadline_is_within_the_state_max_age() -> None:
    loop = FakeBackend().servo
    heartbeat = loop.heartbeat("control")
    assert heartbeat.deadline_s == max(20 * loop.idle_period_s, 0.25) <= STALL_LIMIT_S == MAX_STATE_AGE_S
