"""The MuJoCo backend: the FR3 cell simulated with real physics behind the backend contract.

Physics runs on the servo thread (`armwarden.backends.servo.ServoLoop`): each tick first steps the
simulation up to the tick's time (wall time × `speedup`, in `timestep_s` steps), then commands the
tick's trajectory sample as actuator targets (`MujocoModel.arm_ctrl`: PD with velocity
feed-forward). The targets are one tuple, replaced whole, and read before every physics step, so
a stop issued from any thread reaches the actuators at the next step. A tick that comes late (the
host was busy) catches up with targets ramped from the last sample to its own, as a controller
running at its own rate would have tracked them: stepping the whole stall on the stale sample made
the arm lag, then jerk (tracking errors of 0.1 rad and a 31 N inertial "contact" on a loaded
2-core machine; 3–16 mrad with the ramp).

What is published is what the simulation measures, never what was commanded: joint positions and
velocities (`qpos`/`qvel`) and the external wrench, stamped (monotonic clock) after the step that
produced them. A stop brakes the arm from the next physics step on: its actuators become pure
dampers (saturating at the joint torque limits) until every joint is still, then position servos
that hold it where it stopped (`_ArmTarget`). It never pulls the arm back to where it was last told
to be, nor to where the stop found it; a stopped execution reports where the arm came to rest.

Wrench: the flange force/torque sensor measures what the hand's subtree exerts on the arm. At
rest that is the hand's own weight (and its moment); the estimate subtracts it, computed from the
subtree's mass and centre of mass at the current pose, and reports the rest — the force the
environment applies to the hand — at the TCP, in the base frame.

Gripper: the finger actuator tracks a width ramp at the requested speed, its force capped by the
grasp force (a grasp closes fully: the object stops the fingers, friction holds it). A stop freezes
the finger target where its ramp is (fingers on an object keep their grip; see `_stop_fingers`).

Cameras render offscreen on their own thread from the last published configuration of every
body (`OffscreenCameras`, mujoco/cameras.py); the first snapshot gets `camera_setup_timeout_s` on
top of the usual deadline.
"""

# mujoco ships compiled pybind11 modules without type stubs (see model.py)
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

import asyncio
import logging
import threading
import time
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from armwarden.backends.base import Capabilities
from armwarden.backends.mujoco.cameras import OffscreenCameras
from armwarden.backends.mujoco.config import Config
from armwarden.backends.mujoco.gains import armature_from_profile
from armwarden.backends.mujoco.gripper import SimulatedFingers
from armwarden.backends.mujoco.measurement import CellMeter
from armwarden.backends.mujoco.model import MujocoModel, build_model
from armwarden.backends.mujoco.scene import scene_for_policy
from armwarden.backends.servo import ServoBackend, ServoLoop, Setpoint, frozen
from armwarden.backends.settle import settle
from armwarden.backends.values import CameraImage, ExecutionResult, GripperResult, ProgressCallback
from armwarden.backends.watchdog import Heartbeat
from armwarden.core.errors import BackendError
from armwarden.core.state import GripperState, JointState, Wrench
from armwarden.core.trajectory import JointTrajectory
from armwarden.robot.model import RobotModel, resolve_description
from armwarden.robots import builtin_profile

if TYPE_CHECKING:
    from armwarden.policy import Policy

logger = logging.getLogger(__name__)

#: servo tick period [s] (wall time); physics catches up to each tick in `timestep_s` steps
CONTROL_PERIOD_S = 0.001
#: most physics steps one tick may run; a tick further behind (machine stalled) drops the rest
MAX_STEPS_PER_TICK = 500

