"""A backend that counts every actuation command reaching the backend it wraps.

Evidence for "a refusal moves nothing": tests and `scripts/eval_safety.py` put it between the
Guard and the real backend and assert that refused requests added no command. It is a real
`Backend`: each public call is recorded (actuations by method name, stops by count) *before* it is
forwarded unchanged, so a command the inner backend refuses still counts as one that reached it.
Lifecycle, the cell (and so the capabilities), the arm state, `last_stop_stamp` and any other attribute are the inner backend's.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from typing import Any

from armwarden.backends.arm_state import ArmState
from armwarden.backends.base import Backend
from armwarden.backends.faults import FaultListener
from armwarden.backends.parts import Cell
from armwarden.backends.values import CameraImage, ControllerInfo, ExecutionResult, GripperResult, ProgressCallback
from armwarden.core.state import GripperState, JointState, Transform, Wrench
from armwarden.core.trajectory import JointTrajectory
from armwarden.tools import TOOLS

#: the Backend methods that can move or change the robot
ACTUATING_METHODS = tuple(spec.backend_call for spec in TOOLS if spec.backend_call is not None)


class CountingBackend(Backend):
    """Wraps `inner`: `actuations` lists every actuating call, `stops` counts `stop`/`stop_now` and the e-stops."""

    def __init__(self, inner: Backend) -> None:
        super().__init__(inner.joint_names, start_tolerance_rad=inner.start_tolerance_rad)
        self.inner = inner
        self.name = inner.name
        self.worker_threads = inner.worker_threads
        self.actuations: list[str] = []
        self.stops = 0
        #: of `stops`, how many were e-stops (`emergency_stop`/`emergency_stop_now`)
        self.emergency_stops = 0
        self._count_lock = threading.Lock()  # stop_now may come from another thread

    def __getattr__(self, name: str) -> Any:  # anything beyond the contract (e.g. fault injection)
        if name == "inner":  # not set yet (during construction)
            raise AttributeError(name)
        return getattr(self.inner, name)

    def _actuating(self, method: str) -> None:
        with self._count_lock:
            self.actuations.append(method)

    def _stopping(self, *, emergency: bool = False) -> None:
        with self._count_lock:
            self.stops += 1
            self.emergency_stops += emergency

    # ---------------------------------------------------------------- lifecycle and state
    @property
    def cell(self) -> Cell:
        return self.inner.cell

    @cell.setter
    def cell(self, cell: Cell) -> None:
        raise AttributeError("a counting backend's cell is the inner backend's")

    @property
    def arm_state(self) -> ArmState:
        return self.inner.arm_state

    @property
    def arm_state_since(self) -> float:
        return self.inner.arm_state_since

    @property
    def is_open(self) -> bool:
        return self.inner.is_open

    def _latest_stop_stamp(self) -> float | None:
        return self.inner.last_stop_stamp

    def set_fault_listener(self, listener: FaultListener | None) -> None:
        self.inner.set_fault_listener(listener)

    @property
    def worker_failure(self) -> str | None:
        return self.inner.worker_failure

    def inject_worker_failure(self, worker: str, error: BaseException) -> None:
        self.inner.inject_worker_failure(worker, error)

    def inject_worker_hang(self, worker: str, release: threading.Event) -> None:
        self.inner.inject_worker_hang(worker, release)

    def why_no_injected_death(self) -> str | None:
        return self.inner.why_no_injected_death()

    def inject_death(self) -> str:
        return self.inner.inject_death()

    async def fault_behind_stale_data(self) -> str | None:
        return await self.inner.fault_behind_stale_data()

    async def open(self) -> None:
        await self.inner.open()

    async def close(self) -> None:
        await self.inner.close()

    async def read_joint_state(self) -> JointState:
        return await self.inner.read_joint_state()

    async def read_joint_states_since(self, stamp: float | None) -> tuple[JointState, ...]:
        return await self.inner.read_joint_states_since(stamp)

    async def read_wrench(self) -> Wrench | None:
        return await self.inner.read_wrench()

    # ---------------------------------------------------------------- motion and stops
    async def execute(
        self, trajectory: JointTrajectory, progress: ProgressCallback | None = None, *, stop_epoch: int | None = None
    ) -> ExecutionResult:
        self._actuating("execute")
        return await self.inner.execute(trajectory, progress, stop_epoch=stop_epoch)

    @property
    def stop_epoch(self) -> int:
        return self.inner.stop_epoch

    async def stop(self) -> None:
        self._stopping()
        await self.inner.stop()

    def stop_now(self) -> None:
        self._stopping()
        self.inner.stop_now()

    async def emergency_stop(self) -> None:
        self._stopping(emergency=True)
        await self.inner.emergency_stop()

    def emergency_stop_now(self) -> None:
        self._stopping(emergency=True)
        self.inner.emergency_stop_now()

    # ---------------------------------------------------------------- optional capabilities
    async def gripper_state(self) -> GripperState | None:
        return await self.inner.gripper_state()

    async def gripper_move(self, width_m: float, speed_mps: float, *, stop_epoch: int | None = None) -> GripperResult:
        self._actuating("gripper_move")
        return await self.inner.gripper_move(width_m, speed_mps, stop_epoch=stop_epoch)

    async def gripper_grasp(
        self, width_m: float, force_n: float, speed_mps: float, epsilon_inner_m: float, epsilon_outer_m: float,
        *, stop_epoch: int | None = None,
    ) -> GripperResult:
        self._actuating("gripper_grasp")
        return await self.inner.gripper_grasp(width_m, force_n, speed_mps, epsilon_inner_m, epsilon_outer_m,
                                              stop_epoch=stop_epoch)

    async def gripper_home(self, *, stop_epoch: int | None = None) -> GripperResult:
        self._actuating("gripper_home")
        return await self.inner.gripper_home(stop_epoch=stop_epoch)

    async def camera_snapshot(self, camera: str) -> CameraImage:
        return await self.inner.camera_snapshot(camera)

    async def list_controllers(self) -> list[ControllerInfo]:
        return await self.inner.list_controllers()

    async def switch_controllers(self, activate: Sequence[str], deactivate: Sequence[str], *,
                                 stop_epoch: int | None = None) -> None:
        self._actuating("switch_controllers")
        await self.inner.switch_controllers(activate, deactivate, stop_epoch=stop_epoch)

    async def set_collision_thresholds(self, force_n: float, torque_nm: float, *, stop_epoch: int | None = None) -> None:
        self._actuating("set_collision_thresholds")
        await self.inner.set_collision_thresholds(force_n, torque_nm, stop_epoch=stop_epoch)

    async def error_recovery(self, *, stop_epoch: int | None = None) -> None:
        self._actuating("error_recovery")
        await self.inner.error_recovery(stop_epoch=stop_epoch)

    async def graph(self) -> dict[str, list[str]]:
        return await self.inner.graph()

    async def lookup_transform(self, target_frame: str, source_frame: str) -> Transform:
        return await self.inner.lookup_transform(target_frame, source_frame)

    # ---------------------------------------------------------------- hooks (the public calls above forward instead)
    async def _open(self) -> None:
        await self.inner.open()

    async def _close(self) -> None:
        await self.inner.close()

    async def _read_joint_state(self) -> JointState:
        return await self.inner.read_joint_state()

    async def _execute(self, trajectory: JointTrajectory, progress: ProgressCallback) -> ExecutionResult:
        return await self.inner.execute(trajectory, progress)

    async def _stop(self) -> None:
        await self.inner.stop()

    def _stop_now(self) -> None:
        self.inner.stop_now()

    async def _emergency_stop(self) -> None:
        await self.inner.emergency_stop()

    def _emergency_stop_now(self) -> None:
        self.inner.emergency_stop_now()


__all__ = ["ACTUATING_METHODS", "CountingBackend"]
