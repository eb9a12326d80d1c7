"""A cell's capabilities are the parts it has: nothing is declared beside them."""

from __future__ import annotations

import dataclasses

import pytest

from armwarden.backends.parts import Cameras, Capabilities, Cell, Gripper
from armwarden.backends.values import CameraImage, GripperResult
from armwarden.core.state import GripperState


class _Fingers(Gripper):
    def state(self) -> GripperState:
        raise AssertionError("not called")

    async def move(self, width_m: float, speed_mps: float) -> GripperResult:
        raise AssertionError("not called")

    async def grasp(self, width_m, force_n, speed_mps, epsilon_inner_m, epsilon_outer_m) -> GripperResult:
        raise AssertionError("not called")

    async def home(self) -> GripperResult:
        raise AssertionError("not called")

    def stop_now(self) -> None:
        pass


class _TwoCameras(Cameras):
    @property
    def names(self) -> tuple[str, ...]:
        return ("scene", "wrist")

    async def snapshot(self, camera: str) -> CameraImage:
        raise AssertionError("not called")


def test_an_empty_cell_offers_nothing_but_the_arm() -> None:
    assert Cell().capabilities == Capabilities()


def test_a_gripper_part_makes_the_gripper_a_capability() -> None:
    assert Cell(gripper=_Fingers()).capabilities == Capabilities(gripper=True)


def test_the_cameras_offered_are_the_camera_part_s_names() -> None:
    assert Cell(cameras=_TwoCameras()).capabilities.cameras == ("scene", "wrist")


def test_the_frames_a_cell_reports_are_its_own() -> None:
    assert Cell(frames=("fr3_link0", "fr3_hand_tcp")).capabilities.frames == ("fr3_link0", "fr3_hand_tcp")


def test_every_capability_has_a_part_of_the_same_name() -> None:
    parts = {f.name for f in dataclasses.fields(Cell)}
    assert {f.name for f in dataclasses.fields(Capabilities)} == parts


def test_a_cell_cannot_be_changed_once_built() -> None:
    with pytest.raises(dataclasses.FrozenInstanceError):
        Cell().gripper = _Fingers()  # type: ignore[misc]
