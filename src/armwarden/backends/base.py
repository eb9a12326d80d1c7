"""The async backend contract every robot backend implements (fake, MuJoCo, ROS 2, CAN).

The base class owns what is common — the open/closed lifecycle, deadlines, logging, and the
stop semantics — and calls small `_hooks` that each backend implements (template methods, as
python-can's `BusABC.recv` calls `_recv_internal`). Backends only talk to hardware or
simulation: they never decide whether a motion is allowed. The Guard is the only caller.

Rules every backend follows:
- `stop()` is fast, idempotent, safe to call at any time from the event loop (also while an
  execution is in progress or nothing is open) and stops the arm *and* the gripper.
- `execute()` runs exactly the trajectory it is given (same waypoints, same timing), reports
  progress in [0, 1], returns when the arm has finished or stopped, and stops the arm if the
  awaiting task is cancelled.
- Blocking work (hardware I/O, simulation stepping) lives on the backend's own thread; results
  cross into asyncio with `loop.call_soon_threadsafe`.
- A backend whose thread publishes every new sample (a servo loop, a receive thread, a topic
  subscription) answers `_latest_joint_state` / `_latest_wrench` from that snapshot without
  awaiting anything; the template then skips the read deadline, which costs more than the read.
  Freshness is never assumed: every sample carries its stamp and the Guard refuses stale ones.
"""

from __future__ import annotations

import abc
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import anyio
import numpy as np

from armwarden.errors import BackendError, BackendTimeout
from armwarden.planning.trajectory import JointTrajectory

logger = logging.getLogger(__name__)

ProgressCallback = Callable[[float], None]


@dataclass(frozen=True)
class JointState:
    """Measured joint positions [rad] and velocities [rad/s]; `stamp` on the monotonic clock [s]."""

    names: tuple[str, ...]
    positions: np.ndarray
    velocities: np.ndarray
    stamp: float


@dataclass(frozen=True)
class Wrench:
    """Estimated external wrench at the TCP in the base frame: force [N], torque [N·m]."""

    force: np.ndarray
    torque: np.ndarray
    stamp: float

    @property
    def force_norm_n(self) -> float:
        return float(np.linalg.norm(self.force))

    @property
    def torque_norm_nm(self) -> float:
        return float(np.linalg.norm(self.torque))


@dataclass(frozen=True)
class GripperState:
    width_m: float
    is_grasped: bool
    moving: bool
    stamp: float


@dataclass(frozen=True)
class GripperResult:
    success: bool
    width_m: float
    is_grasped: bool
    detail: str = ""


@dataclass(frozen=True)
class CameraImage:
    camera: str
    width: int
    height: int
    png: bytes
    stamp: float


@dataclass(frozen=True)
class ControllerInfo:
    name: str
    type: str
    state: str  # "active" | "inactive"


@dataclass(frozen=True)
class ExecutionResult:
    """How an execution ended: `completed` (reached the goal) or stopped early, with why."""

    completed: bool
    reason: str
    final_positions: np.ndarray


@dataclass(frozen=True)
class Capabilities:
    """What the backend can do; the server registers only tools the backend supports."""

    wrench: bool = False
    gripper: bool = False
    cameras: tuple[str, ...] = ()
    controllers: bool = False
    collision_thresholds: bool = False
    error_recovery: bool = False
    graph: bool = False
    frames: tuple[str, ...] = field(default_factory=tuple)


