"""What a backend implements and declares, and the rules it keeps: its accuracies and deadlines,
and the `_hooks` that `Backend`'s public methods call (template methods, as python-can's
`BusABC.recv` calls `_recv_internal`; `armwarden.backends.base` enforces what it can).

Kept apart from `Backend` so a backend author reads one short class for what to write: the
abstract hooks (and `Backend.capabilities`) are required, the others belong to optional
capabilities (declare the capability in `capabilities`, then override its hooks).
`tests/backends/contract.py` (`BackendContract`) checks every rule below; a new backend
subclasses it with one fixture. See docs/backends/common.md and docs/add-a-backend.md.

Writing a backend
- Subclass `Backend`; call `super().__init__(joint_names, start_tolerance_rad=...)` with the
  policy's `motion.start_tolerance_rad`. Implement `capabilities`, `_open`, `_close`,
  `_read_joint_state`, `_execute`, `_stop` and `_stop_now`; implement the optional hooks
  (`_read_wrench`, `_gripper_*`, `_camera_snapshot`, `_list_controllers`, ...) only for the
  capabilities you declare. A call to a capability you do not declare raises `BackendError`.
  Every hook, accuracy and deadline is listed in `armwarden.backends.hooks.BackendHooks`; the
  values the hooks return are in `armwarden.backends.values`.
- In the backend's module: a strict pydantic `Config` (extra="forbid", frozen, units in names and
  descriptions) and `create_backend(robot, policy, config: Config) -> Backend`; then register the
  module: a built-in one in `armwarden.backends.BACKENDS`, a third party's as an entry point in
  the group `armwarden.backends` of its own package.

Rules every backend follows
- `stop()` is fast, idempotent, safe at any time from the event loop (also during an execution,
  before `open` and after `close`: then it does nothing) and stops the arm *and* the gripper
  (the gripper through `_stop_fingers`, callable from any thread).
- `stop_now()` is the same stop, synchronous and thread-safe: any thread may call it while the
  event loop is busy or blocked, and the arm is held before it returns (a servo loop commands a
  hold under its lock; see `armwarden.backends.servo`). It must not await the event loop.
- `emergency_stop()` / `emergency_stop_now()` are the e-stop's stop (the `estop` tool, the stop
  channel, SIGUSR1): the same guarantees as `stop()` / `stop_now()` (fast, idempotent, any time;
  the `_now` form synchronous and thread-safe from any thread, done before it returns), and they
  bump the stop epoch too. By default they are `stop()` / `stop_now()`; a physical arm that
  should go limp rather than stiff on an e-stop overrides `_emergency_stop` / `_emergency_stop_now`
  (the CAN backend damps every joint, kp = 0, kd > 0, until the next admitted execution after a
  reset).
- A stop is never overtaken by an actuation that was decided before it (trajectories, gripper
  actions, controller switches, threshold changes, error recovery all take `stop_epoch`). Every stop (`stop`,
  `stop_now`, any thread) first bumps `stop_epoch`; `execute(..., stop_epoch=E)` refuses to start
  ("stopped before it started", nothing moved) once the epoch is no longer E, and the `_execute`
  hook checks `_stop_landed()` again *under the same lock its stop takes* when it hands the
  trajectory over (the servo core does this for you). So either the trajectory was handed over
  first and the stop ends it, or the stop came first and the trajectory never starts.
- `execute()` runs exactly the trajectory it is given (same waypoints, same timing, not
  modified), ends at its goal (within `goal_accuracy_rad`), reports progress in [0, 1] never
  decreasing, returns when the arm has finished ("completed") or was stopped ("stopped"), and stops
  the arm if the awaiting task is cancelled. The base class refuses, before `_execute` runs, a
  malformed trajectory and one that does not start within `start_tolerance_rad` of the measured
  joint positions.
- Physical arms are never exactly where they were told to be. Each backend declares how close it
  gets, and the conformance suite holds it to that: `goal_accuracy_rad` (a completed execution's
  final positions from the goal), `hold_accuracy_rad` (where a stopped arm comes to rest from
  where the stop found it — its braking distance — and how still a resting arm stays) and
  `rest_speed_rad_s` (the joint speed below which the arm is at rest). A stopped execution
  reports in `final_positions` where the arm came to rest and is held. A kinematic backend
  declares zeros: it is exactly where it is commanded.
- State samples carry their stamp (monotonic clock [s]); stamps never go backwards and advance
  with new samples. Freshness is never assumed: the Guard refuses stale ones.
- Blocking work (hardware I/O, simulation stepping) lives on the backend's own thread; results
  cross into asyncio with `armwarden.handoff.settle_threadsafe`. A backend whose thread publishes
  every sample answers `_latest_joint_state` / `_latest_wrench` / `_latest_gripper_state` from that snapshot
  without awaiting; the read deadline is then skipped.
- A fault the backend finds on its own thread (a physical arm's health watch) is handled there
  first — the arm stopped or damped, the stop epoch bumped — then reported to the listener set
  with `set_fault_listener` (the Guard latches its e-stop from any thread). A fault during an
  execution also makes `execute` raise `BackendError` naming it.
- The backend's own threads (a servo or physics loop, a ROS executor) are supervised as
  `armwarden.backends.workers` describes: a dead or hung one stops the arm, is reported once and
  refuses every later call but stop and close.
- Deadlines (class attributes, seconds): reads `read_timeout_s`, stops `stop_timeout_s`, and one
  per optional capability (`*_timeout_s`; gripper motions get `gripper_timeout_s` plus the time
  `gripper_travel_m` takes at the requested speed; camera snapshots get `camera_setup_timeout_s`
  more until `_camera_set_up` says a one-time setup, e.g. an offscreen renderer, is done). A
  missed deadline raises `BackendTimeout`; an actuating call that misses it is followed by a stop.
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
    #: how far from the goal a completed execution may end [rad] (see "Rules every backend follows" above)
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
