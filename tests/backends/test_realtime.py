"""Real-time scheduling of a control thread: asked for, granted or refused with the reason."""

from __future__ import annotations

import os
import threading
from typing import Any

import numpy as np
import pytest

from armwarden.backends import realtime
from armwarden.backends.realtime import make_current_thread_realtime
from armwarden.backends.servo import ServoHooks, ServoLoop
from armwarden.core.errors import BackendError


class SchedulerSpy:
    """Stands in for os.sched_setscheduler: records each request, or refuses as the kernel would."""

    def __init__(self, refuse: OSError | None = None) -> None:
        self.calls: list[tuple[int, int, int, str]] = []
        self.refuse = refuse

    def __call__(self, pid: int, policy: int, param: Any) -> None:
        self.calls.append((pid, policy, param.sched_priority, threading.current_thread().name))
        if self.refuse is not None:
            raise self.refuse


@pytest.mark.parametrize("priority", [0, 100, -1, 1.5, True, "50"])
def test_a_priority_outside_1_to_99_is_refused_before_asking_the_system(monkeypatch: pytest.MonkeyPatch, priority: Any) -> None:
    spy = SchedulerSpy()
    monkeypatch.setattr(realtime.os, "sched_setscheduler", spy)
    with pytest.raises(BackendError, match=r"integer in 1\.\.99"):
        make_current_thread_realtime(priority)
    assert spy.calls == []


def test_the_calling_thread_asks_for_sched_fifo_at_the_priority(monkeypatch: pytest.MonkeyPatch) -> None:
    spy = SchedulerSpy()
    monkeypatch.setattr(realtime.os, "sched_setscheduler", spy)
    make_current_thread_realtime(42)
    assert spy.calls == [(0, os.SCHED_FIFO, 42, threading.current_thread().name)]


def test_a_system_that_refuses_says_what_the_thread_needs(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(realtime.os, "sched_setscheduler", SchedulerSpy(PermissionError(1, "Operation not permitted")))
    with pytest.raises(BackendError, match=r"SCHED_FIFO priority 30: Operation not permitted; it needs CAP_SYS_NICE"):
        make_current_thread_realtime(30)


@pytest.mark.anyio
async def test_a_servo_loop_asks_for_it_from_its_own_thread(monkeypatch: pytest.MonkeyPatch) -> None:
    spy = SchedulerSpy()
    monkeypatch.setattr(realtime.os, "sched_setscheduler", spy)
    loop = ServoLoop(ServoHooks(), np.zeros(2), period_s=0.002, name="test", realtime_priority=10)
    await loop.start("rt-servo-under-test")
    await loop.shutdown()
    assert spy.calls == [(0, os.SCHED_FIFO, 10, "rt-servo-under-test")]


@pytest.mark.anyio
async def test_a_servo_loop_the_system_refuses_does_not_start_and_says_why(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(realtime.os, "sched_setscheduler", SchedulerSpy(PermissionError(1, "Operation not permitted")))
    loop = ServoLoop(ServoHooks(), np.zeros(2), period_s=0.002, name="test", realtime_priority=10)
    with pytest.raises(BackendError, match="SCHED_FIFO priority 10"):
        await loop.start()
    await loop.shutdown()
    assert loop.tick_count == 0


@pytest.mark.anyio
async def test_a_servo_loop_without_a_priority_keeps_the_ordinary_scheduler(monkeypatch: pytest.MonkeyPatch) -> None:
    spy = SchedulerSpy()
    monkeypatch.setattr(realtime.os, "sched_setscheduler", spy)
    loop = ServoLoop(ServoHooks(), np.zeros(2), period_s=0.002, name="test")
    await loop.start()
    await loop.shutdown()
    assert spy.calls == []