class Backend(abc.ABC):
    """Base class: lifecycle, deadlines and logging; subclasses implement the `_hooks`."""

    name: str = "abstract"
    #: deadline for a stop command to be issued [s]; a stop that misses it is a failure
    stop_timeout_s: float = 0.5
    #: deadline for state/wrench reads [s]
    read_timeout_s: float = 0.5

    def __init__(self, joint_names: Sequence[str]) -> None:
        self.joint_names = tuple(joint_names)
        #: monotonic time [s] at which the latest stop took effect (no motion commanded after it),
        #: for backends that can tell (the fake, servo loops); None otherwise
        self.last_stop_stamp: float | None = None
        self._opened = False
        self._closed = False

    # ---------------------------------------------------------------- lifecycle
    @property
    def is_open(self) -> bool:
        return self._opened and not self._closed

    async def open(self) -> None:
        if self._opened:
            return
        await self._open()
        self._opened = True
        logger.info("backend %s opened", self.name)

    async def close(self) -> None:
        """Stop everything and release resources. Safe to call twice or before `open`."""
        if self._closed:
            return
        self._closed = True
        if self._opened:
            # shielded (close often runs in a cancelled task: SIGTERM, disconnect) and bounded (a
            # hung stop must not keep the backend from closing)
            try:
                with anyio.fail_after(self.stop_timeout_s, shield=True):
                    await self._stop()
            except Exception:  # closing must not fail because the stop did
                logger.exception("backend %s: stop during close failed", self.name)
            with anyio.CancelScope(shield=True):
                await self._close()
        logger.info("backend %s closed", self.name)

    def _require_open(self) -> None:
        if not self.is_open:
            raise BackendError(f"backend {self.name} is not open")

    @property
    @abc.abstractmethod
    def capabilities(self) -> Capabilities: ...

    # ---------------------------------------------------------------- state
    async def read_joint_state(self) -> JointState:
        self._require_open()
        published = self._latest_joint_state()
        if published is not None:
            return published
        with anyio.fail_after(self.read_timeout_s):
            return await self._read_joint_state()

    async def read_wrench(self) -> Wrench | None:
        """The latest wrench estimate, or None if this backend has none."""
        self._require_open()
        if not self.capabilities.wrench:
            return None
        published = self._latest_wrench()
        if published is not None:
            return published
        with anyio.fail_after(self.read_timeout_s):
            return await self._read_wrench()

    # ---------------------------------------------------------------- motion
    async def execute(self, trajectory: JointTrajectory, progress: ProgressCallback | None = None) -> ExecutionResult:
        """Run `trajectory` exactly. If the caller is cancelled, the arm is stopped first."""
        self._require_open()
        if trajectory.joint_names != self.joint_names:
            raise BackendError(f"trajectory joints {trajectory.joint_names} do not match backend joints {self.joint_names}")
        try:
            return await self._execute(trajectory, progress or (lambda _fraction: None))
        except BaseException:
            with anyio.CancelScope(shield=True):
                try:
                    await self.stop()
                except BackendError:  # keep the original exception: the caller stops again and latches
                    logger.exception("backend %s: stop after an interrupted execution failed", self.name)
            raise

    async def stop(self) -> None:
        """Stop arm and gripper now. Raises `BackendError` if the stop could not be issued."""
        if not self._opened or self._closed:
            return
        try:
            with anyio.fail_after(self.stop_timeout_s):
                await self._stop()
        except TimeoutError as exc:
            raise BackendTimeout(f"backend {self.name}: stop not confirmed within {self.stop_timeout_s} s") from exc
        except BackendError:
            raise
        except Exception as exc:
            raise BackendError(f"backend {self.name}: stop failed: {exc}") from exc

    # ---------------------------------------------------------------- optional capabilities
    async def gripper_state(self) -> GripperState | None:
        self._require_open()
        return await self._gripper_state() if self.capabilities.gripper else None

    async def gripper_move(self, width_m: float, speed_mps: float) -> GripperResult:
        self._require_capability(self.capabilities.gripper, "gripper")
        return await self._gripper_move(width_m, speed_mps)

    async def gripper_grasp(
        self, width_m: float, force_n: float, speed_mps: float, epsilon_inner_m: float, epsilon_outer_m: float
    ) -> GripperResult:
        self._require_capability(self.capabilities.gripper, "gripper")
        return await self._gripper_grasp(width_m, force_n, speed_mps, epsilon_inner_m, epsilon_outer_m)

    async def gripper_home(self) -> GripperResult:
        self._require_capability(self.capabilities.gripper, "gripper")
        return await self._gripper_home()

    async def camera_snapshot(self, camera: str) -> CameraImage:
        self._require_capability(camera in self.capabilities.cameras, f"camera {camera!r}")
        with anyio.fail_after(2.0):
            return await self._camera_snapshot(camera)

    async def list_controllers(self) -> list[ControllerInfo]:
        self._require_capability(self.capabilities.controllers, "controllers")
        return await self._list_controllers()

    async def switch_controllers(self, activate: Sequence[str], deactivate: Sequence[str]) -> None:
        self._require_capability(self.capabilities.controllers, "controllers")
        await self._switch_controllers(tuple(activate), tuple(deactivate))

    async def set_collision_thresholds(self, force_n: float, torque_nm: float) -> None:
        self._require_capability(self.capabilities.collision_thresholds, "collision thresholds")
        await self._set_collision_thresholds(force_n, torque_nm)

    async def error_recovery(self) -> None:
        self._require_capability(self.capabilities.error_recovery, "error recovery")
        await self._error_recovery()

    async def graph(self) -> dict[str, list[str]]:
        self._require_capability(self.capabilities.graph, "graph")
        return await self._graph()

    def _require_capability(self, present: bool, what: str) -> None:
        self._require_open()
        if not present:
            raise BackendError(f"backend {self.name} has no {what}")

    # ---------------------------------------------------------------- hooks
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
