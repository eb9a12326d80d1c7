"""The explicit arm state: its transition table, and what a real backend reports through real calls."""

from __future__ import annotations

import asyncio
import sys
import time
from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from armwarden.backends.arm_state import (
    ALWAYS_ALLOWED,
    TRANSITIONS,
    ArmEvent,
    ArmState,
    ArmStateError,
    ArmStateMachine,
)
from armwarden.backends.base import Backend
from armwarden.backends.can import robstride as rs
from armwarden.backends.can.backend import CanBackend
from armwarden.backends.fake.backend import FakeBackend
from armwarden.core.errors import BackendError
from armwarden.core.trajectory import JointTrajectory
from armwarden.daemon.startup import SWITCH_INTERVAL_S
from armwarden.robots import load_profile
from tests.backends.arm_states import DEADLINE_S, reaches
from tests.backends.can.test_can_backend import build as build_can_arm
from tests.backends.minimal_backend import MinimalBackend
from tests.helpers import run_opened

_READY = load_profile("fr3").ready_joint_positions or {}
JOINTS, Q_READY = tuple(_READY), np.array(tuple(_READY.values()))
Q_REACH = Q_READY + np.array([0.3, 0.2, 0.0, 0.2, 0.0, 0.0, 0.3])


def line(q_start: np.ndarray, q_goal: np.ndarray, duration_s: float) -> JointTrajectory:
    times = np.linspace(0.0, duration_s, max(2, round(duration_s / 0.01) + 1))
    alpha = times / duration_s
    return JointTrajectory(JOINTS, times, np.outer(1 - alpha, q_start) + np.outer(alpha, q_goal))


# ---------------------------------------------------------------------------- the table
@given(st.lists(st.sampled_from(ArmEvent), max_size=40))
def test_any_event_sequence_keeps_the_state_one_the_table_allows(events: list[ArmEvent]) -> None:
    machine = ArmStateMachine("test")
    for event in events:
        before = machine.state
        allowed = TRANSITIONS.get((before, event))
        if allowed is None:
            with pytest.raises(ArmStateError, match="internal error"):
                machine.apply(event)
            assert machine.state is before
        else:
            assert machine.apply(event) is allowed
            assert machine.state is allowed


@pytest.mark.parametrize("state", list(ArmState))
@pytest.mark.parametrize("event", [event for event in ArmEvent if event in ALWAYS_ALLOWED])
def test_stops_damping_faults_and_close_are_never_refused(state: ArmState, event: ArmEvent) -> None:
    assert (state, event) in TRANSITIONS


@pytest.mark.parametrize("state", [ArmState.MOVING, ArmState.DAMPED, ArmState.FAULTED, ArmState.CLOSED])
def test_nothing_starts_moving_from_a_damped_faulted_moving_or_closed_arm(state: ArmState) -> None:
    assert (state, ArmEvent.EXECUTE) not in TRANSITIONS


def test_a_fault_stays_latched_until_a_recovery() -> None:
    machine = ArmStateMachine("test")
    machine.apply(ArmEvent.OPEN)
    machine.apply(ArmEvent.FAULT)
    for event in (ArmEvent.STOP, ArmEvent.DAMP, ArmEvent.FINISH, ArmEvent.OPEN):
        assert machine.apply(event) is ArmState.FAULTED
    assert machine.apply(ArmEvent.RECOVER) is ArmState.IDLE


def test_an_illegal_event_is_logged_as_an_internal_error(caplog: pytest.LogCaptureFixture) -> None:
    machine = ArmStateMachine("arm under test")
    with pytest.raises(ArmStateError):
        machine.apply(ArmEvent.EXECUTE)  # closed: nothing may move
    assert any(r.levelname == "ERROR" and "arm under test" in r.getMessage() for r in caplog.records)


def test_the_time_of_the_last_change_is_recorded_and_kept_when_nothing_changes() -> None:
    now = [10.0]
    machine = ArmStateMachine("test", clock=lambda: now[0])
    now[0] = 11.0
    machine.apply(ArmEvent.OPEN)
    now[0] = 12.0
    machine.apply(ArmEvent.RECOVER)  # idle -> idle: no change
    assert machine.changed_at == 11.0


# ---------------------------------------------------------------------------- the fake backend
def test_a_new_backend_is_closed_and_an_opened_one_idle() -> None:
    backend = FakeBackend()
    assert backend.arm_state is ArmState.CLOSED

    async def scenario(opened: FakeBackend) -> ArmState:
        return opened.arm_state

    assert run_opened(lambda: backend, scenario) is ArmState.IDLE