#: an execution has finished when the measured arm is this close to the goal [rad] ...
SETTLE_POSITION_RAD = 1e-3
#: ... and this slow [rad/s] (the speed below which the arm counts as stopped)
SETTLE_SPEED_RAD_S = 1e-3
#: a stopped arm comes to rest, and stays, this close to where it was measured when the stop took
#: effect [rad]: the braking distance at the contract's test speeds, and the servos' stiffness
HOLD_ACCURACY_RAD = 5e-3
#: a stop turns the arm actuators into dampers this many times stiffer than the tracking damping
#: (saturating at the torque limits). Measured: 5 brings 0.5 rad/s to rest in ~25 ms simulated;
#: 20 goes unstable at 1 kHz on the light joints (scripts/_bench/mujoco_cell.py, docs/benchmarks.md)
BRAKE_DAMPING_FACTOR = 5.0
#: below this joint speed [rad/s] the brake is released into a position hold where the arm stands
BRAKE_RELEASE_RAD_S = 1e-4
#: simulated time [s] after which the brake is released into a hold whatever the speed (a brake
#: never stays on: the position hold is what keeps a stopped arm where it is)
BRAKE_LIMIT_S = 0.3
#: simulated time [s] the arm may take to settle after the trajectory's time is up
SETTLE_TIMEOUT_S = 1.0
#: how often the event loop looks at the published sample while waiting to settle [s]
SETTLE_POLL_S = 0.002

#: extra deadline [s] for the first camera snapshot, which creates the renderer and draws its first
#: frame (1.2–1.5 s measured on a loaded 2-core machine with software EGL, vs 0.2–0.35 s after)
RENDERER_SETUP_TIMEOUT_S = 15.0


@dataclass
class _ArmTarget:
    """What the arm actuators do: track `positions` [rad] with feed-forward `velocities` [rad/s]
    (a trajectory sample when `following`, else a hold), or brake (`braking`: pure damping until
    the arm is still, then a hold where it stopped). Replaced whole, never edited, except that the
    physics thread notes when a brake began (`since_s`, simulated time [s])."""

    positions: np.ndarray
    velocities: np.ndarray
    following: bool = False
    braking: bool = False
    since_s: float | None = None


