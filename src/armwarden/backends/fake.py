"""The fake backend: a kinematic FR3 + Franka Hand, deterministic, no dependency beyond the core.

The arm is kinematic: on its own daemon thread a control loop ticks every `control_period_s`
(≤ 1 ms) and sets the joint positions to `trajectory.sample(elapsed × speedup)`, the same linear
interpolation the envelope checked, so the final positions equal the goal exactly. Everything
that crosses from that thread into asyncio goes through `loop.call_soon_threadsafe`.

Stop semantics. A stop takes effect in the thread that issues it, before `_stop()` returns:
under the lock it ends the running (or just submitted) execution as "stopped" and republishes the
last commanded positions with zero velocity, so no later position is ever commanded. The control
thread computes each step outside the lock and publishes it under the lock only if no stop landed
meanwhile (a stop sequence number tells), so a stop racing a tick can never be overtaken by it. A
kinematic arm has no inertia: it is still from that instant, which `last_stop_stamp` records
(monotonic clock). Nothing therefore waits for the control thread to be scheduled, which under
load (the thread needs the interpreter lock) could take several milliseconds.

Contact. With `table_height_m` set, the estimated wrench is a force of `stiffness × penetration`
along +z, where penetration = max(0, table_height_m − tcp_z) and tcp_z comes from the thread's own
`RobotModel` (Pinocchio data is not thread safe, so the loop side never shares it). The wrench is
computed on the control thread and stamped with that tick's monotonic time.

The gripper is a width model driven on the event loop (no thread): it moves at the requested
speed (time-scaled) and `_stop()` halts it where it is. Cameras render a small top view with
Pillow when it is installed.

Fault injection for tests: `fail_stop` (stop raises and is not delivered), `freeze_wrench` (the
wrench stops updating, so its stamp stops advancing), `stall_wrench_s` (wrench reads take that
long), `fault` (the robot is in an error state until `error_recovery`), `object_width_m` (the
object between the fingers). All of them are plain attributes that can be changed at run time.
"""

from __future__ import annotations

import asyncio
import io
import logging
import math
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import anyio
import numpy as np

from armwarden.backends.base import (
    Backend,
    CameraImage,
    Capabilities,
    ControllerInfo,
    ExecutionResult,
    GripperResult,
    GripperState,
    JointState,
    ProgressCallback,
    Wrench,
)
from armwarden.errors import BackendError
from armwarden.planning.trajectory import JointTrajectory
from armwarden.robot.model import RobotModel

try:  # pillow is optional: without it the fake has no cameras
    from PIL import Image, ImageDraw

    HAVE_PILLOW = True
except ImportError:  # pragma: no cover - exercised only where pillow is missing
    HAVE_PILLOW = False

logger = logging.getLogger(__name__)

FR3_JOINT_NAMES = tuple(f"fr3_joint{i}" for i in range(1, 8))
FR3_READY = (0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2, math.pi / 4)

#: minimum interval between two progress callbacks [s] (≤ 50 Hz)
PROGRESS_PERIOD_S = 0.02
#: control-loop period while the arm is idle [s]; stops and executions wake it immediately
IDLE_PERIOD_S = 0.01
#: how long `_close` waits for the control thread to finish [s]
JOIN_TIMEOUT_S = 2.0
#: `open` fails if the control thread has not published its first state by then [s]
FIRST_TICK_TIMEOUT_S = 5.0
#: speed of the homing motion (fully open) [m/s]
GRIPPER_HOMING_SPEED_MPS = 0.1
#: the controller that executes trajectories; arm motion is refused while it is inactive
TRAJECTORY_CONTROLLER = "fr3_arm_controller"
#: camera image size [px]
CAMERA_WIDTH_PX, CAMERA_HEIGHT_PX = 320, 240

DEFAULT_CONTROLLERS = (
    ControllerInfo("fr3_arm_controller", "joint_trajectory_controller/JointTrajectoryController", "active"),
    ControllerInfo("joint_impedance_controller", "franka_example_controllers/JointImpedanceExampleController", "inactive"),
    ControllerInfo("franka_robot_state_broadcaster", "franka_robot_state_broadcaster/FrankaRobotStateBroadcaster", "active"),
)
#: controllers that command the arm joints; at most one of them may be active (ros2_control claims)
ARM_COMMAND_CONTROLLER_TYPES = ("joint_trajectory_controller/", "franka_example_controllers/")


