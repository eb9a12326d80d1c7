"""What a backend implements and declares, and the rules it keeps: its accuracies and deadlines,
and the `_hooks` that `Backend`'s public methods call (template methods, as python-can's
`BusABC.recv` calls `_recv_internal`; `armwarden.backends.base` enforces what it can).

Kept apart from `Backend` so a backend author reads one short class for what to write: the
abstract hooks drive the arm; everything else a cell has is a part (`armwarden.backends.parts`:
gripper, cameras, wrench sensor, controllers, ...), built by the backend into `self.cell`.
`tests/backends/contract.py` (`BackendContract`) checks every rule below; a new backend
subclasses it with one fixture. See docs/backends/common.md and docs/add-a-backend.md.

Writing a backend
- Subclass `Backend`; call `super().__init__(joint_names, start_tolerance_rad=...)` with the
  policy's `motion.start_tolerance_rad`. Implement `_open`, `_close`, `_read_joint_state`,
  `_execute`, `_stop` and `_stop_now`. Build the parts your cell has (subclasses of the part base
  classes in `armwarden.backends.parts`, each with its own deadlines) and set
  `self.cell = Cell(gripper=..., cameras=..., ...)`; what is absent stays None, and a call to an
  absent part raises `BackendError`. The capabilities the server reads are derived from the cell.
  Every arm hook, accuracy and deadline is listed in `armwarden.backends.hooks.BackendHooks`; the
  values the hooks and parts return are in `armwarden.backends.values`.
- In the backend's module: a strict pydantic `Config` (extra="forbid", frozen, units in names and
  descriptions) and `create_backend(robot, policy, config: Config) -> Backend`; then register the
  module: a built-in one in `armwarden.backends.BACKENDS`, a third party's as an entry point in
  the group `armwarden.backends` of its own package.

Rules every backend follows
- `stop()` is fast, idempotent, safe at any time from the event loop (also during an execution,
  before `open` and after `close`: then it does nothing) and stops the arm *and* the gripper
  (the gripper through `_stop_fingers`, which calls the gripper part's `stop_now`: any thread).
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
  every sample answers `_latest_joint_state` (and its parts' `Gripper.state` / `WrenchSensor.latest`)
  from that snapshot without awaiting; the read deadline is then skipped.
- A fault the backend finds on its own thread (a physical arm's health watch) is handled there
  first — the arm stopped or damped, the stop epoch bumped — then reported to the listener set
  with `set_fault_listener` (the Guard latches its e-stop from any thread). A fault during an
  execution also makes `execute` raise `BackendError` naming it.
- The backend's own threads (a servo or physics loop, a ROS executor) are supervised as
  `armwarden.backends.workers` describes: a dead or hung one stops the arm, is reported once and
  refuses every later call but stop and close.
- Deadlines (seconds): reads `read_timeout_s` and stops `stop_timeout_s` (class attributes here),
  and each part its own (`timeout_s`; gripper motions get `Gripper.timeout_s` plus the time
  `Gripper.travel_m` takes at the requested speed; camera snapshots get `Cameras.setup_timeout_s`
  more until `Cameras.set_up` says a one-time setup, e.g. an offscreen renderer, is done). A
  missed deadline raises `BackendTimeout`; an actuating call that misses it is followed by a stop.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence

from armwarden.backends.values import ExecutionResult, ProgressCallback
from armwarden.core.state import JointState
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
    #: whether the backend reports the arm's motion events itself (`armwarden.backends.arm_state`:
    #: EXECUTE at the hand-over, FINISH, STOP, under the lock its stop takes, as a servo loop or an
    #: action client can); if not, `Backend` reports them around `_execute` and the stop hooks
    reports_motion_events: bool = False

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

    def _joint_states_since(self, stamp: float) -> Sequence[JointState] | None:
        """Every sample kept after `stamp`, oldest first, from a short history
        (`armwarden.backends.state_history`), or the newest kept one alone when none is newer
        (`JointStateHistory.since_or_latest`); None = this backend keeps none, and readers get the
        latest sample alone. A servo loop that publishes faster than the Guard polls keeps one:
        the contact observer integrates every sample (see `Backend.read_joint_states_since`)."""
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
