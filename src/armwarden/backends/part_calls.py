"""The calls to a cell's optional parts, with the rules every part keeps.

`Backend` answers each tool's backend call here by the part it needs (`armwarden.backends.parts`):
the backend must be open and its worker threads alive, the part must be in the cell (else
`BackendError` naming it: the server offers no tool for an absent part, so this is the last line),
an actuating call must not have been overtaken by a stop (the stop epoch it was decided under),
and every call has the part's own deadline (a missed one raises `BackendTimeout`, after a stop if
the call actuates). Kept apart from `armwarden.backends.base` so the arm's lifecycle and the parts'
calls each read as one short class.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Awaitable, Callable, Sequence
from typing import TypeVar

from armwarden.backends.arm_state import ArmEvent, ArmState
from armwarden.backends.parts import Cell
from armwarden.backends.values import CameraImage, ControllerInfo, GripperResult
from armwarden.core.errors import BackendError
from armwarden.core.state import GripperState, Transform, Wrench

T = TypeVar("T")
P = TypeVar("P")


class PartCalls(abc.ABC):
    """The public calls of the optional parts; `Backend` provides what they are built on."""

    name: str
    @property
    @abc.abstractmethod
    def cell(self) -> Cell:
        """The parts of this backend's cell."""
    read_timeout_s: float
    _gripper_epoch: int

    @abc.abstractmethod
    def _require_open(self) -> None: ...

    @abc.abstractmethod
    def _admit(self, stop_epoch: int | None, what: str) -> int: ...

    @abc.abstractmethod
    def _arm_event(self, event: ArmEvent) -> ArmState: ...

    @abc.abstractmethod
    async def _bounded(self, what: str, timeout_s: float, call: Callable[[], Awaitable[T]], *,
                       actuating: bool = False) -> T: ...

    def _part(self, part: P | None, what: str) -> P:
        """`part`, once the backend is open and working; `BackendError` if the cell has none."""
        self._require_open()
        if part is None:
            raise BackendError(f"backend {self.name} has no {what}")
        return part

    # ---------------------------------------------------------------- wrench
    async def read_wrench(self) -> Wrench | None:
        """The latest wrench estimate, or None if this cell has no wrench sensor."""
        self._require_open()
        sensor = self.cell.wrench
        if sensor is None:
            return None
        published = sensor.latest()
        if published is not None:
            return published
        return await self._bounded("wrench read", self.read_timeout_s, sensor.read)

    # ---------------------------------------------------------------- gripper
    def _stop_fingers(self) -> None:
        """Any thread, never awaiting the event loop: the gripper part's `stop_now` (no gripper:
        nothing to stop). The one name every stop, e-stop and fault path calls."""
        gripper = self.cell.gripper
        if gripper is not None:
            gripper.stop_now()

    async def gripper_state(self) -> GripperState | None:
        """The gripper's published state, or None if this cell has no gripper."""
        self._require_open()
        gripper = self.cell.gripper
        return None if gripper is None else gripper.state()

    async def gripper_move(self, width_m: float, speed_mps: float, *, stop_epoch: int | None = None) -> GripperResult:
        """Actuating calls take the `stop_epoch` their caller decided under, like `execute`."""
        gripper = self._part(self.cell.gripper, "gripper")
        self._gripper_epoch = self._admit(stop_epoch, "gripper move")
        return await self._bounded("gripper move", finger_deadline_s(gripper.timeout_s, gripper.travel_m, speed_mps),
                                   lambda: gripper.move(width_m, speed_mps), actuating=True)

    async def gripper_grasp(
        self, width_m: float, force_n: float, speed_mps: float, epsilon_inner_m: float, epsilon_outer_m: float,
        *, stop_epoch: int | None = None,
    ) -> GripperResult:
        gripper = self._part(self.cell.gripper, "gripper")
        self._gripper_epoch = self._admit(stop_epoch, "gripper grasp")
        return await self._bounded(
            "gripper grasp", finger_deadline_s(gripper.timeout_s, gripper.travel_m, speed_mps),
            lambda: gripper.grasp(width_m, force_n, speed_mps, epsilon_inner_m, epsilon_outer_m), actuating=True,
        )

    async def gripper_home(self, *, stop_epoch: int | None = None) -> GripperResult:
        gripper = self._part(self.cell.gripper, "gripper")
        self._gripper_epoch = self._admit(stop_epoch, "gripper homing")
        return await self._bounded("gripper homing", gripper.home_timeout_s, gripper.home, actuating=True)

    # ---------------------------------------------------------------- cameras
    async def camera_snapshot(self, camera: str) -> CameraImage:
        offered = self.cell.cameras
        cameras = self._part(offered if offered is not None and camera in offered.names else None, f"camera {camera!r}")
        if cameras.setup_timeout_s > 0 and not cameras.set_up():  # a first frame may be far slower
            what, timeout_s = (f"camera {camera!r} snapshot (the first, which sets up rendering)",
                               cameras.timeout_s + cameras.setup_timeout_s)
        else:
            what, timeout_s = f"camera {camera!r} snapshot", cameras.timeout_s
        return await self._bounded(what, timeout_s, lambda: cameras.snapshot(camera))

    # ---------------------------------------------------------------- controllers and arm services
    async def list_controllers(self) -> list[ControllerInfo]:
        controllers = self._part(self.cell.controllers, "controllers")
        return await self._bounded("controller listing", controllers.timeout_s, controllers.list)

    async def switch_controllers(self, activate: Sequence[str], deactivate: Sequence[str], *,
                                 stop_epoch: int | None = None) -> None:
        controllers = self._part(self.cell.controllers, "controllers")
        self._admit(stop_epoch, "controller switch")
        await self._bounded("controller switch", controllers.timeout_s,
                            lambda: controllers.switch(tuple(activate), tuple(deactivate)), actuating=True)

    async def set_collision_thresholds(self, force_n: float, torque_nm: float, *, stop_epoch: int | None = None) -> None:
        thresholds = self._part(self.cell.collision_thresholds, "collision thresholds")
        self._admit(stop_epoch, "collision threshold change")
        await self._bounded("collision threshold change", thresholds.timeout_s,
                            lambda: thresholds.set(force_n, torque_nm), actuating=True)

    async def error_recovery(self, *, stop_epoch: int | None = None) -> None:
        recovery = self._part(self.cell.error_recovery, "error recovery")
        self._admit(stop_epoch, "error recovery")
        await self._bounded("error recovery", recovery.timeout_s, recovery.recover, actuating=True)
        self._arm_event(ArmEvent.RECOVER)

    async def graph(self) -> dict[str, list[str]]:
        graph = self._part(self.cell.graph, "graph")
        return await self._bounded("graph description", graph.timeout_s, graph.describe)

    async def lookup_transform(self, target_frame: str, source_frame: str) -> Transform:
        """Pose of `source_frame` in `target_frame` from the cell's frame tree; `BackendError` if
        a frame is unknown, disconnected or stale."""
        tree = self._part(self.cell.transforms, "transforms")
        return await self._bounded("transform lookup", tree.timeout_s, lambda: tree.lookup(target_frame, source_frame))


def finger_deadline_s(timeout_s: float, travel_m: float, speed_mps: float) -> float:
    """Deadline [s] of a gripper move/grasp at `speed_mps`: the full travel plus a fixed margin
    (an invalid speed gets the margin alone; the gripper refuses it)."""
    if not (isinstance(speed_mps, (int, float)) and math.isfinite(speed_mps) and speed_mps > 0):
        return timeout_s
    return timeout_s + travel_m / speed_mps