@dataclass(eq=False)
class _Execution:
    """One trajectory handed to the control thread, and how the thread reports back."""

    trajectory: JointTrajectory
    loop: asyncio.AbstractEventLoop
    future: asyncio.Future
    start_time: float | None = None  # perf_counter of the tick that started it
    fraction: float = 0.0  # progress in [0, 1], written by the thread


@dataclass(eq=False)
class _GripperMotion:
    """A gripper motion in progress: the width is a function of time until it ends or is halted."""

    start_width_m: float
    target_width_m: float
    speed_mps: float  # already time-scaled
    start_time: float
    halted: anyio.Event = field(default_factory=anyio.Event)

    @property
    def duration_s(self) -> float:
        return abs(self.target_width_m - self.start_width_m) / self.speed_mps

    def width_at(self, now: float) -> float:
        travel = min(abs(self.target_width_m - self.start_width_m), self.speed_mps * max(0.0, now - self.start_time))
        return self.start_width_m + math.copysign(travel, self.target_width_m - self.start_width_m)


def _resolve(future: asyncio.Future, result: Any = None, error: BaseException | None = None) -> None:
    """Complete `future` unless its awaiter already gave up on it (runs on the event loop)."""
    if future.done():
        return
    if error is not None:
        future.set_exception(error)
    else:
        future.set_result(result)


def _post(loop: asyncio.AbstractEventLoop, future: asyncio.Future, result: Any = None, error: BaseException | None = None) -> None:
    """From any thread: complete `future` on its loop (ignored if that loop is gone)."""
    try:
        loop.call_soon_threadsafe(_resolve, future, result, error)
    except RuntimeError:  # the loop was closed: nobody is waiting any more
        pass


def _segment_velocity(trajectory: JointTrajectory, t: float) -> np.ndarray:
    """Joint velocity [rad/s] of the linear segment the trajectory is on at time `t`."""
    times = trajectory.times
    if t <= 0.0 or t >= times[-1] or len(times) < 2:
        return np.zeros(trajectory.positions.shape[1])
    k = int(np.searchsorted(times, t, side="right")) - 1
    span = times[k + 1] - times[k]
    if span <= 0:
        return np.zeros(trajectory.positions.shape[1])
    return (trajectory.positions[k + 1] - trajectory.positions[k]) / span


