"""The fake backend builds its cell of parts of its own (armwarden.backends.parts), like MuJoCo:
no capability flags, no optional hooks, each part with its own deadlines."""

from __future__ import annotations

import asyncio

import pytest

from armwarden.backends.base import Backend
from armwarden.backends.fake.backend import FakeBackend
from armwarden.backends.parts import (
    Cameras,
    CollisionThresholds,
    Controllers,
    ErrorRecovery,
    Graph,
    Gripper,
    WrenchSensor,
)
from armwarden.core.errors import BackendError

pytestmark = pytest.mark.anyio

#: the optional hooks of before the cell of parts, which no backend has any more
OPTIONAL_HOOKS = ("_latest_wrench", "_read_wrench", "_latest_gripper_state", "_gripper_move", "_gripper_grasp",
                  "_gripper_home", "_stop_fingers", "_camera_snapshot", "_camera_set_up", "_list_controllers",
                  "_switch_controllers", "_set_collision_thresholds", "_error_recovery", "_graph")


def test_the_fake_cell_is_built_of_the_fake_packages_own_parts() -> None:
    cell = FakeBackend().cell
    parts = {Gripper: cell.gripper, Cameras: cell.cameras, WrenchSensor: cell.wrench, Controllers: cell.controllers,
             CollisionThresholds: cell.collision_thresholds, ErrorRecovery: cell.error_recovery, Graph: cell.graph}
    for base, part in parts.items():
        assert isinstance(part, base), base.__name__
        assert type(part).__module__.startswith("armwarden.backends.fake."), type(part)
    assert cell.transforms is None


def test_the_fake_declares_no_capability_flags_and_no_optional_hooks() -> None:
    assert FakeBackend.capabilities is Backend.capabilities
    assert [hook for hook in OPTIONAL_HOOKS if hook in vars(FakeBackend)] == []


def test_the_finger_travel_is_the_gripper_parts_full_opening() -> None:
    gripper = FakeBackend(gripper_max_width_m=0.05).cell.gripper
    assert gripper is not None
    assert gripper.travel_m == pytest.approx(0.05)


def test_a_fake_without_wrench_has_no_wrench_sensor_part() -> None:
    backend = FakeBackend(wrench=False)
    assert backend.cell.wrench is None
    assert not backend.capabilities.wrench


async def test_a_stop_whose_arm_hold_fails_still_stops_the_fingers() -> None:
    backend = FakeBackend(speedup=1.0)
    await backend.open()
    try:
        move = asyncio.create_task(backend.gripper_move(0.0, 0.01))  # 8 s of travel: still moving at the stop
        await asyncio.sleep(0.05)

        def broken_hold() -> None:
            raise RuntimeError("injected: the hold could not be commanded")

        backend.servo.hold = broken_hold  # type: ignore[method-assign]
        with pytest.raises(BackendError, match="the hold could not be commanded"):
            backend.stop_now()
        result = await asyncio.wait_for(move, 5.0)
    finally:
        del backend.servo.hold
        await backend.close()
    assert not result.success and result.detail == "stopped"
