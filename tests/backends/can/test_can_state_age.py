"""The CAN backend's joint state is as old as its data (issue 24, item 10): it carries the time of
the oldest actuator reply that went into it, never the time of the servo tick that published it,
so actuators that go silent make the state age and the Guard refuse it.

Found by review: 10 s after every actuator went silent, `get_robot_state` still returned the last
positions (and a frozen velocity) with a fresh stamp on every tick.
"""

from __future__ import annotations

import time

import anyio
import pytest

from armwarden.backends.can.backend import CanBackend
from tests.backends.can.test_can_backend import all_motors
from tests.helpers import text_of
from tests.server.harness import arm_harness

pytestmark = pytest.mark.anyio

#: how long the state must visibly age once the replies have stopped [s]
AGED_S = 0.2


async def settled_stamp(arm: CanBackend) -> float:
    """The joint state's stamp once it has stopped changing for 0.3 s (replies already on their way
    when the actuators went silent still arrive, later on a loaded host)."""
    last, since = (await arm.read_joint_state()).stamp, time.monotonic()
    with anyio.fail_after(10.0):  # a stamp that keeps advancing never settles: the state claims fresh data
        while time.monotonic() - since < 0.3:
            await anyio.sleep(0.05)
            if (latest := (await arm.read_joint_state()).stamp) != last:
                last, since = latest, time.monotonic()
    return last


async def test_silent_actuators_leave_the_joint_state_with_the_time_of_their_last_reply(arm: CanBackend) -> None:
    emulator = arm.emulator
    assert emulator is not None
    fresh = await arm.read_joint_state()
    assert time.monotonic() - fresh.stamp < 0.5
    for motor in all_motors(arm):
        emulator.silence(motor)
    last = await settled_stamp(arm)
    await anyio.sleep(AGED_S)  # servo ticks go on publishing; the data does not get newer
    aged = await arm.read_joint_state()
    assert aged.stamp == last and time.monotonic() - aged.stamp >= AGED_S


async def test_one_silent_actuator_is_enough_for_the_joint_state_to_age(arm: CanBackend) -> None:
    emulator = arm.emulator
    assert emulator is not None
    emulator.silence(3)  # fr3_joint3; the six others keep answering every tick
    last = await settled_stamp(arm)
    await anyio.sleep(AGED_S)
    aged = await arm.read_joint_state()
    assert aged.stamp == last and time.monotonic() - aged.stamp >= AGED_S


async def test_get_robot_state_refuses_the_positions_of_silent_actuators(tmp_path) -> None:
    async with arm_harness(tmp_path, backend="can") as arm, arm.client() as client:
        assert not (await client.call_tool("get_robot_state", {})).is_error
        backend = arm.inner
        assert isinstance(backend, CanBackend) and backend.emulator is not None
        for motor in all_motors(backend):
            backend.emulator.silence(motor)
        with anyio.fail_after(10.0):  # the Guard's 0.5 s age limit, however late the last reply came
            state = await client.call_tool("get_robot_state", {})
            while not state.is_error:
                await anyio.sleep(0.05)
                state = await client.call_tool("get_robot_state", {})
        assert "STALE_STATE" in text_of(state) and "s old" in text_of(state), text_of(state)


async def test_the_contact_observer_gets_only_states_every_actuator_answered(arm: CanBackend) -> None:
    """A state that mixes one actuator's old reply with the others' new ones is published (stamped
    by its oldest part) but not kept for the observer, which would read the mix as a contact."""
    emulator = arm.emulator
    assert emulator is not None
    answered = arm.joint_history.since(0.0)
    assert len(answered) > 1 and [s.stamp for s in answered] == sorted({s.stamp for s in answered})
    emulator.silence(3)
    await settled_stamp(arm)
    kept = arm.joint_history.since(0.0)[-1]
    await anyio.sleep(AGED_S)  # six actuators go on answering every tick
    assert arm.joint_history.since(kept.stamp) == ()
    # the observer's read gets the last kept state again, not the newer mixed one published since
    assert [s.stamp for s in await arm.read_joint_states_since(kept.stamp)] == [kept.stamp]
    # and its first read starts there too: a newer start would make the next read go back in time
    assert [s.stamp for s in await arm.read_joint_states_since(None)] == [kept.stamp]