class MujocoBackend(ServoBackend):
    """The simulated arm (see the module docstring)."""

    name = "mujoco"
    worker_threads = ("physics",)  # the servo loop; the render thread only runs submitted frames
    goal_accuracy_rad = SETTLE_POSITION_RAD
    hold_accuracy_rad = HOLD_ACCURACY_RAD
    rest_speed_rad_s = SETTLE_SPEED_RAD_S
    camera_setup_timeout_s = RENDERER_SETUP_TIMEOUT_S

    def __init__(self, robot: RobotModel, cell: MujocoModel, home: np.ndarray, *, speedup: float = 1.0,
                 start_tolerance_rad: float = 0.05, camera_size_px: tuple[int, int] = (640, 480)) -> None:
        super().__init__(robot.joint_names, start_tolerance_rad=start_tolerance_rad)
        if tuple(cell.arm_joints) != tuple(robot.joint_names):
            raise BackendError(f"the MuJoCo model's arm joints {cell.arm_joints} are not the robot's {robot.joint_names}")
        self.cell = cell
        model = cell.model
        # an unstable step must end the simulation, not restart it: MuJoCo's automatic reset would
        # put the arm back at the model's defaults (time back to 0) and that would be published as
        # a fresh, valid state (found by review: an idle, held arm "moved" 2.3 rad)
        model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)
        # MuJoCo writes its warnings to MUJOCO_LOG.TXT in the working directory unless told
        # otherwise (process-wide, set once here): they go to the log on stderr instead
        mujoco.set_mju_user_warning(_log_mujoco_warning)
        self._model = model
        self._data = mujoco.MjData(model)
        self.timestep_s = float(model.opt.timestep)
        home = np.asarray(home, dtype=float)
        if home.shape != (len(robot.joint_names),) or not np.all(np.isfinite(home)) or not robot.within_limits(home):
            raise BackendError(f"home {home.tolist()} is not a finite configuration within the joint limits")
        cell.set_arm_positions(self._data, home)
        if cell.gripper_actuator is not None:  # fingers open, and held open
            for address, name in zip(cell.finger_qpos, cell.finger_joints, strict=True):
                self._data.qpos[address] = model.jnt_range[model.joint(name).id][1]
            self._data.ctrl[cell.gripper_actuator] = model.actuator_ctrlrange[cell.gripper_actuator][1]
        mujoco.mj_forward(model, self._data)
        self._gripper = cell.gripper_actuator
        #: the full opening [m] (the finger actuator's control range)
        self.gripper_max_width_m = float(model.actuator_ctrlrange[self._gripper][1]) if self._gripper is not None else 0.0
        self.gripper_travel_m = self.gripper_max_width_m
        force_limit_n = float(model.actuator_forcerange[self._gripper][1]) if self._gripper is not None else 0.0
        #: the fingers: what they track (read before every physics step) and the gripper actions
        self.fingers = SimulatedFingers(self.gripper_max_width_m, force_limit_n, lambda: self._measured,
                                        self._gripper_stop_landed, lambda: self.servo.require_running())
        self._meter = CellMeter(cell, robot)
        #: deepest robot contact [m] seen since `reset_peak_penetration` (simulation diagnostics)
        self.peak_robot_penetration_m = 0.0
        #: what the arm's actuators do; replaced whole (stops, ticks), read before every physics step
        self._target = _ArmTarget(frozen(home), frozen(np.zeros_like(home)))
        self._braking_gains = False  # the actuators' gains are the brake's (physics thread)
        self._tracking_kv = np.asarray(cell.gains.kv, dtype=float)
        self._tracking_kp = np.asarray(cell.gains.kp, dtype=float)
        self._measured = self._meter.measure(self._data)
        self._last_wall: float | None = None  # perf_counter up to which physics has run; None: not started
        self._pending_sim_s = 0.0
        #: largest |measured − commanded| [rad] over the running trajectory's samples (servo thread)
        self._tracking_peak_rad = 0.0
        #: physics steps run so far, and steps skipped because the thread fell too far behind
        self.step_count = 0
        self.dropped_steps = 0
        self._cameras = OffscreenCameras(model, camera_size_px)
        self._capabilities = Capabilities(wrench=True, gripper=self._gripper is not None, cameras=tuple(cell.cameras),
                                          frames=tuple(robot.frame_names()))
        self.servo = ServoLoop(self, home, period_s=CONTROL_PERIOD_S, idle_period_s=CONTROL_PERIOD_S, speedup=speedup,
                               name="mujoco backend")

    # ================================================================ lifecycle
    @property
    def capabilities(self) -> Capabilities:
        return self._capabilities

    async def _open(self) -> None:
        self._last_wall = time.perf_counter()
        await self.servo.start("armwarden-mujoco-physics")

    def _worker_heartbeats(self) -> tuple[Heartbeat, ...]:
        """The physics runs on the servo loop: a tick that does not come is a step that does not."""
        return (self.servo.heartbeat("physics"),)

    async def _close(self) -> None:
        await self.servo.shutdown()
        await self._cameras.close()

    # ================================================================ state
    def _latest_joint_state(self) -> JointState:
        self.servo.require_running()
        sample = self._measured
        return JointState(self.joint_names, sample.positions, sample.velocities, sample.stamp)

    async def _read_joint_state(self) -> JointState:
        return self._latest_joint_state()

    def _latest_wrench(self) -> Wrench:
        self.servo.require_running()
        sample = self._measured
        return Wrench(sample.force, sample.torque, sample.stamp)

    async def _read_wrench(self) -> Wrench:
        return self._latest_wrench()

    # ================================================================ motion
    async def _execute(self, trajectory: JointTrajectory, progress: ProgressCallback) -> ExecutionResult:
        self.servo.require_running()
        self._tracking_peak_rad = 0.0  # no tick follows this trajectory before `run` hands it over
        result = await self.servo.run(trajectory, progress, preempted=self._stop_landed)
        if result.completed:
            result = await self._settle(trajectory.goal)
        elif result.reason == "stopped":
            result = replace(result, final_positions=await self._rest_position())
        return replace(result, max_tracking_error_rad=self._tracking_peak_rad)

    async def _settle(self, goal: np.ndarray) -> ExecutionResult:
        """The trajectory's time is up and its goal is commanded; the physical arm is still
        catching up: within `SETTLE_TIMEOUT_S` of simulated time (`settle`)."""
        return await settle(goal, measure=lambda: self._measured, check=self.servo.require_running,
                            stop_landed=self._stop_landed, rest_position=self._rest_position,
                            accuracy_rad=SETTLE_POSITION_RAD, rest_speed_rad_s=SETTLE_SPEED_RAD_S,
                            timeout_s=SETTLE_TIMEOUT_S, poll_s=SETTLE_POLL_S, speedup=self.servo.speedup)

    async def _rest_position(self) -> np.ndarray:
        """Where a stopped arm came to rest: once the brake has let go (or after
        `SETTLE_TIMEOUT_S` of simulated time, or once the physics has stopped: then where it is)."""
        deadline = time.monotonic() + SETTLE_TIMEOUT_S / self.servo.speedup
        thread = self.servo.thread
        while self._target.braking and time.monotonic() < deadline and thread is not None and thread.is_alive():  # noqa: ASYNC110 - released by the physics thread
            await asyncio.sleep(SETTLE_POLL_S)
        return self._measured.positions.copy()

    async def _stop(self) -> None:
        self._stop_now()

    def _stop_now(self) -> None:
        self.servo.hold()
        self._stop_fingers()
        self.servo.require_running()  # held either way; a dead physics thread is still a failure

    def _stop_fingers(self) -> None:
        """Any thread (`Backend._stop_fingers`): see `SimulatedFingers.freeze`."""
        self.fingers.freeze()

    # ================================================================ gripper (gripper.py)
    def _latest_gripper_state(self) -> GripperState:
        return self.fingers.state()

    async def _gripper_move(self, width_m: float, speed_mps: float) -> GripperResult:
        return await self.fingers.move(width_m, speed_mps)

    async def _gripper_grasp(self, width_m: float, force_n: float, speed_mps: float, epsilon_inner_m: float,
                             epsilon_outer_m: float) -> GripperResult:
        return await self.fingers.grasp(width_m, force_n, speed_mps, epsilon_inner_m, epsilon_outer_m)

    async def _gripper_home(self) -> GripperResult:
        return await self.fingers.home()

    # ================================================================ cameras
    async def _camera_snapshot(self, camera: str) -> CameraImage:
        self.servo.require_running()
        sample = self._measured
        return await self._cameras.snapshot(camera, sample.scene_qpos, sample.stamp)

    def _camera_set_up(self) -> bool:
        return self._cameras.set_up

    # ================================================================ servo hooks
    def servo_prepare(self, setpoint: Setpoint) -> None:
        """Servo thread: run the physics up to now (× speedup) with the current targets."""
        if self._last_wall is None or threading.current_thread() is not self.servo.thread:
            return  # the loop's first setpoint is prepared at construction, before physics runs
        self._worker_checkpoint("physics")
        now = time.perf_counter()
        self._pending_sim_s += (now - self._last_wall) * self.servo.speedup
        self._last_wall = now
        steps = int(self._pending_sim_s / self.timestep_s)
        self._pending_sim_s -= steps * self.timestep_s
        if steps > MAX_STEPS_PER_TICK:
            self.dropped_steps += steps - MAX_STEPS_PER_TICK
            logger.warning("mujoco backend: physics fell %d steps behind; dropping them", steps - MAX_STEPS_PER_TICK)
            steps = MAX_STEPS_PER_TICK
        if steps == 0:
            return
        model, data, cell = self._model, self._data, self.cell
        # a stalled tick (a loaded machine): the trajectory moved on meanwhile, so the catch-up
        # steps track the samples between the last one commanded and this tick's, not the stale
        # one — the simulated controller keeps its rate whatever the host's scheduling
        ramp = self._target if self._target.following and setpoint.following and steps > 1 else None
        for step in range(steps):
            target = self._target
            if target.braking:
                if target.since_s is None:
                    target.since_s = float(data.time)
                if (float(np.max(np.abs(data.qvel[cell.arm_dofs]))) < BRAKE_RELEASE_RAD_S
                        or data.time - target.since_s > BRAKE_LIMIT_S):
                    self._release_brake(target)
                    target = self._target
            if target.braking != self._braking_gains:
                self._set_brake(target.braking)
            if ramp is not None and target is ramp:  # not replaced (by a stop) since the catch-up began
                a = step / steps
                data.ctrl[cell.arm_actuators] = cell.arm_ctrl(
                    ramp.positions + a * (setpoint.positions - ramp.positions),
                    ramp.velocities + a * (setpoint.velocities - ramp.velocities))
            elif not target.braking:
                data.ctrl[cell.arm_actuators] = cell.arm_ctrl(target.positions, target.velocities)
            if self._gripper is not None:
                fingers = self.fingers.target
                data.ctrl[self._gripper] = fingers.ramp.position(data.time)
                model.actuator_forcerange[self._gripper] = (-fingers.force_n, fingers.force_n)
            mujoco.mj_step(model, data)
        self.step_count += steps
        unstable = data.warning[int(mujoco.mjtWarning.mjWARN_BADQACC)].number > 0
        if unstable or not (np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.qvel))):
            raise BackendError("the simulation diverged (" + ("unstable accelerations" if unstable else "non-finite state") + ")")
        self._measured = self._meter.measure(self._data)
        self.peak_robot_penetration_m = max(self.peak_robot_penetration_m, self._measured.robot_penetration_m)
        if setpoint.following:  # the physics has reached this sample's time: how far off is the arm?
            error = float(np.max(np.abs(self._measured.positions - setpoint.positions)))
            self._tracking_peak_rad = max(self._tracking_peak_rad, error)

    def servo_command(self, setpoint: Setpoint) -> None:
        """Track a trajectory sample; while idle, keep whatever hold (or brake) is in force — it,
        not the loop's last commanded position, knows where the arm came to rest. The first idle
        tick after a completed trajectory holds its goal."""
        if setpoint.following or self._target.following:
            self._target = _ArmTarget(setpoint.positions, setpoint.velocities, following=setpoint.following)

    def servo_hold_positions(self, commanded: np.ndarray) -> np.ndarray:
        return self._measured.positions

    def servo_hold(self, setpoint: Setpoint) -> None:
        """Any thread: brake from the next physics step on (see `_set_brake`)."""
        self._target = _ArmTarget(setpoint.positions, setpoint.velocities, braking=True)

    def servo_failed(self, error: BaseException) -> None:
        """Physics thread, dying: tell the Guard (it latches the e-stop; one found before it listens
        is kept for it). Nothing is simulated any more, so nothing moves (found by review: the
        death was reported to nobody, and an idle arm's e-stop never latched); every later call is
        refused naming it."""
        self._worker_died("physics", error)

    def _set_brake(self, braking: bool) -> None:
        """Physics thread: the arm actuators become pure dampers (force = −kv_brake·q̇, saturating
        at the joint torque limits: the hardest stop the drives can make), or position servos again."""
        model, actuators = self._model, self.cell.arm_actuators
        kp = 0.0 if braking else self._tracking_kp
        model.actuator_gainprm[actuators, 0] = kp
        model.actuator_biasprm[actuators, 1] = -kp
        model.actuator_biasprm[actuators, 2] = -self._tracking_kv * (BRAKE_DAMPING_FACTOR if braking else 1.0)
        self._braking_gains = braking

    def _release_brake(self, braking: _ArmTarget) -> None:
        """Physics thread: the arm has stopped; hold it where it is. Only the brake this step saw
        is released (a stop that replaced it meanwhile brakes anew)."""
        arm = self._data.qpos[self.cell.arm_qpos]
        if self._target is braking:
            self._target = _ArmTarget(frozen(arm), braking.velocities)

def _log_mujoco_warning(text: str) -> None:
    logger.warning("mujoco: %s", text.strip())


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
