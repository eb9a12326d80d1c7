"""The MuJoCo backend: the FR3 cell simulated with real physics behind the backend contract.

The backend composes its parts: the arm (`SimulatedArm`, mujoco/arm.py) is the physics the servo
thread (`armwarden.backends.servo.ServoLoop`) steps each tick, tracking the trajectory sample and
braking on a stop; the fingers (`SimulatedFingers`, mujoco/gripper.py); the cameras
(`OffscreenCameras`, mujoco/cameras.py). This module keeps what joins them: the lifecycle, the
servo hooks, and when an execution has settled.

What is published is what the simulation measures, never what was commanded: joint positions and
velocities (`qpos`/`qvel`), joint torques and the external wrench, stamped (monotonic clock) with
the wall time at which the simulated state held. Every tick's joint state is also kept for a
moment (`joint_history`), so the contact observer integrates each one. A stop brakes the arm
(mujoco/arm.py) and never pulls it back to where it was last told to be, nor to where the stop
found it; a stopped execution reports where the arm came to rest.

Wrench: the flange force/torque sensor measures what the hand's subtree exerts on the arm. At
rest that is the hand's own weight (and its moment); the estimate subtracts it, computed from the
subtree's mass and centre of mass at the current pose, and reports the rest — the force the
environment applies to the hand — at the TCP, in the base frame.

Joint torques (`JointState.efforts`): the arm actuators' generalized forces, `qfrc_actuator` —
the position servo's torque plus the gravity compensation, which the arm joints' `actgravcomp`
routes through the actuators (counted against their torque limits) as a real motor supplies it;
nothing lands in `qfrc_passive` (the model has no joint springs, damping or passive gravity
compensation on the arm). They are the torques applied over the step that ends at the sample,
the servo's damping taken at the step's end velocity as the implicit integrator applies it. At
rest, nothing touching the arm, they equal Pinocchio's g(q) to rounding; the armature (rotor
inertia, `gains.armature_from_profile`) shows in them as it would on a real drive. A test pushes
on the arm with `push` / `release_push` (a force at a point of a body, mujoco/arm.py); a `fixed`
scene object is an obstacle welded to the world.

Gripper: the finger actuator tracks a width ramp at the requested speed, its force capped by the
grasp force (a grasp closes fully: the object stops the fingers, friction holds it). A stop freezes
the finger target where its ramp is (fingers on an object keep their grip; see `SimulatedFingers.stop_now`).

Cameras render offscreen on their own thread from the last published configuration of every
body (`OffscreenCameras`, mujoco/cameras.py); the first snapshot gets the camera part's
`setup_timeout_s` on top of the usual deadline (`SimulatedCameras`).
"""

# mujoco ships compiled pybind11 modules without type stubs (see model.py)
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from armwarden.backends.mujoco.arm import Push, SimulatedArm
from armwarden.backends.mujoco.cameras import OffscreenCameras, SimulatedCameras
from armwarden.backends.mujoco.config import Config
from armwarden.backends.mujoco.gains import armature_from_profile
from armwarden.backends.mujoco.gripper import SimulatedFingers
from armwarden.backends.mujoco.measurement import Measured
from armwarden.backends.mujoco.model import MujocoModel, build_model
from armwarden.backends.mujoco.scene import scene_for_policy
from armwarden.backends.parts import Cell, PublishedWrench
from armwarden.backends.servo import ServoBackend, ServoLoop, Setpoint, frozen
from armwarden.backends.settle import settle
from armwarden.backends.state_history import JointStateHistory
from armwarden.backends.values import ExecutionResult, ProgressCallback
from armwarden.backends.watchdog import Heartbeat
from armwarden.core.errors import BackendError
from armwarden.core.state import JointState, Wrench
from armwarden.core.trajectory import JointTrajectory
from armwarden.robot.model import RobotModel, resolve_description
from armwarden.robots import builtin_profile

if TYPE_CHECKING:
    from armwarden.policy import Policy

#: servo tick period [s] (wall time); physics catches up to each tick in `timestep_s` steps
CONTROL_PERIOD_S = 0.001

#: an execution has finished when the measured arm is this close to the goal [rad] ...
SETTLE_POSITION_RAD = 1e-3
#: ... and this slow [rad/s] (the speed below which the arm counts as stopped)
SETTLE_SPEED_RAD_S = 1e-3
#: a stopped arm comes to rest, and stays, this close to where it was measured when the stop took
#: effect [rad]: the braking distance at the contract's test speeds, and the servos' stiffness
HOLD_ACCURACY_RAD = 5e-3
#: simulated time [s] the arm may take to settle after the trajectory's time is up
SETTLE_TIMEOUT_S = 1.0
#: how often the event loop looks at the published sample while waiting to settle [s]
SETTLE_POLL_S = 0.002