class FakeBackend(Backend):
    """Kinematic FR3 + Franka Hand with a real-time control thread (see the module docstring)."""

    name = "fake"

    def __init__(
        self,
        *,
        robot: RobotModel | None = None,
        description: str = "builtin:fr3",
        joint_names: Sequence[str] | None = None,
        base_frame: str | None = None,
        tcp_frame: str | None = None,
        home: Sequence[float] | None = None,
        speedup: float = 1.0,
        control_period_s: float = 0.001,
        table_height_m: float | None = None,
        table_stiffness_n_per_m: float = 20000.0,
        cameras: Sequence[str] = ("wrist", "scene"),
        controllers: Sequence[ControllerInfo | tuple[str, str, str]] | None = None,
        gripper_max_width_m: float = 0.08,
        wrench: bool = True,
        fail_stop: bool = False,
        freeze_wrench: bool = False,
        stall_wrench_s: float = 0.0,
        start_tolerance_rad: float = 0.05,
    ) -> None:
        joint_names = tuple(joint_names if joint_names is not None else (robot.joint_names if robot else FR3_JOINT_NAMES))
        super().__init__(joint_names)
        base_frame = base_frame or (robot.base_frame if robot else "fr3_link0")
        tcp_frame = tcp_frame or (robot.tcp_frame if robot else "fr3_hand_tcp")
        _require(math.isfinite(speedup) and speedup > 0, f"speedup must be a positive number, got {speedup}")
        _require(
            math.isfinite(control_period_s) and 0 < control_period_s <= 0.001,
            f"control_period_s must be in (0, 0.001] s, got {control_period_s}",
        )
        _require(table_height_m is None or math.isfinite(table_height_m), f"table_height_m must be finite, got {table_height_m}")
        _require(
            math.isfinite(table_stiffness_n_per_m) and table_stiffness_n_per_m > 0,
            f"table_stiffness_n_per_m must be positive, got {table_stiffness_n_per_m}",
        )
        _require(
            math.isfinite(gripper_max_width_m) and gripper_max_width_m > 0,
            f"gripper_max_width_m must be positive, got {gripper_max_width_m}",
        )
        _require(math.isfinite(stall_wrench_s) and stall_wrench_s >= 0, f"stall_wrench_s must be ≥ 0, got {stall_wrench_s}")
        _require(start_tolerance_rad >= 0, f"start_tolerance_rad must be ≥ 0, got {start_tolerance_rad}")

        # The thread's own kinematics (Pinocchio data is not thread safe); `robot` stays on the loop side.
        self._model = RobotModel.from_description(description, joint_names, base_frame, tcp_frame)
        self.robot = robot
        q_home = np.array(FR3_READY if home is None else home, dtype=float)
        _require(q_home.shape == (len(joint_names),), f"home needs {len(joint_names)} positions, got {q_home.shape}")
        _require(bool(np.all(np.isfinite(q_home))), f"home must be finite, got {q_home.tolist()}")
        _require(
            self._model.within_limits(q_home),
            f"home {q_home.tolist()} is outside the joint limits {self._model.lower.tolist()} .. {self._model.upper.tolist()}",
        )

        self.speedup = float(speedup)
        self.control_period_s = float(control_period_s)
        self.table_height_m = table_height_m
        self.table_stiffness_n_per_m = float(table_stiffness_n_per_m)
        self.gripper_max_width_m = float(gripper_max_width_m)
        self.start_tolerance_rad = float(start_tolerance_rad)
        self.fail_stop = fail_stop
        self.freeze_wrench = freeze_wrench
        self.stall_wrench_s = stall_wrench_s
        #: the robot is in an error state (reflex); arm motion is refused until `error_recovery`
        self.fault = False
        self.fault_reason = ""
        #: width of the object between the fingers [m]; None = exactly what the grasp asks for
        self.object_width_m: float | None = None
        #: every call that could move something (refused or not) increments this
        self.actuation_commands = 0
        #: monotonic time the latest stop's hold was published [s]
        self.last_stop_stamp: float | None = None
        #: control ticks run so far (the thread's heartbeat)
        self.tick_count = 0
        self.collision_thresholds: tuple[float, float] | None = None
        self.last_grasp_force_n: float | None = None

        frames = robot.frame_names() if robot is not None else self._model.frame_names()
        self._capabilities = Capabilities(
            wrench=bool(wrench),
            gripper=True,
            cameras=tuple(cameras) if HAVE_PILLOW else (),
            controllers=True,
            collision_thresholds=True,
            error_recovery=True,
            graph=True,
            frames=tuple(frames),
        )
        self._controllers = {
            c.name: c for c in (ControllerInfo(*c) if isinstance(c, tuple) else c for c in (controllers or DEFAULT_CONTROLLERS))
        }
        self._camera_frames = dict.fromkeys(self._capabilities.cameras, 0)

        # ---- shared with the control thread. Published snapshots are whole tuples, replaced by a
        # single assignment, so reads need no lock; the handoff (pending, stop requests) uses the lock.
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._shutdown = False
        self._pending: _Execution | None = None
        self._active: _Execution | None = None  # the running execution (changed under the lock)
        self._stop_seq = 0  # bumped by every stop: a tick computed before it is not published
        self._refusing_executions: str | None = None  # set once the control thread is gone (why)
        self._thread_error: BaseException | None = None
        now = time.monotonic()
        self._still = _frozen(np.zeros(len(joint_names)))
        q_start = _frozen(q_home)
        self._tcp_q = None
        self._tcp_position = self._compute_tcp(q_start)
        #: (commanded positions, velocities, stamp, TCP position): published arrays are read-only
        self._state = (q_start, self._still, now, self._tcp_position)
        self._wrench = (self._contact_force_n(self._tcp_position), now)
        self.control_thread: threading.Thread | None = None

        # ---- gripper (event loop only)
        self._gripper_width_m = self.gripper_max_width_m
        self._gripper_grasped = False
        self._gripper_motion: _GripperMotion | None = None

    # ================================================================ lifecycle
    @property
    def capabilities(self) -> Capabilities:
        return self._capabilities

    async def _open(self) -> None:
        """Start the control thread and return once it has published a state of its own (until
        then the only sample is the one taken at construction, which may already be stale)."""
        self.control_thread = threading.Thread(target=self._run, name="armwarden-fake-control", daemon=True)
        self.control_thread.start()
        deadline = time.monotonic() + FIRST_TICK_TIMEOUT_S
        while self.tick_count == 0:
            self._require_running()
            if time.monotonic() > deadline:
                raise BackendError(f"fake backend: the control thread did not tick within {FIRST_TICK_TIMEOUT_S} s")
            await asyncio.sleep(0.0005)

    async def _close(self) -> None:
        self._shutdown = True
        self._wake.set()
        thread = self.control_thread
        if thread is not None and thread.is_alive():
            await anyio.to_thread.run_sync(thread.join, JOIN_TIMEOUT_S)
            if thread.is_alive():
                logger.error("fake backend: control thread did not stop within %.1f s", JOIN_TIMEOUT_S)
        # whoever still waits is told the backend is gone (normally nobody: close stopped everything)
        self._fail_executions(BackendError("fake backend closed"))

    def _require_running(self) -> None:
        thread = self.control_thread
        if self._thread_error is not None:
            raise BackendError(f"fake backend control thread failed: {self._thread_error!r}")
        if thread is None or not thread.is_alive():
            raise BackendError("fake backend control thread is not running")

    # ================================================================ state
    def _latest_joint_state(self) -> JointState:
        self._require_running()
        q, dq, stamp, _tcp = self._state  # read-only arrays, replaced whole by each tick
        return JointState(self.joint_names, q, dq, stamp)

    async def _read_joint_state(self) -> JointState:
        return self._latest_joint_state()

    def _latest_wrench(self) -> Wrench | None:
        if self.stall_wrench_s > 0:
            return None  # a stalled sensor: take the slow path below, under the read deadline
        return self._wrench_sample()

    async def _read_wrench(self) -> Wrench | None:
        if self.stall_wrench_s > 0:
            await anyio.sleep(self.stall_wrench_s)
        return self._wrench_sample()

    def _wrench_sample(self) -> Wrench:
        self._require_running()
        force_z, stamp = self._wrench
        return Wrench(np.array([0.0, 0.0, force_z]), _ZERO3, stamp)

    # ================================================================ motion
    async def _execute(self, trajectory: JointTrajectory, progress: ProgressCallback) -> ExecutionResult:
        self.actuation_commands += 1
        self._require_running()
        if self.fault:
            raise BackendError(f"robot is in an error state ({self.fault_reason or 'fault'}); error recovery is needed")
        arm_controller = self._controllers.get(TRAJECTORY_CONTROLLER)
        if arm_controller is not None and arm_controller.state != "active":
            raise BackendError(f"{TRAJECTORY_CONTROLLER} is not active; the arm cannot follow a trajectory")
        self._check_trajectory(trajectory)

        loop = asyncio.get_running_loop()
        execution = _Execution(trajectory, loop, loop.create_future())
        with self._lock:
            if self._refusing_executions is not None:  # the thread died after the check above
                raise BackendError(f"fake backend: {self._refusing_executions}")
            if self._pending is not None or self._active is not None:
                raise BackendError("fake backend is already executing a trajectory; one execution at a time")
            self._pending = execution
        self._wake.set()

        reported = -1.0
        try:
            while True:
                done, _ = await asyncio.wait((execution.future,), timeout=PROGRESS_PERIOD_S)
                if done:
                    break
                self._require_running()  # never wait on a thread that is gone
                if execution.fraction != reported:
                    reported = execution.fraction
                    progress(reported)
            result: ExecutionResult = execution.future.result()
            if result.completed and reported != 1.0:
                progress(1.0)
            return result
        except BaseException:
            # cancelled (or the progress callback raised): hold the arm now, even before the base
            # class's stop() runs, and do not leave the future dangling (unless the injected fault
            # says stops are lost: then the arm keeps going, as a real one would)
            if not self.fail_stop:
                self._hold()
            execution.future.cancel()
            raise

    def _check_trajectory(self, trajectory: JointTrajectory) -> None:
        times, positions = trajectory.times, trajectory.positions
        n = len(self.joint_names)
        if times.ndim != 1 or len(times) == 0 or positions.shape != (len(times), n):
            raise BackendError(f"malformed trajectory: times {times.shape}, positions {positions.shape}, {n} joints")
        if not (np.all(np.isfinite(times)) and np.all(np.isfinite(positions))):
            raise BackendError("malformed trajectory: non-finite time or position")
        if times[0] != 0.0 or np.any(np.diff(times) < 0):
            raise BackendError("malformed trajectory: times must start at 0 and never decrease")
        q_now = self._state[0]
        deviation = np.abs(trajectory.start - q_now)
        worst = int(np.argmax(deviation))
        if deviation[worst] > self.start_tolerance_rad:
            raise BackendError(
                f"trajectory starts {deviation[worst]:.4f} rad away from the arm on {self.joint_names[worst]} "
                f"(start {trajectory.start[worst]:.4f}, measured {q_now[worst]:.4f}, tolerance {self.start_tolerance_rad} rad)"
            )

    async def _stop(self) -> None:
        if self.fail_stop:  # neither the arm nor the gripper hears this stop
            raise BackendError("injected fault: the stop command was not delivered (fail_stop=True)")
        self._hold()
        self._halt_gripper()
        self._require_running()  # held either way; a dead control thread is still reported as a failure

    def _hold(self) -> None:
        """Stop commanding motion, now, from the calling thread (see the module docstring)."""
        with self._lock:
            self._stop_seq += 1
            stopped = [e for e in (self._active, self._pending) if e is not None]
            self._active = self._pending = None
            q, _dq, _stamp, tcp = self._state
            stamp = time.monotonic()
            self._state = (q, self._still, stamp, tcp)
            self.last_stop_stamp = stamp
        for execution in stopped:
            _post(execution.loop, execution.future, ExecutionResult(False, "stopped", q.copy()))
        self._wake.set()  # the idle period starts now

    # ================================================================ the control thread
    def _run(self) -> None:
        period = self.control_period_s
        next_tick = time.perf_counter()
        try:
            while not self._shutdown:
                self._tick()
                # while nothing moves, tick slowly: a stop or a new execution wakes the loop at once,
                # and the idle loop then takes the interpreter lock from planning 10× less often
                busy = self._active is not None or self._pending is not None
                next_tick += period if busy else max(period, IDLE_PERIOD_S)
                delay = next_tick - time.perf_counter()
                if delay < -10 * period:  # fell far behind (machine stalled): resynchronise
                    next_tick = time.perf_counter()
                elif delay > 0 and self._wake.wait(delay):
                    self._wake.clear()  # woken early by a stop or a new execution: tick now
                    next_tick = time.perf_counter()
        except BaseException as exc:  # a dead control loop must never look like a healthy one
            logger.exception("fake backend: control thread failed")
            self._thread_error = exc
            self.fault, self.fault_reason = True, f"control thread failed: {exc!r}"
        finally:
            self._fail_executions(BackendError("fake backend control thread stopped"))

    def _tick(self) -> None:
        with self._lock:
            if self._active is None and self._pending is not None:
                self._active, self._pending = self._pending, None
            execution = self._active
            stop_seq = self._stop_seq
        now = time.perf_counter()
        stamp = time.monotonic()
        self.tick_count += 1

        q, dq, completed = self._state[0], self._still, False  # held where the last tick (or hold) left it
        if execution is not None:
            if execution.start_time is None:
                execution.start_time = now
            trajectory = execution.trajectory
            t = (now - execution.start_time) * self.speedup
            duration = trajectory.duration_s
            if t >= duration:
                q, completed = _frozen(trajectory.goal), True
            else:
                q, dq = _frozen(trajectory.sample(t)), _frozen(_segment_velocity(trajectory, t))
        tcp = self._compute_tcp(q)
        force_n = self._contact_force_n(tcp)

        with self._lock:
            if self._stop_seq != stop_seq:
                return  # a stop landed while this step was computed: it already published the hold
            self._state = (q, dq, stamp, tcp)
            if not self.freeze_wrench:  # a frozen sensor repeats its last sample, stamp included
                self._wrench = (force_n, stamp)
            if execution is not None:
                execution.fraction = 1.0 if completed else t / duration
                if completed:
                    self._active = None
        if completed:
            _post(execution.loop, execution.future, ExecutionResult(True, "completed", q.copy()))

    def _compute_tcp(self, q: np.ndarray) -> np.ndarray:
        """TCP position in the base frame; forward kinematics only when q changed (thread side)."""
        if self._tcp_q is None or not np.array_equal(q, self._tcp_q):
            self._tcp_q = q.copy()
            self._tcp_position = self._model.tcp_pose(q).position
        return self._tcp_position

    def _contact_force_n(self, tcp_position: np.ndarray) -> float:
        if self.table_height_m is None:
            return 0.0
        penetration_m = max(0.0, self.table_height_m - float(tcp_position[2]))
        return self.table_stiffness_n_per_m * penetration_m

    def _fail_executions(self, error: BackendError) -> None:
        """Fail every submitted execution and refuse later ones (the control thread is gone)."""
        with self._lock:
            self._refusing_executions = str(error)
            pending = [e for e in (self._pending, self._active) if e is not None]
            self._pending = self._active = None
        for execution in pending:
            _post(execution.loop, execution.future, error=error)

    # ================================================================ gripper (event loop side)
    async def _gripper_state(self) -> GripperState:
        motion = self._gripper_motion
        width = motion.width_at(time.perf_counter()) if motion is not None else self._gripper_width_m
        return GripperState(width, self._gripper_grasped, motion is not None, time.monotonic())

    async def _gripper_move(self, width_m: float, speed_mps: float) -> GripperResult:
        self.actuation_commands += 1
        self._check_gripper_args(width_m, speed_mps)
        width, stopped = await self._run_gripper(width_m, speed_mps)
        if stopped:
            return GripperResult(False, width, False, "stopped")
        return GripperResult(True, width, False, "")

    async def _gripper_grasp(
        self, width_m: float, force_n: float, speed_mps: float, epsilon_inner_m: float, epsilon_outer_m: float
    ) -> GripperResult:
        self.actuation_commands += 1
        self._check_gripper_args(width_m, speed_mps)
        for name, value in (("force_n", force_n), ("epsilon_inner_m", epsilon_inner_m), ("epsilon_outer_m", epsilon_outer_m)):
            if not (math.isfinite(value) and value >= 0):
                raise BackendError(f"gripper grasp: {name} must be finite and ≥ 0, got {value}")
        self.last_grasp_force_n = float(force_n)
        object_width = width_m if self.object_width_m is None else float(self.object_width_m)
        # the fingers close until they touch the object, or fully if it is not between them
        target = object_width if 0.0 <= object_width <= self._gripper_width_m else 0.0
        width, stopped = await self._run_gripper(target, speed_mps)
        if stopped:
            return GripperResult(False, width, False, "stopped")
        grasped = width_m - epsilon_inner_m <= width <= width_m + epsilon_outer_m
        self._gripper_grasped = grasped
        detail = "" if grasped else f"final width {width:.4f} m outside [{width_m - epsilon_inner_m:.4f}, {width_m + epsilon_outer_m:.4f}] m"
        return GripperResult(grasped, width, grasped, detail)

    async def _gripper_home(self) -> GripperResult:
        self.actuation_commands += 1
        width, stopped = await self._run_gripper(self.gripper_max_width_m, GRIPPER_HOMING_SPEED_MPS)
        if stopped:
            return GripperResult(False, width, False, "stopped")
        return GripperResult(True, width, False, "")

    def _check_gripper_args(self, width_m: float, speed_mps: float) -> None:
        if not (math.isfinite(width_m) and 0.0 <= width_m <= self.gripper_max_width_m):
            raise BackendError(f"gripper width {width_m} m outside [0, {self.gripper_max_width_m}] m")
        if not (math.isfinite(speed_mps) and speed_mps > 0):
            raise BackendError(f"gripper speed must be finite and > 0, got {speed_mps} m/s")

    async def _run_gripper(self, target_m: float, speed_mps: float) -> tuple[float, bool]:
        """Move the fingers to `target_m`; returns (final width, whether a stop interrupted it)."""
        if self._gripper_motion is not None:
            raise BackendError("the gripper is already moving; one gripper action at a time")
        self._gripper_grasped = False  # any motion releases what was held
        motion = _GripperMotion(self._gripper_width_m, target_m, speed_mps * self.speedup, time.perf_counter())
        self._gripper_motion = motion
        finished = False
        try:
            with anyio.move_on_after(motion.duration_s):
                await motion.halted.wait()
            finished = True
        finally:
            if self._gripper_motion is motion:  # not halted by _stop: it arrived, or our caller was cancelled
                self._gripper_motion = None
                self._gripper_width_m = target_m if finished else motion.width_at(time.perf_counter())
        # a stop that lands after the fingers arrived (before this task resumed) did not interrupt it
        interrupted = motion.halted.is_set() and not math.isclose(self._gripper_width_m, target_m, abs_tol=1e-9)
        return self._gripper_width_m, interrupted

    def _halt_gripper(self) -> None:
        motion = self._gripper_motion
        if motion is not None:
            self._gripper_width_m = motion.width_at(time.perf_counter())
            self._gripper_motion = None
            motion.halted.set()

    # ================================================================ cameras
    async def _camera_snapshot(self, camera: str) -> CameraImage:
        self._camera_frames[camera] += 1
        frame = self._camera_frames[camera]
        _q, _dq, stamp, tcp = self._state
        width = self._gripper_width_m if self._gripper_motion is None else self._gripper_motion.width_at(time.perf_counter())
        force_z = self._wrench[0]
        png = await anyio.to_thread.run_sync(_render_top_view, camera, frame, tcp.copy(), width, force_z, self.table_height_m)
        return CameraImage(camera, CAMERA_WIDTH_PX, CAMERA_HEIGHT_PX, png, stamp)

    # ================================================================ controllers, thresholds, recovery, graph
    async def _list_controllers(self) -> list[ControllerInfo]:
        return list(self._controllers.values())

    async def _switch_controllers(self, activate: tuple[str, ...], deactivate: tuple[str, ...]) -> None:
        self.actuation_commands += 1
        unknown = [name for name in (*activate, *deactivate) if name not in self._controllers]
        if unknown:
            raise BackendError(f"unknown controller(s) {unknown}; available: {sorted(self._controllers)}")
        both = sorted(set(activate) & set(deactivate))
        if both:
            raise BackendError(f"controller(s) {both} both activated and deactivated")
        if (activate or deactivate) and (self._pending is not None or self._active is not None):
            raise BackendError("cannot switch controllers while a trajectory is executing")
        states = {name: info.state for name, info in self._controllers.items()}
        states.update(dict.fromkeys(deactivate, "inactive"))
        states.update(dict.fromkeys(activate, "active"))
        commanding = [
            name
            for name, state in states.items()
            if state == "active" and self._controllers[name].type.startswith(ARM_COMMAND_CONTROLLER_TYPES)
        ]
        if len(commanding) > 1:
            raise BackendError(f"controllers {commanding} would both claim the arm's command interfaces")
        self._controllers = {name: ControllerInfo(name, info.type, states[name]) for name, info in self._controllers.items()}

    async def _set_collision_thresholds(self, force_n: float, torque_nm: float) -> None:
        self.actuation_commands += 1
        if not (math.isfinite(force_n) and force_n > 0 and math.isfinite(torque_nm) and torque_nm > 0):
            raise BackendError(f"collision thresholds must be finite and > 0, got {force_n} N, {torque_nm} N·m")
        self.collision_thresholds = (float(force_n), float(torque_nm))

    async def _error_recovery(self) -> None:
        self.actuation_commands += 1
        self._require_running()
        self.fault = False
        self.fault_reason = ""

    async def _graph(self) -> dict[str, list[str]]:
        topics = ["/joint_states", "/robot_description", "/tf", "/tf_static", "/franka_gripper/joint_states"]
        if self._capabilities.wrench:
            topics.append("/franka_robot_state_broadcaster/external_wrench_in_base_frame")
        topics += [f"/cameras/{name}/image_raw" for name in self._capabilities.cameras]
        return {
            "nodes": ["/armwarden_fake", "/controller_manager", "/franka_gripper", "/robot_state_publisher"]
            + [f"/{name}" for name in self._controllers],
            "topics": sorted(topics),
            "services": [
                "/controller_manager/list_controllers",
                "/controller_manager/switch_controller",
                "/service_server/set_full_collision_behavior",
            ],
            "actions": [
                "/action_server/error_recovery",
                "/fr3_arm_controller/follow_joint_trajectory",
                "/franka_gripper/grasp",
                "/franka_gripper/homing",
                "/franka_gripper/move",
            ],
        }


