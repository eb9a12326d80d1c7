"""What one step of the simulated cell publishes: joint positions, velocities and torques, the
external wrench at the TCP (the hand's weight taken out), the fingers' width, speed and squeeze, every
body's configuration for rendering, and how deep the robot overlaps anything.

Read on the physics thread right after a step and published whole (`Measured`, read-only
arrays): every other thread reads the last sample, never `MjData` the physics thread is stepping.
"""

# mujoco ships compiled pybind11 modules without type stubs (see model.py)
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

import time
from dataclasses import dataclass

import mujoco
import numpy as np

from armwarden.backends.mujoco.model import GRAVITY_MPS2, MujocoModel
from armwarden.backends.servo import frozen
from armwarden.core.errors import BackendError
from armwarden.robot.model import RobotModel


@dataclass(frozen=True)
class Measured:
    """One published simulation sample; arrays are read-only."""

    positions: np.ndarray
    velocities: np.ndarray
    #: the arm actuators' joint torques [N·m] (`qfrc_actuator`: the servo's force and, with
    #: `actgravcomp`, the gravity compensation a real motor supplies too)
    efforts: np.ndarray
    #: the true external joint torques [N·m] on the arm (τ_ext of M q̈ + C q̇ + g = τ + τ_ext): contacts,
    #: joint limits and a test's push (`qfrc_constraint` and `xfrc_applied`). What a contact
    #: observer estimates: for tests and benchmarks, never published to the Guard
    external_efforts: np.ndarray
    force: np.ndarray  # external force on the hand at the TCP, base frame [N]
    torque: np.ndarray  # external torque about the TCP, base frame [N·m]
    gripper_width_m: float
    gripper_speed_mps: float
    gripper_force_n: float  # how hard the finger actuator squeezes [N] (0: no fingers)
    sim_s: float  # simulated time of the sample [s]
    scene_qpos: np.ndarray  # every body's configuration (arm, fingers, objects), for rendering
    robot_penetration_m: float  # deepest overlap of a robot geom with anything [m]; 0: none
    stamp: float


