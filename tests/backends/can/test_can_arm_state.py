"""The CAN arm's explicit state through real calls on the emulated arm: an e-stop damps it (not a
stiff hold), a fault damps then latches it, the execution a reset admits recovers it, moves it and
leaves it idle, and a setpoint the frames out refuse damps it before the next tick makes it a fault."""

from __future__ import annotations

import asyncio
import time

import numpy as np
import pytest

from armwarden.backends.arm_state import ArmEvent, ArmState
from armwarden.backends.can import robstride as rs
from armwarden.backends.can.backend import CanBackend
from armwarden.core.errors import BackendError
from tests.backends.arm_states import DEADLINE_S, reaches
from tests.backends.can.test_can_backend import POLICY
from tests.backends.contract import straight_line

pytestmark = pytest.mark.anyio


class Events:
    """Every arm event the backend reports, with the state it led to, in order."""

    def __init__(self, backend: CanBackend) -> None:
        self.seen: list[tuple[ArmEvent, ArmState]] = []
        report = backend._arm_event

        def recording(event: ArmEvent) -> ArmState:
            state = report(event)
            self.seen.append((event, state))
            return state

        backend._arm_event = recording  # type: ignore[method-assign]

    def events(self) -> list[ArmEvent]:
        return [event for event, _ in self.seen]


async def at_rest(backend: CanBackend) -> np.ndarray:
    """The measured positions once the (damped, drifting) arm has come to rest."""
    deadline = time.monotonic() + DEADLINE_S
    while True:
        q = (await backend.read_joint_state()).positions.copy()
        await asyncio.sleep(0.05)
        if np.max(np.abs((await backend.read_joint_state()).positions - q)) < 1e-3:
            return q
        assert time.monotonic() < deadline, "the damped arm did not come to rest"


async def test_an_estop_leaves_the_arm_damped_not_held(arm: CanBackend):
    await arm.emergency_stop()
    assert arm.arm_state is ArmState.DAMPED


async def test_a_fault_damps_the_arm_then_latches_it_faulted(arm: CanBackend):
    events = Events(arm)
    assert arm.emulator is not None
    arm.emulator.raise_fault(3, rs.FeedbackFault.OVER_CURRENT)
    assert await reaches(arm, ArmState.FAULTED) is ArmState.FAULTED
    assert (ArmEvent.DAMP, ArmState.DAMPED) in events.seen
    assert events.events().index(ArmEvent.DAMP) < events.events().index(ArmEvent.FAULT)


async def test_the_execution_a_reset_admits_recovers_the_damped_arm_moves_it_and_leaves_it_idle(arm: CanBackend):
    await arm.emergency_stop()
    q = await at_rest(arm)
    events = Events(arm)
    seen_moving = False

    async def watch() -> None:
        nonlocal seen_moving
        while not seen_moving:
            seen_moving = arm.arm_state is ArmState.MOVING
            await asyncio.sleep(0.002)

    watcher = asyncio.create_task(watch())
    try:
        result = await arm.execute(straight_line(arm.joint_names, q, q + 0.05, 0.5))
    finally:
        watcher.cancel()
    assert result.completed
    assert events.events()[:2] == [ArmEvent.STOP, ArmEvent.RECOVER]  # the hold, then damping ends
    assert (ArmEvent.EXECUTE, ArmState.MOVING) in events.seen
    assert seen_moving
    assert arm.arm_state is ArmState.IDLE


async def test_a_hold_the_frames_out_refuse_damps_the_arm_before_the_fault(arm: CanBackend):
    """A joint pushed past its policy limit (a rigid obstacle moves it there): the stop's hold at
    the measured position is never sent; the stream damps instead, and the next tick faults."""
    emulator = arm.emulator
    assert emulator is not None
    joint = arm.config.joints[0]
    upper = POLICY.robot.upper_limits[0]
    q0 = (await arm.read_joint_state()).positions[0]
    beyond = emulator.snapshot(joint.can_id).position_rad + joint.direction * (upper + 0.05 - q0)
    if joint.direction > 0:
        emulator.place_obstacle(joint.can_id, low_rad=beyond)
    else:
        emulator.place_obstacle(joint.can_id, high_rad=beyond)
    deadline = time.monotonic() + DEADLINE_S
    while (await arm.read_joint_state()).positions[0] <= upper:
        assert time.monotonic() < deadline, "the obstacle did not push the joint past its limit"
        await asyncio.sleep(0.005)
    events = Events(arm)
    await arm.stop()
    assert await reaches(arm, ArmState.FAULTED) is ArmState.FAULTED
    assert (ArmEvent.DAMP, ArmState.DAMPED) in events.seen
    assert events.events().index(ArmEvent.DAMP) < events.events().index(ArmEvent.FAULT)
    assert arm.fault is not None and "outside the policy limits" in arm.fault


async def test_an_execution_while_the_frames_out_damp_is_refused_by_name(arm: CanBackend):
    """The tick after a refused setpoint damps before the fault latches: an execution handed over
    then is refused naming the damping (not as an internal arm-state error) and sends no motion."""
    q = (await arm.read_joint_state()).positions
    frames_before = arm.motion_frames
    with arm._fault_lock:  # the frames out's damping and its report, as between refusal and fault
        arm._stream.damping = True
        arm._arm_event(ArmEvent.DAMP)
    with pytest.raises(BackendError, match="damping after a setpoint outside the policy limits"):
        await arm.execute(straight_line(arm.joint_names, q, q + 0.05, 0.5))
    assert arm.motion_frames == frames_before
    assert arm.arm_state is ArmState.DAMPED  # the refusal's stop does not stiffen damped drives