def _frozen(array: np.ndarray) -> np.ndarray:
    out = np.array(array, dtype=float)
    out.setflags(write=False)
    return out


_ZERO3 = _frozen(np.zeros(3))


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise ValueError(message)


def _render_top_view(
    camera: str, frame: int, tcp: np.ndarray, gripper_width_m: float, force_z_n: float, table_height_m: float | None
) -> bytes:
    """A deterministic top view (x up, y left): the table and workspace, the base and the TCP dot.

    "scene" shows the whole workspace at 200 px/m; any other camera ("wrist") is centred on the
    TCP at 800 px/m and also draws the fingers at the current opening.
    """
    if camera == "scene":
        centre_x, centre_y, scale = 0.4, 0.0, 200.0
    else:
        centre_x, centre_y, scale = float(tcp[0]), float(tcp[1]), 800.0

    def to_px(x: float, y: float) -> tuple[float, float]:
        return (CAMERA_WIDTH_PX / 2 - (y - centre_y) * scale, CAMERA_HEIGHT_PX / 2 - (x - centre_x) * scale)

    image = Image.new("RGB", (CAMERA_WIDTH_PX, CAMERA_HEIGHT_PX), (200, 170, 130) if table_height_m is not None else (90, 90, 90))
    draw = ImageDraw.Draw(image)
    grid_m = 0.1 if camera == "scene" else 0.05
    half_w, half_h = CAMERA_WIDTH_PX / 2 / scale, CAMERA_HEIGHT_PX / 2 / scale
    for k in range(math.floor((centre_y - half_w) / grid_m), math.ceil((centre_y + half_w) / grid_m) + 1):
        u, _ = to_px(0.0, k * grid_m)
        draw.line([(u, 0), (u, CAMERA_HEIGHT_PX)], fill=(150, 130, 100))
    for k in range(math.floor((centre_x - half_h) / grid_m), math.ceil((centre_x + half_h) / grid_m) + 1):
        _, v = to_px(k * grid_m, 0.0)
        draw.line([(0, v), (CAMERA_WIDTH_PX, v)], fill=(150, 130, 100))
    bu, bv = to_px(0.0, 0.0)
    base_r = 0.08 * scale
    draw.ellipse([bu - base_r, bv - base_r, bu + base_r, bv + base_r], fill=(230, 230, 230), outline=(40, 40, 40))
    tu, tv = to_px(float(tcp[0]), float(tcp[1]))
    if camera != "scene":  # the fingers, seen from above, across y
        for side in (-1, 1):
            fu = tu + side * (gripper_width_m / 2 + 0.005) * scale
            draw.rectangle([fu - 0.005 * scale, tv - 0.01 * scale, fu + 0.005 * scale, tv + 0.01 * scale], fill=(60, 60, 60))
    dot_r = 5
    colour = (220, 30, 30) if force_z_n > 0 else (30, 90, 220)
    draw.ellipse([tu - dot_r, tv - dot_r, tu + dot_r, tv + dot_r], fill=colour, outline=(0, 0, 0))
    draw.text((4, 4), f"{camera} #{frame}", fill=(0, 0, 0))
    draw.text((4, CAMERA_HEIGHT_PX - 14), f"tcp {tcp[0]:+.3f} {tcp[1]:+.3f} {tcp[2]:+.3f} m", fill=(0, 0, 0))
    buffer = io.BytesIO()
    image.save(buffer, format="PNG")
    return buffer.getvalue()


def create_backend(**kwargs: Any) -> FakeBackend:
    """Registry factory. `policy` and `config_path` are accepted for uniformity and unused here."""
    kwargs.pop("policy", None)
    kwargs.pop("config_path", None)
    return FakeBackend(**kwargs)


__all__ = ["FakeBackend", "create_backend"]
