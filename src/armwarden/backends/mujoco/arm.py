"""The MuJoCo arm in motion: the physics the servo thread steps, the arm actuators' targets, and
the brake a stop applies.

The servo thread is the physics thread: each tick steps the whole cell (arm and fingers) up to the
tick's time (wall time × `speedup`, in `timestep_s` steps) with the current targets, then commands
the tick's trajectory sample (`MujocoModel.arm_ctrl`: PD with velocity feed-forward). The targets
are one record (`ArmTarget`), replaced whole, and read before every physics step, so a stop issued
from any thread reaches the actuators at the next step. A tick that comes late (the host was busy)
catches up with targets ramped from the last sample to its own, as a controller running at its own
rate would have tracked them: stepping the whole stall on the stale sample made the arm lag, then
jerk (tracking errors of 0.1 rad and a 31 N inertial "contact" on a loaded 2-core machine; 3–16
mrad with the ramp).

A stop brakes the arm from the next physics step on: its actuators become pure dampers (saturating
at the joint torque limits) until every joint is still, then position servos that hold it where it
stopped. It never pulls the arm back to where it was last told to be, nor to where the stop found it.

What is published (`measured`) is what the simulation measures after a step, never what was commanded.

A test pushes on the arm (`push`): a force at a point of a body, applied through `xfrc_applied`
from the next physics step on, re-aimed every step as the body turns, until it is released.
"""

# mujoco ships compiled pybind11 modules without type stubs (see model.py)
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np

from armwarden.backends.mujoco.gripper import FingerTarget
from armwarden.backends.mujoco.measurement import CellMeter, Measured
from armwarden.backends.mujoco.model import MujocoModel
from armwarden.backends.servo import Setpoint, frozen
from armwarden.core.errors import BackendError
from armwarden.robot.model import RobotModel

logger = logging.getLogger(__name__)

#: most physics steps one tick may run; a tick further behind (machine stalled) drops the rest
MAX_STEPS_PER_TICK = 500
#: a stop turns the arm actuators into dampers this many times stiffer than the tracking damping
#: (saturating at the torque limits). Measured: 5 brings 0.5 rad/s to rest in ~25 ms simulated;
#: 20 goes unstable at 1 kHz on the light joints (scripts/_bench/mujoco_cell.py, docs/benchmarks.md)
BRAKE_DAMPING_FACTOR = 5.0
#: below this joint speed [rad/s] the brake is released into a position hold where the arm stands
BRAKE_RELEASE_RAD_S = 1e-4
#: simulated time [s] after which the brake is released into a hold whatever the speed (a brake
#: never stays on: the position hold is what keeps a stopped arm where it is)
BRAKE_LIMIT_S = 0.3


@dataclass(frozen=True)
class Push:
    """A force `force_world` [N] (world frame) at `point_in_body` [m] of the MuJoCo body `body_id`."""

    body_id: int
    force_world: np.ndarray
    point_in_body: np.ndarray


@dataclass
class ArmTarget:
    """What the arm actuators do: track `positions` [rad] with feed-forward `velocities` [rad/s]
    (a trajectory sample when `following`, else a hold), or brake (`braking`: pure damping until
    the arm is still, then a hold where it stopped). Replaced whole, never edited, except that the
    physics thread notes when a brake began (`since_s`, simulated time [s])."""

    positions: np.ndarray
    velocities: np.ndarray
    following: bool = False
    braking: bool = False
    since_s: float | None = None


