"""CountingBackend: a real Backend that counts actuations and stops and forwards everything."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from armwarden.backends.arm_state import ArmState
from armwarden.backends.base import Backend
from armwarden.backends.counting import ACTUATING_METHODS, CountingBackend
from armwarden.backends.fake.backend import FakeBackend
from armwarden.backends.parts import Cell, FrameTree
from armwarden.core.errors import BackendError
from armwarden.core.state import Transform
from armwarden.robots import load_profile
from tests.backends.contract import BackendContract, straight_line
from tests.backends.minimal_backend import MinimalBackend

_READY = load_profile("fr3").ready_joint_positions or {}
FR3_JOINT_NAMES, FR3_READY = tuple(_READY), tuple(_READY.values())

pytestmark = pytest.mark.anyio


class TestCountingBackendContract(BackendContract):
    """Wrapped, a backend still keeps the whole contract."""

    def build(self) -> Backend:
        return CountingBackend(MinimalBackend(FR3_JOINT_NAMES, FR3_READY, start_tolerance_rad=0.01))


async def test_every_actuating_call_is_counted_even_when_the_backend_refuses_it() -> None:
    fake = FakeBackend(speedup=10.0)
    counting = CountingBackend(fake)
    await counting.open()
    try:
        await counting.read_joint_state()
        await counting.gripper_state()
        await counting.list_controllers()
        await counting.graph()
        await counting.camera_snapshot("scene")
        assert counting.actuations == [] and counting.stops == 0
        q = np.array(FR3_READY)
        await counting.execute(straight_line(FR3_JOINT_NAMES, q, q + 0.05, 0.05))
        await counting.gripper_move(0.05, 0.1)
        await counting.gripper_grasp(0.04, 10.0, 0.1, 0.01, 0.01)
        await counting.gripper_home()
        await counting.switch_controllers([], [])
        await counting.set_collision_thresholds(20.0, 20.0)
        await counting.error_recovery()
        with pytest.raises(BackendError):
            await counting.gripper_move(1.0, 0.1)  # refused by the fake, still a command that reached it
        await counting.stop()
        thread = threading.Thread(target=counting.stop_now)
        thread.start()
        thread.join()
    finally:
        await counting.close()
    assert counting.actuations == [*ACTUATING_METHODS, "gripper_move"]
    assert counting.stops == 2


async def test_it_forwards_the_cell_stop_stamp_and_backend_specific_attributes() -> None:
    fake = FakeBackend()
    counting = CountingBackend(fake)
    assert counting.cell is fake.cell and counting.capabilities == fake.capabilities and counting.name == "fake"
    assert counting.start_tolerance_rad == fake.start_tolerance_rad
    await counting.open()
    try:
        assert counting.is_open and fake.is_open
        await counting.stop()
        assert counting.last_stop_stamp is not None and counting.last_stop_stamp == fake.last_stop_stamp
        assert counting.fail_stop is fake.fail_stop  # not part of the contract: read from the fake
        assert counting.tick_count > 0
    finally:
        await counting.close()
    assert not fake.is_open


def test_a_fault_listener_set_on_the_wrapper_hears_the_inner_backends_faults() -> None:
    inner = MinimalBackend(FR3_JOINT_NAMES, FR3_READY, start_tolerance_rad=0.01)
    heard: list[str] = []
    CountingBackend(inner).set_fault_listener(heard.append)
    inner._report_fault("joint 3: over-temperature")
    assert heard == ["joint 3: over-temperature"]


def test_a_fault_reported_before_any_listener_is_told_to_the_first_one_set() -> None:
    """Between the servo thread's start and the Guard's building nobody listens: a fault found
    then is kept and told at once to the listener set next (found by review: it was only logged,
    and the Guard never latched its e-stop)."""
    inner = MinimalBackend(FR3_JOINT_NAMES, FR3_READY, start_tolerance_rad=0.01)
    inner._report_fault("joint 3: over-current on enable")
    heard: list[str] = []
    CountingBackend(inner).set_fault_listener(heard.append)
    inner._report_fault("joint 5: encoder")
    assert heard == ["joint 3: over-current on enable", "joint 5: encoder"]


def test_a_failing_fault_listener_does_not_reach_the_reporting_thread(caplog: pytest.LogCaptureFixture) -> None:
    inner = MinimalBackend(FR3_JOINT_NAMES, FR3_READY, start_tolerance_rad=0.01)

    def broken(reason: str) -> None:
        raise RuntimeError("listener bug")

    inner.set_fault_listener(broken)
    inner._report_fault("bus-off")  # logged, not raised: the backend has already damped the arm
    assert "fault listener failed" in caplog.text


async def test_e_stops_are_counted_as_stops_and_as_e_stops_and_reach_the_inner_backend() -> None:
    inner = MinimalBackend(FR3_JOINT_NAMES, FR3_READY, start_tolerance_rad=0.01)
    counting = CountingBackend(inner)
    await counting.open()
    try:
        before = inner.stop_epoch
        await counting.emergency_stop()
        thread = threading.Thread(target=counting.emergency_stop_now)
        thread.start()
        thread.join()
    finally:
        await counting.close()
    assert (counting.stops, counting.emergency_stops) == (2, 2)
    assert inner.stop_epoch >= before + 2


class _OneFrameTree(FrameTree):
    async def lookup(self, target_frame: str, source_frame: str) -> Transform:
        assert (target_frame, source_frame) == ("world", "camera")
        return Transform(np.array([0.1, 0.0, 0.0]), np.array([0.0, 0.0, 0.0, 1.0]), 0.0)


async def test_a_transform_lookup_reaches_the_inner_backend_s_frame_tree() -> None:
    inner = MinimalBackend(FR3_JOINT_NAMES, FR3_READY, start_tolerance_rad=0.01)
    inner.cell = Cell(transforms=_OneFrameTree())
    counting = CountingBackend(inner)
    await counting.open()
    try:
        transform = await counting.lookup_transform("world", "camera")
    finally:
        await counting.close()
    assert transform.translation.tolist() == [0.1, 0.0, 0.0] and counting.actuations == []


async def test_the_arm_state_read_through_the_wrapper_is_the_inner_backend_s() -> None:
    inner = FakeBackend(speedup=10.0)
    counting = CountingBackend(inner)
    await counting.open()
    try:
        opened = counting.arm_state
        await counting.stop()
        held = counting.arm_state
    finally:
        await counting.close()
    assert (opened, held) == (ArmState.IDLE, ArmState.HELD)
    assert counting.arm_state is inner.arm_state and counting.arm_state_since == inner.arm_state_since