class MujocoBackend(ServoBackend):
    """The simulated arm (see the module docstring)."""

    name = "mujoco"
    worker_threads = ("physics",)  # the servo loop; the render thread only runs submitted frames
    goal_accuracy_rad = SETTLE_POSITION_RAD
    hold_accuracy_rad = HOLD_ACCURACY_RAD
    rest_speed_rad_s = SETTLE_SPEED_RAD_S

    def __init__(self, robot: RobotModel, cell: MujocoModel, home: np.ndarray, *, speedup: float = 1.0,
                 start_tolerance_rad: float = 0.05, camera_size_px: tuple[int, int] = (640, 480)) -> None:
        super().__init__(robot.joint_names, start_tolerance_rad=start_tolerance_rad)
        if tuple(cell.arm_joints) != tuple(robot.joint_names):
            raise BackendError(f"the MuJoCo model's arm joints {cell.arm_joints} are not the robot's {robot.joint_names}")
        #: the compiled model and where its parts are
        self.sim = cell
        self._robot = robot
        model = cell.model
        home = np.asarray(home, dtype=float)
        if home.shape != (len(robot.joint_names),) or not np.all(np.isfinite(home)) or not robot.within_limits(home):
            raise BackendError(f"home {home.tolist()} is not a finite configuration within the joint limits")
        #: the physics and the arm's targets (the servo hooks delegate here)
        self.arm = SimulatedArm(cell, robot, home, lambda: self.fingers.target)
        actuator = cell.gripper_actuator
        #: the full opening [m] (the finger actuator's control range)
        self.gripper_max_width_m = float(model.actuator_ctrlrange[actuator][1]) if actuator is not None else 0.0
        force_limit_n = float(model.actuator_forcerange[actuator][1]) if actuator is not None else 0.0
        #: the fingers: what they track (read before every physics step) and the gripper actions
        self.fingers = SimulatedFingers(self.gripper_max_width_m, force_limit_n, lambda: self.arm.measured,
                                        self._gripper_stop_landed, lambda: self.servo.require_running())
        self._renderer = OffscreenCameras(model, camera_size_px)
        self.cell = Cell(gripper=self.fingers if actuator is not None else None,
                         cameras=SimulatedCameras(self._renderer, tuple(cell.cameras), self._published_scene)
                         if cell.cameras else None,
                         wrench=PublishedWrench(self._published_wrench), frames=tuple(robot.frame_names()),
                         joint_torques=True, time_scale=float(speedup),
                         joint_state_interval_s=CONTROL_PERIOD_S)  # a sample per physics tick
        self.servo = ServoLoop(self, home, period_s=CONTROL_PERIOD_S, idle_period_s=CONTROL_PERIOD_S, speedup=speedup,
                               name="mujoco backend")
        #: every tick's joint state, for the contact observer (`_joint_states_since`)
        self.joint_history = JointStateHistory()

    # ================================================================ lifecycle
    async def _open(self) -> None:
        self.arm.start(time.perf_counter())
        await self.servo.start("armwarden-mujoco-physics")

    def _worker_heartbeats(self) -> tuple[Heartbeat, ...]:
        """The physics runs on the servo loop: a tick that does not come is a step that does not."""
        return (self.servo.heartbeat("physics"),)

    async def _close(self) -> None:
        await self.servo.shutdown()
        await self._renderer.close()

    # ================================================================ state
    def _latest_joint_state(self) -> JointState:
        self.servo.require_running()
        return self._joint_state(self.arm.measured)

    def _joint_state(self, sample: Measured) -> JointState:
        return JointState(self.joint_names, sample.positions, sample.velocities, sample.stamp, sample.efforts)

    async def _read_joint_state(self) -> JointState:
        return self._latest_joint_state()

    def _joint_states_since(self, stamp: float) -> Sequence[JointState]:
        self.servo.require_running()
        return self.joint_history.since_or_latest(stamp)

    def _published_wrench(self) -> Wrench:
        self.servo.require_running()
        sample = self.arm.measured
        return Wrench(sample.force, sample.torque, sample.stamp)

    def _published_scene(self) -> tuple[np.ndarray, float]:
        """Every body's configuration in the latest sample, and its stamp (what cameras render)."""
        self.servo.require_running()
        sample = self.arm.measured
        return sample.scene_qpos, sample.stamp

    # ================================================================ pushing on the arm (tests)
    def push(self, body: str, force_base: Sequence[float], point_in_body: Sequence[float] = (0.0, 0.0, 0.0)) -> None:
        """Push on the arm from the next physics step on, until `release_push`: a force
        `force_base` [N] (the policy's base frame) at `point_in_body` [m] of the MuJoCo body `body`
        (a link: its frame is the URDF link's)."""
        model = self.sim.model
        force = np.array(force_base, dtype=float)
        point = np.array(point_in_body, dtype=float)
        if force.shape != (3,) or point.shape != (3,) or not (np.all(np.isfinite(force)) and np.all(np.isfinite(point))):
            raise ValueError(f"a push needs a finite 3-vector force and point, got {force.tolist()} at {point.tolist()}")
        body_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body)
        if body_id < 0:
            raise ValueError(f"MuJoCo has no body {body!r}")
        world_from_base = self.arm.data.xmat[model.body(self._robot.base_frame).id].reshape(3, 3)  # welded: constant
        self.arm.push = Push(body_id, frozen(world_from_base @ force), frozen(point))

    def release_push(self) -> None:
        """Nothing pushes on the arm any more (from the next physics step on)."""
        self.arm.push = None

    # ================================================================ motion
    async def _execute(self, trajectory: JointTrajectory, progress: ProgressCallback) -> ExecutionResult:
        self.servo.require_running()
        self.arm.tracking_peak_rad = 0.0  # no tick follows this trajectory before `run` hands it over
        result = await self.servo.run(trajectory, progress, preempted=self._stop_landed)
        if result.completed:
            result = await self._settle(trajectory.goal)
        elif result.reason == "stopped":
            result = replace(result, final_positions=await self._rest_position())
        return replace(result, max_tracking_error_rad=self.arm.tracking_peak_rad)

    async def _settle(self, goal: np.ndarray) -> ExecutionResult:
        """The trajectory's time is up and its goal is commanded; the physical arm is still
        catching up: within `SETTLE_TIMEOUT_S` of simulated time (`settle`)."""
        return await settle(goal, measure=lambda: self.arm.measured, check=self.servo.require_running,
                            stop_landed=self._stop_landed, rest_position=self._rest_position,
                            accuracy_rad=SETTLE_POSITION_RAD, rest_speed_rad_s=SETTLE_SPEED_RAD_S,
                            timeout_s=SETTLE_TIMEOUT_S, poll_s=SETTLE_POLL_S, speedup=self.servo.speedup)

    async def _rest_position(self) -> np.ndarray:
        """Where a stopped arm came to rest: once the brake has let go (or after
        `SETTLE_TIMEOUT_S` of simulated time, or once the physics has stopped: then where it is)."""
        deadline = time.monotonic() + SETTLE_TIMEOUT_S / self.servo.speedup
        thread = self.servo.thread
        while self.arm.target.braking and time.monotonic() < deadline and thread is not None and thread.is_alive():  # noqa: ASYNC110 - released by the physics thread
            await asyncio.sleep(SETTLE_POLL_S)
        return self.arm.measured.positions.copy()

    async def _stop(self) -> None:
        self._stop_now()

    def _stop_now(self) -> None:
        try:
            self.servo.hold()
        finally:  # the fingers stop even if the arm's hold failed
            self._stop_fingers()
        self.servo.require_running()  # held either way; a dead physics thread is still a failure

    # ================================================================ servo hooks
    def servo_prepare(self, setpoint: Setpoint) -> None:
        """Servo thread: run the physics up to now (× speedup) with the current targets."""
        if not self.arm.started or threading.current_thread() is not self.servo.thread:
            return  # the loop's first setpoint is prepared at construction, before physics runs
        self._worker_checkpoint("physics")
        before = self.arm.measured
        self.arm.step(setpoint, time.perf_counter(), self.servo.speedup)
        sample = self.arm.measured
        if sample is not before:  # a tick too short for a physics step measures nothing new
            self.joint_history.append(self._joint_state(sample))

    def servo_command(self, setpoint: Setpoint) -> None:
        """Track a trajectory sample (`SimulatedArm.command`)."""
        self.arm.command(setpoint)

    def servo_hold_positions(self, commanded: np.ndarray) -> np.ndarray:
        return self.arm.measured.positions

    def servo_hold(self, setpoint: Setpoint) -> None:
        """Any thread: brake from the next physics step on (`SimulatedArm.brake`)."""
        self.arm.brake(setpoint)

    def servo_failed(self, error: BaseException) -> None:
        """Physics thread, dying: tell the Guard (it latches the e-stop; one found before it listens
        is kept for it). Nothing is simulated any more, so nothing moves (found by review: the
        death was reported to nobody, and an idle arm's e-stop never latched); every later call is
        refused naming it."""
        self._worker_died("physics", error)

    def why_no_injected_death(self) -> str | None:
        return None  # a simulation, always

    def _inject_death(self) -> str:
        """Evaluation only (`armwarden.backends.death`): the physics thread dies at its next step."""
        return self._kill_worker("physics")


def create_backend(robot: RobotModel, policy: Policy, config: Config) -> MujocoBackend:
    """Registry factory: the simulated cell for `policy`'s robot, with `config`'s options."""
    overrides: dict[str, object] = {"timestep_s": config.timestep_s}
    if config.table_top_z_m is not None:
        overrides["table_top_z_m"] = config.table_top_z_m
    if config.cameras is not None:  # else the robot profile's mounts (scene_for_policy)
        overrides["cameras"] = tuple(c.spec() for c in config.cameras)
    overrides["objects"] = tuple(o.spec() for o in config.objects)
    scene = scene_for_policy(policy, **overrides)
    description = policy.robot.description
    cell = build_model(resolve_description(description), robot, scene,
                       armature=armature_from_profile(builtin_profile(description), robot.joint_names))
    return MujocoBackend(robot, cell, np.asarray(policy.robot.home_joint_positions, dtype=float),
                         speedup=config.speedup, start_tolerance_rad=policy.motion.start_tolerance_rad,
                         camera_size_px=(config.camera_width_px, config.camera_height_px))


__all__ = ["CONTROL_PERIOD_S", "Config", "MujocoBackend", "create_backend"]