class SimulatedArm:
    """The cell's physics and the arm's targets (see the module docstring). `step` runs on the
    physics thread only; `command`, `brake` and `measured` may be used from any thread."""

    def __init__(self, cell: MujocoModel, robot: RobotModel, home: np.ndarray,
                 finger_target: Callable[[], FingerTarget]) -> None:
        self.cell = cell
        model = cell.model
        # an unstable step must end the simulation, not restart it: MuJoCo's automatic reset would
        # put the arm back at the model's defaults (time back to 0) and that would be published as
        # a fresh, valid state (found by review: an idle, held arm "moved" 2.3 rad)
        model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)
        # MuJoCo writes its warnings to MUJOCO_LOG.TXT in the working directory unless told
        # otherwise (process-wide, set once here): they go to the log on stderr instead
        mujoco.set_mju_user_warning(_log_mujoco_warning)
        self.model = model
        self.data = mujoco.MjData(model)
        self.timestep_s = float(model.opt.timestep)
        cell.set_arm_positions(self.data, home)
        if cell.gripper_actuator is not None:  # fingers open, and held open
            for address, name in zip(cell.finger_qpos, cell.finger_joints, strict=True):
                self.data.qpos[address] = model.jnt_range[model.joint(name).id][1]
            self.data.ctrl[cell.gripper_actuator] = model.actuator_ctrlrange[cell.gripper_actuator][1]
        mujoco.mj_forward(model, self.data)
        self._finger_target = finger_target  # what the fingers track, read before every step
        self._meter = CellMeter(cell, robot)
        #: deepest robot contact [m] seen since it was last reset (simulation diagnostics)
        self.peak_robot_penetration_m = 0.0
        #: what the arm's actuators do; replaced whole (stops, ticks), read before every physics step
        self.target = ArmTarget(frozen(home), frozen(np.zeros_like(home)))
        self._braking_gains = False  # the actuators' gains are the brake's (physics thread)
        self._tracking_kv = np.asarray(cell.gains.kv, dtype=float)
        self._tracking_kp = np.asarray(cell.gains.kp, dtype=float)
        #: the latest published sample, replaced whole after each tick's steps
        self.measured: Measured = self._meter.measure(self.data)
        self._last_wall: float | None = None  # perf_counter up to which physics has run; None: not started
        self._pending_sim_s = 0.0
        self._monotonic_minus_wall = 0.0  # monotonic − perf_counter, read when the physics starts
        #: largest |measured − commanded| [rad] over the running trajectory's samples (physics thread)
        self.tracking_peak_rad = 0.0
        #: physics steps run so far, and steps skipped because the thread fell too far behind
        self.step_count = 0
        self.dropped_steps = 0
        #: a test's push on the arm (None: none); replaced whole, read before every physics step
        self.push: Push | None = None
        self._pushed_body: int | None = None  # the body whose `xfrc_applied` the push wrote (physics thread)

    @property
    def started(self) -> bool:
        return self._last_wall is not None

    def start(self, now_wall: float) -> None:
        """Simulated time runs from `now_wall` (perf_counter) on."""
        self._last_wall = now_wall
        self._monotonic_minus_wall = time.monotonic() - time.perf_counter()

    def step(self, setpoint: Setpoint, now_wall: float, speedup: float) -> None:
        """Physics thread: run the physics up to `now_wall` (× `speedup`) with the current targets."""
        if self._last_wall is None:
            raise BackendError("the physics was stepped before it started")
        self._pending_sim_s += (now_wall - self._last_wall) * speedup
        self._last_wall = now_wall
        steps = int(self._pending_sim_s / self.timestep_s)
        self._pending_sim_s -= steps * self.timestep_s
        if steps > MAX_STEPS_PER_TICK:
            self.dropped_steps += steps - MAX_STEPS_PER_TICK
            logger.warning("mujoco backend: physics fell %d steps behind; dropping them", steps - MAX_STEPS_PER_TICK)
            steps = MAX_STEPS_PER_TICK
        if steps == 0:
            return
        model, data, cell = self.model, self.data, self.cell
        # a stalled tick (a loaded machine): the trajectory moved on meanwhile, so the catch-up
        # steps track the samples between the last one commanded and this tick's, not the stale
        # one — the simulated controller keeps its rate whatever the host's scheduling
        ramp = self.target if self.target.following and setpoint.following and steps > 1 else None
        gripper = cell.gripper_actuator
        velocities_before: np.ndarray | None = None
        for step in range(steps):
            target = self.target
            if target.braking:
                if target.since_s is None:
                    target.since_s = float(data.time)
                if (float(np.max(np.abs(data.qvel[cell.arm_dofs]))) < BRAKE_RELEASE_RAD_S
                        or data.time - target.since_s > BRAKE_LIMIT_S):
                    self._release_brake(target)
                    target = self.target
            if target.braking != self._braking_gains:
                self._set_brake(target.braking)
            if ramp is not None and target is ramp:  # not replaced (by a stop) since the catch-up began
                a = step / steps
                data.ctrl[cell.arm_actuators] = cell.arm_ctrl(
                    ramp.positions + a * (setpoint.positions - ramp.positions),
                    ramp.velocities + a * (setpoint.velocities - ramp.velocities))
            elif not target.braking:
                data.ctrl[cell.arm_actuators] = cell.arm_ctrl(target.positions, target.velocities)
            if gripper is not None:
                fingers = self._finger_target()
                data.ctrl[gripper] = fingers.ramp.position(data.time)
                model.actuator_forcerange[gripper] = (-fingers.force_n, fingers.force_n)
            self._apply_push(self.push)
            velocities_before = data.qvel.copy()  # the measured torques need the last step's
            mujoco.mj_step(model, data)
        self.step_count += steps
        unstable = data.warning[int(mujoco.mjtWarning.mjWARN_BADQACC)].number > 0
        if unstable or not (np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.qvel))):
            raise BackendError("the simulation diverged (" + ("unstable accelerations" if unstable else "non-finite state") + ")")
        # stamped when the simulated state held on the wall clock, not when the thread got to
        # measuring it: the physics reached `now_wall` less the fraction of a step still pending.
        # A stamp taken after the steps would carry their compute time and the thread's
        # scheduling, and the contact observer, which divides momentum changes by the stamps'
        # intervals, read that jitter as torque (4.3 N·m on joint 2 against 2.1 N·m)
        held_at = now_wall - self._pending_sim_s / speedup + self._monotonic_minus_wall
        self.measured = self._meter.measure(self.data, velocities_before, stamp=held_at)
        self.peak_robot_penetration_m = max(self.peak_robot_penetration_m, self.measured.robot_penetration_m)
        if setpoint.following:  # the physics has reached this sample's time: how far off is the arm?
            error = float(np.max(np.abs(self.measured.positions - setpoint.positions)))
            self.tracking_peak_rad = max(self.tracking_peak_rad, error)

    def _apply_push(self, push: Push | None) -> None:
        """Physics thread: the push as a wrench at the body's centre of mass (`xfrc_applied`), its
        moment about it from where the point is now; a released push leaves nothing behind."""
        data = self.data
        if self._pushed_body is not None and (push is None or push.body_id != self._pushed_body):
            data.xfrc_applied[self._pushed_body] = 0.0
            self._pushed_body = None
        if push is None:
            return
        body = push.body_id
        point = data.xpos[body] + data.xmat[body].reshape(3, 3) @ push.point_in_body
        data.xfrc_applied[body, :3] = push.force_world
        data.xfrc_applied[body, 3:] = np.cross(point - data.xipos[body], push.force_world)
        self._pushed_body = body

    def command(self, setpoint: Setpoint) -> None:
        """Track a trajectory sample; while idle, keep whatever hold (or brake) is in force — it,
        not the loop's last commanded position, knows where the arm came to rest. The first idle
        tick after a completed trajectory holds its goal."""
        if setpoint.following or self.target.following:
            self.target = ArmTarget(setpoint.positions, setpoint.velocities, following=setpoint.following)

    def brake(self, setpoint: Setpoint) -> None:
        """Any thread: brake from the next physics step on (see `_set_brake`)."""
        self.target = ArmTarget(setpoint.positions, setpoint.velocities, braking=True)

    def _set_brake(self, braking: bool) -> None:
        """Physics thread: the arm actuators become pure dampers (force = −kv_brake·q̇, saturating
        at the joint torque limits: the hardest stop the drives can make), or position servos again."""
        model, actuators = self.model, self.cell.arm_actuators
        kp = 0.0 if braking else self._tracking_kp
        model.actuator_gainprm[actuators, 0] = kp
        model.actuator_biasprm[actuators, 1] = -kp
        model.actuator_biasprm[actuators, 2] = -self._tracking_kv * (BRAKE_DAMPING_FACTOR if braking else 1.0)
        self._braking_gains = braking

    def _release_brake(self, braking: ArmTarget) -> None:
        """Physics thread: the arm has stopped; hold it where it is. Only the brake this step saw
        is released (a stop that replaced it meanwhile brakes anew)."""
        arm = self.data.qpos[self.cell.arm_qpos]
        if self.target is braking:
            self.target = ArmTarget(frozen(arm), braking.velocities)


def _log_mujoco_warning(text: str) -> None:
    logger.warning("mujoco: %s", text.strip())


__all__ = ["BRAKE_DAMPING_FACTOR", "ArmTarget", "Push", "SimulatedArm"]
