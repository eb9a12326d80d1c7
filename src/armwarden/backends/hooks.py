"""What a backend implements and declares: its accuracies and deadlines, and the `_hooks` that
`Backend`'s public methods call (template methods; see `armwarden.backends.base` for the rules).

Kept apart from `Backend` so a backend author reads one short class for what to write: the
abstract hooks (and `Backend.capabilities`) are required, the others belong to optional
capabilities (declare the capability in `capabilities`, then override its hooks).
"""

from __future__ import annotations

import abc

from armwarden.backends.values import (
    CameraImage,
    ControllerInfo,
    ExecutionResult,
    GripperResult,
    ProgressCallback,
)
from armwarden.core.state import GripperState, JointState, Transform, Wrench
from armwarden.core.trajectory import JointTrajectory


class BackendHooks(abc.ABC):
    """The accuracies and deadlines a backend declares, and the hooks it implements."""

    name: str = "abstract"
    #: how far from the goal a completed execution may end [rad] (see `armwarden.backends.base`, "Rules")
    goal_accuracy_rad: float = 0.0
    #: how far a resting arm may be from where it is held [rad]
    hold_accuracy_rad: float = 0.0
    #: joint speed [rad/s] at or below which the arm counts as at rest
    rest_speed_rad_s: float = 0.0
    #: deadline for a stop command to be issued [s]; a stop that misses it is a failure
    stop_timeout_s: float = 0.5
    #: deadline for state/wrench reads [s]
    read_timeout_s: float = 0.5
    #: deadline for a gripper state read [s]
    gripper_state_timeout_s: float = 0.5
    #: fixed part of a gripper move/grasp deadline [s]; the travel time at the requested speed is added
    gripper_timeout_s: float = 5.0
    #: the longest finger travel [m] a move or grasp may need (the gripper's full opening)
    gripper_travel_m: float = 0.1
    #: deadline for homing the gripper [s]
    gripper_home_timeout_s: float = 30.0
    #: deadline for a camera snapshot [s]
    camera_timeout_s: float = 2.0
    #: added to the deadline of a backend's first camera snapshot [s], for one-time setup (an
    #: offscreen renderer's GL context and first frame); see `_camera_deadline`
    camera_setup_timeout_s: float = 0.0
    #: deadline for listing or switching controllers [s]
    controllers_timeout_s: float = 5.0
    #: deadline for setting collision thresholds [s]
    thresholds_timeout_s: float = 2.0
    #: deadline for error recovery [s]
    error_recovery_timeout_s: float = 10.0
    #: deadline for describing the graph [s]
    graph_timeout_s: float = 2.0
    #: deadline for a transform lookup [s]
    transform_timeout_s: float = 0.5

    @abc.abstractmethod
    async def _open(self) -> None: ...

    @abc.abstractmethod
    async def _close(self) -> None: ...

    @abc.abstractmethod
    async def _read_joint_state(self) -> JointState: ...

    def _latest_joint_state(self) -> JointState | None:
        """The newest published sample, without waiting (may raise BackendError); None = ask
        `_read_joint_state` under the read deadline."""
        return None

    def _latest_wrench(self) -> Wrench | None:
        """Like `_latest_joint_state`, for the wrench estimate."""
        return None

    async def _read_wrench(self) -> Wrench | None:
        return None

    @abc.abstractmethod
    async def _execute(self, trajectory: JointTrajectory, progress: ProgressCallback) -> ExecutionResult: ...

    @abc.abstractmethod
    async def _stop(self) -> None: ...

    @abc.abstractmethod
    def _stop_now(self) -> None:
        """Synchronous, thread-safe stop (see `stop_now`); must not touch the event loop."""

    async def _emergency_stop(self) -> None:
        """The e-stop's stop (see `emergency_stop`); default: the ordinary stop."""
        await self._stop()

    def _emergency_stop_now(self) -> None:
        """Synchronous, thread-safe e-stop (see `emergency_stop_now`); default: `_stop_now`."""
        self._stop_now()

    def _stop_fingers(self) -> None:
        """Any thread (the event loop, a servo or watchdog thread, a stop from a signal), never
        awaiting the event loop: the fingers stop where they are and the gripper action in
        progress ends "stopped". The one name every backend's stop, e-stop and fault paths call
        for "stop the fingers"; default: no gripper, nothing to stop."""
        return None

    def _latest_gripper_state(self) -> GripperState | None:
        """Like `_latest_joint_state`, for the gripper: its published state, without waiting."""
        return None

    async def _gripper_state(self) -> GripperState | None:
        return None

    async def _gripper_move(self, width_m: float, speed_mps: float) -> GripperResult:
        raise NotImplementedError

    async def _gripper_grasp(
        self, width_m: float, force_n: float, speed_mps: float, epsilon_inner_m: float, epsilon_outer_m: float
    ) -> GripperResult:
        raise NotImplementedError

    async def _gripper_home(self) -> GripperResult:
        raise NotImplementedError

    async def _camera_snapshot(self, camera: str) -> CameraImage:
        raise NotImplementedError

    def _camera_set_up(self) -> bool:
        """Whether the one-time camera setup `camera_setup_timeout_s` allows for is done."""
        return True

    async def _list_controllers(self) -> list[ControllerInfo]:
        raise NotImplementedError

    async def _switch_controllers(self, activate: tuple[str, ...], deactivate: tuple[str, ...]) -> None:
        raise NotImplementedError

    async def _set_collision_thresholds(self, force_n: float, torque_nm: float) -> None:
        raise NotImplementedError

    async def _error_recovery(self) -> None:
        raise NotImplementedError

    async def _graph(self) -> dict[str, list[str]]:
        raise NotImplementedError

    async def _lookup_transform(self, target_frame: str, source_frame: str) -> Transform:
        raise NotImplementedError


__all__ = ["BackendHooks"]