class CellMeter:
    """Reads a `Measured` sample from the cell's data (the indices it needs found once)."""

    def __init__(self, cell: MujocoModel, robot: RobotModel) -> None:
        model = cell.model
        self._cell = cell
        self._gripper = cell.gripper_actuator
        self._finger_dofs = np.array([model.jnt_dofadr[model.joint(name).id] for name in cell.finger_joints], dtype=np.intp)
        self._flange_body = model.body(cell.flange_body).id
        self._flange_site = model.site(_site_name(model, self._flange_body)).id
        self._tcp_body = model.body(robot.tcp_frame).id
        self._base_body = model.body(robot.base_frame).id
        #: geoms that belong to the robot (the arm's kinematic tree under the world)
        self._robot_geom = model.body_rootid[model.geom_bodyid] == model.body_rootid[self._base_body]
        self._hand_weight_n = float(model.body_subtreemass[self._flange_body]) * GRAVITY_MPS2
        self._implicit = int(model.opt.integrator) in (int(mujoco.mjtIntegrator.mjINT_IMPLICIT),
                                                       int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST))
        self._damping = np.zeros((model.nv, model.nv))  # ∂(actuator + passive force)/∂q̇ of the last step, dense

    def measure(self, data: mujoco.MjData, velocities_before: np.ndarray | None = None,
                stamp: float | None = None) -> Measured:
        """The sample the data holds after a step (servo thread); `velocities_before`: every
        joint velocity (`qvel`) before that step (None: no step ran); `stamp`: when, on the
        monotonic clock, the simulated state held (None: now)."""
        cell = self._cell
        site_rotation = data.site_xmat[self._flange_site].reshape(3, 3)
        site_position = data.site_xpos[self._flange_site]
        # what the hand's subtree exerts on the arm, in the world frame, about the flange site
        exerted_force = site_rotation @ data.sensordata[cell.force_sensor_adr:cell.force_sensor_adr + 3]
        exerted_torque = site_rotation @ data.sensordata[cell.torque_sensor_adr:cell.torque_sensor_adr + 3]
        # the hand's own weight, at its centre of mass: what it exerts at rest with nothing touching it
        weight = np.array([0.0, 0.0, -self._hand_weight_n])
        weight_torque = np.cross(data.subtree_com[self._flange_body] - site_position, weight)
        # the sensor reads the arm's force on the hand: at rest it carries the weight exactly
        # (arm + weight + environment = 0), so the environment's share is what remains, reversed;
        # while the hand accelerates, its inertial force shows up here too
        force = -(exerted_force + weight)
        torque_site = -(exerted_torque + weight_torque)
        torque_tcp = torque_site + np.cross(site_position - data.xpos[self._tcp_body], force)
        base_rotation = data.xmat[self._base_body].reshape(3, 3).T  # world → base
        return Measured(
            positions=frozen(data.qpos[cell.arm_qpos]),
            velocities=frozen(data.qvel[cell.arm_dofs]),
            efforts=frozen(self._applied_actuator_torques(data, velocities_before)),
            external_efforts=frozen(self._external(data)[cell.arm_dofs]),
            force=frozen(base_rotation @ force),
            torque=frozen(base_rotation @ torque_tcp),
            gripper_width_m=float(np.sum(data.qpos[cell.finger_qpos])),
            gripper_speed_mps=float(np.sum(data.qvel[self._finger_dofs])),
            gripper_force_n=-float(data.actuator_force[self._gripper]) if self._gripper is not None else 0.0,
            sim_s=float(data.time),
            scene_qpos=frozen(data.qpos),
            robot_penetration_m=self._robot_penetration_m(data),
            stamp=time.monotonic() if stamp is None else stamp,
        )

    def _applied_actuator_torques(self, data: mujoco.MjData, velocities_before: np.ndarray | None) -> np.ndarray:
        """The arm actuators' torques [N·m] the last step applied. `qfrc_actuator` evaluates the
        servo's damping −kv·q̇ at the step's starting velocity; the implicit integrators solve
        (M − h·∂f/∂q̇)·Δq̇ = h·f, so the arm receives f + (∂f/∂q̇)·Δq̇: the damping at the step's end
        velocity (∂f/∂q̇ is MuJoCo's own `qDeriv`, which leaves out a torque clamped at its limit).
        Without this an observer saw 1.4 N·m of phantom contact mid-motion (h·kv = 0.29 kg·m² of
        extra inertia on joint 2) and 4.6 N·m in a brake."""
        cell = self._cell
        torques = data.qfrc_actuator[cell.arm_dofs].copy()
        if self._implicit and velocities_before is not None:
            model = cell.model
            mujoco.mju_sparse2dense(self._damping, data.qDeriv, model.D_rownnz, model.D_rowadr, model.D_colind)
            torques += self._damping[cell.arm_dofs] @ (data.qvel - velocities_before)
        return torques

    def _external(self, data: mujoco.MjData) -> np.ndarray:
        """Generalized forces [N·m] of everything outside the actuators, gravity and inertia:
        constraints (contacts, limits) and the bodies' applied wrenches (at their centres of mass,
        as MuJoCo applies them), over the step that ends at the sample."""
        external = data.qfrc_constraint.copy()
        applied = data.xfrc_applied
        for body in np.flatnonzero(np.any(applied != 0.0, axis=1)):
            mujoco.mj_applyFT(self._cell.model, data, applied[body, :3].copy(), applied[body, 3:].copy(),
                              data.xipos[body].copy(), int(body), external)
        return external

    def _robot_penetration_m(self, data: mujoco.MjData) -> float:
        """How deep the deepest contact involving a robot geom overlaps [m] (0: none)."""
        if data.ncon == 0:
            return 0.0
        contacts = data.contact
        involved = self._robot_geom[contacts.geom1[:data.ncon]] | self._robot_geom[contacts.geom2[:data.ncon]]
        depths = -contacts.dist[:data.ncon][involved]
        return float(max(0.0, depths.max())) if depths.size else 0.0


def _site_name(model: mujoco.MjModel, body_id: int) -> str:
    for site in range(model.nsite):
        if model.site_bodyid[site] == body_id:
            return model.site(site).name
    raise BackendError("the MuJoCo model has no flange site")