def _minimal() -> MinimalBackend:
    """A backend written from the guide alone: no arm event of its own (`reports_motion_events`)."""
    return MinimalBackend(JOINTS, tuple(Q_READY), start_tolerance_rad=0.01, speedup=1.0)


#: a servo backend that reports its own motion events, and one whose events the base class reports
BUILDS = pytest.mark.parametrize("build", [FakeBackend, _minimal], ids=["servo", "plain"])


@BUILDS
def test_an_execution_is_moving_until_it_completes_then_idle(build: Callable[[], Backend]) -> None:
    async def scenario(backend: Backend) -> tuple[ArmState, bool, ArmState]:
        task = asyncio.create_task(backend.execute(line(Q_READY, Q_REACH, 1.0)))
        during = await reaches(backend, ArmState.MOVING)
        result = await task
        return during, result.completed, backend.arm_state

    during, completed, after = run_opened(build, scenario)
    assert during is ArmState.MOVING
    assert completed and after is ArmState.IDLE


@BUILDS
def test_a_stop_mid_motion_holds_the_arm(build: Callable[[], Backend]) -> None:
    async def scenario(backend: Backend) -> tuple[str, ArmState]:
        task = asyncio.create_task(backend.execute(line(Q_READY, Q_REACH, 30.0)))
        assert await reaches(backend, ArmState.MOVING) is ArmState.MOVING
        backend.stop_now()  # (from this thread, as the e-stop channel does)
        return (await task).reason, backend.arm_state

    reason, state = run_opened(build, scenario)
    assert reason == "stopped" and state is ArmState.HELD


def test_an_injected_fault_latches_faulted_and_close_ends_closed() -> None:
    async def scenario(backend: FakeBackend) -> tuple[ArmState, FakeBackend]:
        backend.inject_worker_failure("control", RuntimeError("injected: the control thread dies"))
        faulted = await reaches(backend, ArmState.FAULTED)
        with pytest.raises(BackendError):  # a dead thread is recovered only by a restart
            await backend.error_recovery()
        assert backend.arm_state is ArmState.FAULTED
        return faulted, backend

    faulted, backend = run_opened(FakeBackend, scenario)
    assert faulted is ArmState.FAULTED
    assert backend.arm_state is ArmState.CLOSED


def test_error_recovery_makes_a_held_arm_idle() -> None:
    async def scenario(backend: FakeBackend) -> tuple[ArmState, ArmState]:
        await backend.stop()
        held = backend.arm_state
        await backend.error_recovery()
        return held, backend.arm_state

    assert run_opened(FakeBackend, scenario) == (ArmState.HELD, ArmState.IDLE)


# ---------------------------------------------------------------------------- the CAN backend
@pytest.mark.realtime
def test_a_can_fault_latches_faulted_until_the_execution_a_reset_admits_recovers_it() -> None:
    """CAN recovers inside the execution the Guard admits after a human reset (`_recover` reports
    the recovery before the hand-over to its servo loop), and the arm moves again, then rests idle."""

    async def scenario(arm: CanBackend) -> tuple[ArmState, ArmState, bool, ArmState]:
        emulator = arm.emulator
        assert emulator is not None
        emulator.raise_fault(3, rs.FeedbackFault.OVER_CURRENT)
        faulted = await reaches(arm, ArmState.FAULTED)
        emulator.clear_faults(3)
        deadline = time.monotonic() + DEADLINE_S
        while arm._conditions(time.monotonic()):  # the cleared bit comes with the next feedback frames
            assert time.monotonic() < deadline, "the fault did not clear"
            await asyncio.sleep(0.01)
        latched = arm.arm_state  # cleared on the bus, still latched: only the reset's execution recovers
        while True:  # damping lets the arm drift: start from where it rests
            q = (await arm.read_joint_state()).positions.copy()
            await asyncio.sleep(0.05)
            if np.max(np.abs((await arm.read_joint_state()).positions - q)) < 1e-3:
                break
            assert time.monotonic() < deadline, "the damped arm did not come to rest"
        result = await arm.execute(line(q, q + 0.05, 0.3))
        return faulted, latched, result.completed, arm.arm_state

    switch_interval = sys.getswitchinterval()
    sys.setswitchinterval(SWITCH_INTERVAL_S)  # as `armwarden serve` runs (tests/backends/can/conftest.py)
    try:
        faulted, latched, completed, after = run_opened(build_can_arm, scenario)
    finally:
        sys.setswitchinterval(switch_interval)
    assert faulted is ArmState.FAULTED and latched is ArmState.FAULTED
    assert completed and after is ArmState.IDLE
