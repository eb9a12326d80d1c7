"""Parts built from a backend's `_hooks`, for a backend that declares capability flags instead of
building its `Cell` (`armwarden.backends.parts`). Transitional: each built-in backend moves to
parts of its own, and this module goes with the last one."""

from __future__ import annotations

from armwarden.backends.hooks import BackendHooks
from armwarden.backends.parts import (
    Cameras,
    Capabilities,
    Cell,
    CollisionThresholds,
    Controllers,
    ErrorRecovery,
    FrameTree,
    Graph,
    Gripper,
    WrenchSensor,
)
from armwarden.backends.values import CameraImage, ControllerInfo, GripperResult
from armwarden.core.errors import BackendError
from armwarden.core.state import GripperState, Transform, Wrench


class _HookGripper(Gripper):
    def __init__(self, backend: BackendHooks) -> None:
        self._backend = backend
        self.timeout_s, self.travel_m = backend.gripper_timeout_s, backend.gripper_travel_m
        self.home_timeout_s = backend.gripper_home_timeout_s

    def state(self) -> GripperState:
        state = self._backend._latest_gripper_state()
        if state is None:
            raise BackendError(f"backend {self._backend.name} publishes no gripper state")
        return state

    async def move(self, width_m: float, speed_mps: float) -> GripperResult:
        return await self._backend._gripper_move(width_m, speed_mps)

    async def grasp(self, width_m: float, force_n: float, speed_mps: float, epsilon_inner_m: float,
                    epsilon_outer_m: float) -> GripperResult:
        return await self._backend._gripper_grasp(width_m, force_n, speed_mps, epsilon_inner_m, epsilon_outer_m)

    async def home(self) -> GripperResult:
        return await self._backend._gripper_home()

    def stop_now(self) -> None:
        type(self._backend)._stop_fingers(self._backend)


class _HookCameras(Cameras):
    def __init__(self, backend: BackendHooks, names: tuple[str, ...]) -> None:
        self._backend, self._names = backend, names
        self.timeout_s, self.setup_timeout_s = backend.camera_timeout_s, backend.camera_setup_timeout_s

    @property
    def names(self) -> tuple[str, ...]:
        return self._names

    def set_up(self) -> bool:
        return self._backend._camera_set_up()

    async def snapshot(self, camera: str) -> CameraImage:
        return await self._backend._camera_snapshot(camera)


class _HookWrench(WrenchSensor):
    def __init__(self, backend: BackendHooks) -> None:
        self._backend = backend

    def latest(self) -> Wrench | None:
        return self._backend._latest_wrench()

    async def read(self) -> Wrench | None:
        return await self._backend._read_wrench()


class _HookControllers(Controllers):
    def __init__(self, backend: BackendHooks) -> None:
        self._backend, self.timeout_s = backend, backend.controllers_timeout_s

    async def list(self) -> list[ControllerInfo]:
        return await self._backend._list_controllers()

    async def switch(self, activate: tuple[str, ...], deactivate: tuple[str, ...]) -> None:
        await self._backend._switch_controllers(activate, deactivate)


class _HookThresholds(CollisionThresholds):
    def __init__(self, backend: BackendHooks) -> None:
        self._backend, self.timeout_s = backend, backend.thresholds_timeout_s

    async def set(self, force_n: float, torque_nm: float) -> None:
        await self._backend._set_collision_thresholds(force_n, torque_nm)


class _HookRecovery(ErrorRecovery):
    def __init__(self, backend: BackendHooks) -> None:
        self._backend, self.timeout_s = backend, backend.error_recovery_timeout_s

    async def recover(self) -> None:
        await self._backend._error_recovery()


class _HookGraph(Graph):
    def __init__(self, backend: BackendHooks) -> None:
        self._backend, self.timeout_s = backend, backend.graph_timeout_s

    async def describe(self) -> dict[str, list[str]]:
        return await self._backend._graph()


class _HookFrames(FrameTree):
    def __init__(self, backend: BackendHooks) -> None:
        self._backend, self.timeout_s = backend, backend.transform_timeout_s

    async def lookup(self, target_frame: str, source_frame: str) -> Transform:
        return await self._backend._lookup_transform(target_frame, source_frame)


def cell_from_hooks(backend: BackendHooks, declared: Capabilities) -> Cell:
    """The cell a flag-declaring backend's `capabilities` describe, its parts calling its hooks."""
    return Cell(
        gripper=_HookGripper(backend) if declared.gripper else None,
        cameras=_HookCameras(backend, tuple(declared.cameras)) if declared.cameras else None,
        wrench=_HookWrench(backend) if declared.wrench else None,
        controllers=_HookControllers(backend) if declared.controllers else None,
        collision_thresholds=_HookThresholds(backend) if declared.collision_thresholds else None,
        error_recovery=_HookRecovery(backend) if declared.error_recovery else None,
        graph=_HookGraph(backend) if declared.graph else None,
        transforms=_HookFrames(backend) if declared.transforms else None,
        frames=tuple(declared.frames),
    )
