"""The MuJoCo model of the cell, built from the same URDF the Pinocchio `RobotModel` loads.

One description, two engines: MuJoCo imports the URDF for the kinematic tree and the inertias, and
`mujoco.MjSpec` adds what a URDF lacks — actuators, the gripper coupling, the table, lights,
cameras and the flange force/torque sensor. The URDF's own collision shapes are replaced by the
bodies the safety envelope checks, so physical contacts happen where the envelope thinks the arm
is; every contact geom lies inside an envelope body of its link (tested):

- With fitted geometry (`RobotModel.fitted`, the bundled FR3): the fitted capsules, each on its
  own link's body in the link frame. The envelope sweeps a finger's capsules over the whole
  opening; here they sit un-swept on the finger bodies, which move. A finger capsule that reaches
  past the plane the fingers meet in when closed is fitting slack there (no real finger lies
  beyond it), and an object between the fingers would meet that slack first and read too wide: it
  stays without contacts, and a pad inside it with one face on that plane takes its contacts.
  Self-contacts: parent and child are excluded, and so are link pairs the pair analysis shows in
  contact by construction; every pair the envelope checks on an excluded link pair is restored as
  an explicit pair (`_Builder.exclude_links_in_contact`).
- Without (the URDF's primitives, `robot.collision_geometry: urdf`): one capsule per primitive.
  The envelope covers the fingers with one capsule that spans every opening width; as a contact
  shape it would collide with any object between the fingers, so it stays without contacts and
  each finger gets a pad that lies inside it at every opening (tested).

Nothing here reaches the network; meshes are not needed because the collision and visual geometry
are all primitives.

Arm control: one position actuator per arm joint (force = kp·(ctrl − q) − kv·q̇), with joint torque
limits from the URDF `effort`, gravity compensation counted against those limits, each joint's
rotor inertia (armature) from the robot profile's `actuators` (gains.py), and gains sized from the
arm's own joint-space inertia (`ArmGains.for_bandwidth`). `MujocoModel.arm_ctrl` turns a
sampled trajectory point (q, q̇) into the control that makes that actuator a PD law with velocity
feed-forward, so tracking does not lag by kv·q̇/kp.
"""

# mujoco ships compiled pybind11 modules, star-imported into `mujoco`, without type stubs: pyright
# sees none of its names, so attribute checks are off in this file only
# pyright: reportAttributeAccessIssue=false
from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.backends.mujoco.gains import ArmGains, generic_armature, joint_inertia
from armwarden.backends.mujoco.gripper_model import add_gripper, finger_joints
from armwarden.backends.mujoco.names import (
    ENVELOPE_PREFIX,
    FLANGE_SITE,
    FORCE_SENSOR,
    GRIPPER_ACTUATOR,
    HIDDEN_GROUP,
    TORQUE_SENSOR,
)
from armwarden.backends.mujoco.scene import SceneSpec, add_cell
from armwarden.core.errors import RobotModelError
from armwarden.robot.capsules import capsule_from_geometry
from armwarden.robot.model import RobotModel

logger = logging.getLogger(__name__)

#: standard gravity [m/s²], also used to compensate the hand's weight in the wrench estimate
GRAVITY_MPS2 = 9.81


@dataclass(frozen=True)
class MujocoModel:
    """A compiled model and where its parts are: indices into `qpos`/`qvel`/`ctrl`/`sensordata`."""

    model: mujoco.MjModel
    arm_joints: tuple[str, ...]
    arm_qpos: np.ndarray
    arm_dofs: np.ndarray
    arm_actuators: np.ndarray
    gains: ArmGains
    finger_joints: tuple[str, ...]
    finger_qpos: np.ndarray
    gripper_actuator: int | None
    force_sensor_adr: int
    torque_sensor_adr: int
    #: the body the flange site sits on; the sensor measures the force its subtree exerts
    flange_body: str
    cameras: tuple[str, ...]

    def arm_ctrl(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """Controls that make each arm actuator kp·(q − q_meas) + kv·(q̇ − q̇_meas)."""
        kp = np.asarray(self.gains.kp)
        kv = np.asarray(self.gains.kv)
        return np.asarray(q, dtype=float) + kv / kp * np.asarray(qd, dtype=float)

    def set_arm_positions(self, data: mujoco.MjData, q: np.ndarray) -> None:
        """Place the arm at `q` at rest and hold it there (ctrl = q)."""
        data.qpos[self.arm_qpos] = q
        data.qvel[self.arm_dofs] = 0.0
        data.ctrl[self.arm_actuators] = q


class _Builder:
    """Edits the imported spec step by step; `build_model` is the public entry point."""

    def __init__(self, urdf_path: Path, robot: RobotModel, scene: SceneSpec) -> None:
        self.robot = robot
        self.scene = scene
        try:
            self.spec = mujoco.MjSpec.from_file(str(urdf_path))
        except Exception as exc:  # mujoco raises ValueError with the parser's message
            raise RobotModelError(f"MuJoCo cannot import robot description {urdf_path}: {exc}") from exc
        compiler = self.spec.compiler
        compiler.fusestatic = False  # keep every URDF link a body: flange, hand and TCP stay addressable
        # keep contact-free geoms: the finger envelope capsule is one (the URDF's own shapes are deleted anyway)
        compiler.discardvisual = False
        # the bundled hand's URDF inertia breaks the triangle inequality; MuJoCo refuses it unless balanced
        compiler.balanceinertia = True
        self.robot_bodies = [body.name for body in self.spec.bodies if body.name != "world"]
        self.world_from_base = self._world_from_base()
        #: envelope body name -> the geom that makes its contacts (its own, or a finger pad inside it)
        self.contact_geoms: dict[str, str] = {}

    def _world_from_base(self) -> pin.SE3:
        """Where the policy's base frame sits in the URDF root frame (MuJoCo's world)."""
        model = self.robot.model
        data = model.createData()
        pin.framesForwardKinematics(model, data, pin.neutral(model))
        return data.oMf[self.robot.frame_id(self.robot.base_frame)].copy()

    def replace_collision_geometry(self) -> None:
        """Drop the URDF's shapes; add the envelope's bodies as geoms on their links' bodies: the
        fitted capsules (`robot.fitted`, link frame) when the robot has them, else one capsule per
        URDF collision primitive."""
        for geom in list(self.spec.geoms):
            self.spec.delete(geom)
        for mesh in list(self.spec.meshes):  # unused now; their files need not exist (the fitted capsules stand in)
            self.spec.delete(mesh)
        fitted = self.robot.fitted
        if fitted is not None:
            for link, fit in fitted.links.items():
                body = self._link_body(link)
                for item in fit.bodies:
                    self._add_capsule(body, item.name, np.asarray(item.p0_m, dtype=float),
                                      np.asarray(item.p1_m, dtype=float), item.radius_m)
            return
        model = self.robot.model
        for obj in self.robot.geometry.geometryObjects:
            p0, p1, radius = capsule_from_geometry(obj)
            link_frame = model.frames[obj.parentFrame]
            # the capsule's points are in its joint's frame; the MuJoCo body is the link's frame
            link_from_joint = link_frame.placement.inverse()
            self._add_capsule(self._link_body(link_frame.name), obj.name, link_from_joint.act(p0),
                              link_from_joint.act(p1), radius)

    def _link_body(self, link: str) -> mujoco.MjsBody:
        body = self.spec.body(link)
        if body is None:
            raise RobotModelError(f"MuJoCo has no body for link {link!r}")
        return body

    def _add_capsule(self, body: mujoco.MjsBody, name: str, a: np.ndarray, b: np.ndarray, radius: float) -> None:
        """The envelope body `name` as a contact geom (`ENVELOPE_PREFIX` + name) on `body`."""
        self.contact_geoms[name] = ENVELOPE_PREFIX + name
        if np.linalg.norm(b - a) < 1e-12:
            body.add_geom(name=ENVELOPE_PREFIX + name, type=mujoco.mjtGeom.mjGEOM_SPHERE, pos=a, size=[radius, 0, 0])
        else:
            body.add_geom(name=ENVELOPE_PREFIX + name, type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                          fromto=[*a, *b], size=[radius, 0, 0])

    def configure_arm(self) -> None:
        for name in self.robot.joint_names:
            joint = self.spec.joint(name)
            if joint is None:
                raise RobotModelError(f"MuJoCo has no joint {name!r}")
            joint.actgravcomp = True  # gravity compensation counts against the joint's torque limit
        for name in self.robot_bodies:
            body = self.spec.body(name)
            body.gravcomp = 1.0
            # MuJoCo skips parent-child contacts except below a body welded to the world (the
            # base): adjacent links' capsules overlap at the joint by design, so exclude them all
            if body.parent is not None and body.parent.name in self.robot_bodies:
                self.spec.add_exclude(bodyname1=body.parent.name, bodyname2=name)

    def exclude_links_in_contact(self) -> None:
        """With fitted geometry: no contacts between links that the pair analysis shows in contact
        by construction, and contacts for every body pair the envelope checks.

        MuJoCo excludes whole body pairs, the analysis judges capsule pairs. A link pair gets an
        exclude (besides parent and child, excluded in `configure_arm`) when one of its capsule
        pairs is `overlapping` (always touching within the analysed limits) or `adjacent` (touching
        at the joint between them): MuJoCo would otherwise report a contact in every
        configuration, which the envelope rightly ignores. The other capsule pairs of an excluded
        link pair lose their contacts too; that is sound only for pairs the envelope does not
        check either (proved `apart`, or on one driven joint). Every pair the envelope does check
        on a link pair MuJoCo filters (by an exclude, or by its own parent-child rule between weld
        bodies) is restored as an explicit contact pair, which no exclude filters (and MuJoCo
        never counts twice). So the sim's self-contacts are the envelope's checked pairs plus
        pairs proved never to touch."""
        fitted = self.robot.fitted
        if fitted is None:
            return
        link_of = {item.name: link for link, fit in fitted.links.items() for item in fit.bodies}
        excluded = {frozenset((exclude.bodyname1, exclude.bodyname2)) for exclude in self.spec.excludes}
        for pair in fitted.excluded_pairs:
            links = frozenset(link_of[name] for name in pair.bodies)
            if pair.reason in ("overlapping", "adjacent") and len(links) == 2 and links not in excluded:
                first, second = sorted(links)
                self.spec.add_exclude(bodyname1=first, bodyname2=second)
                excluded.add(links)
        capsules = self.robot.capsules
        for a, b in self.robot.self_collision_pairs:
            first, second = capsules[a], capsules[b]
            if frozenset((first.link, second.link)) in excluded or self._welds_are_parent_and_child(first.link, second.link):
                self.spec.add_pair(geomname1=self.contact_geoms[first.name], geomname2=self.contact_geoms[second.name])

    def _weld(self, body: mujoco.MjsBody) -> mujoco.MjsBody:
        """The body MuJoCo welds `body` to: itself if it has a joint, else its parent's weld."""
        while not body.joints and body.parent is not None and body.name != "world":
            body = body.parent
        return body

    def _welds_are_parent_and_child(self, link_a: str, link_b: str) -> bool:
        """Whether MuJoCo's own parent-child filter (on weld bodies) may drop contacts between the links."""
        weld_a, weld_b = self._weld(self._link_body(link_a)), self._weld(self._link_body(link_b))
        parent_a = self._weld(weld_a.parent) if weld_a.parent is not None else None
        parent_b = self._weld(weld_b.parent) if weld_b.parent is not None else None
        return (parent_b is not None and parent_b.name == weld_a.name) or \
            (parent_a is not None and parent_a.name == weld_b.name)

    def arm_efforts(self) -> list[float]:
        efforts = []
        for name in self.robot.joint_names:
            joint = self.spec.joint(name)
            low, high = joint.actfrcrange
            if not (high > 0 and low < 0):
                raise RobotModelError(f"joint {name!r} has no effort limit in the description; MuJoCo needs one")
            efforts.append(float(min(-low, high)))
        return efforts

    def add_arm_actuators(self, gains: ArmGains) -> None:
        for index, name in enumerate(self.robot.joint_names):
            self.spec.joint(name).armature = gains.armature[index]
            actuator = self.spec.add_actuator(name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
            actuator.set_to_position(kp=gains.kp[index], kv=gains.kv[index])
            actuator.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE  # ctrl carries velocity feed-forward


    def add_flange_sensor(self) -> str:
        """A site at the flange (the first body past the last arm joint toward the TCP) with a
        force and a torque sensor: they measure what the tool's subtree exerts on the arm."""
        last_arm_body = self.spec.joint(self.robot.joint_names[-1]).parent
        body = self.spec.body(self.robot.tcp_frame)
        if body is None:
            raise RobotModelError(f"MuJoCo has no body for the TCP frame {self.robot.tcp_frame!r}")
        while body.parent is not None and body.parent.name != last_arm_body.name:
            body = body.parent
        if body.parent is None:
            raise RobotModelError(f"the TCP frame {self.robot.tcp_frame!r} is not beyond the last arm joint")
        body.add_site(name=FLANGE_SITE, size=[0.01, 0, 0], group=HIDDEN_GROUP)
        self.spec.add_sensor(name=FORCE_SENSOR, type=mujoco.mjtSensor.mjSENS_FORCE,
                             objtype=mujoco.mjtObj.mjOBJ_SITE, objname=FLANGE_SITE)
        self.spec.add_sensor(name=TORQUE_SENSOR, type=mujoco.mjtSensor.mjSENS_TORQUE,
                             objtype=mujoco.mjtObj.mjOBJ_SITE, objname=FLANGE_SITE)
        return body.name

    def set_options(self) -> None:
        option = self.spec.option
        option.timestep = self.scene.timestep_s
        # implicit in the actuators' damping: stable with stiff position servos at 1 kHz
        option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
        option.gravity = [0.0, 0.0, -GRAVITY_MPS2]
        # a grasp holds by friction alone: elliptic cones, frictional constraints 10× harder than
        # normal ones, and a few no-slip iterations remove the creep soft contacts otherwise allow
        # (about 1 mm/s of a 0.2 kg box slipping out of a 70 N grasp without them)
        option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
        option.impratio = 10.0
        option.noslip_iterations = 3
        self.spec.visual.global_.offwidth = 1280
        self.spec.visual.global_.offheight = 960

    def compile(self) -> mujoco.MjModel:
        try:
            return self.spec.compile()
        except Exception as exc:
            raise RobotModelError(f"MuJoCo cannot compile the model: {exc}") from exc



def build_model(urdf_path: Path, robot: RobotModel, scene: SceneSpec, *, armature: Sequence[float] | None = None,
                gains: ArmGains | None = None, reference_q: np.ndarray | None = None) -> MujocoModel:
    """Compile the cell for `robot` (loaded from `urdf_path`). Without `gains`, they are sized for
    a 60 rad/s, critically damped joint servo at `reference_q` (default: mid-range), each joint
    alone with its inertia there and its `armature` [kg·m²] (the robot profile's,
    `armature_from_profile`; None: `generic_armature` by drive size, logged)."""
    builder = _Builder(urdf_path, robot, scene)
    builder.replace_collision_geometry()
    builder.configure_arm()
    efforts = builder.arm_efforts()
    fingers = finger_joints(builder.spec, set(robot.joint_names))
    if fingers:
        add_gripper(builder.spec, fingers, force_limit_n=scene.gripper_force_limit_n, fitted=robot.fitted is not None,
                    contact_geoms=builder.contact_geoms)
    builder.exclude_links_in_contact()
    flange_body = builder.add_flange_sensor()
    add_cell(builder.spec, scene, builder.world_from_base)
    builder.set_options()
    if gains is not None:
        if armature is not None:
            raise RobotModelError("give the arm's armature or its whole gains, not both")
        armature = gains.armature
    elif armature is None:
        armature = generic_armature(efforts)
        logger.warning("the robot profile gives no actuators: the MuJoCo arm uses the generic armature rule by "
                       "drive size (%s kg·m² for joints %s)", ", ".join(map(str, armature)), ", ".join(robot.joint_names))
    if len(armature) != len(robot.joint_names):
        raise RobotModelError(f"gains for {len(armature)} joints; the arm has {len(robot.joint_names)}")
    if gains is None:
        for index, name in enumerate(robot.joint_names):
            builder.spec.joint(name).armature = armature[index]
        probe = builder.compile()
        qpos, dofs = _arm_addresses(probe, robot.joint_names)
        q = (robot.lower + robot.upper) / 2.0 if reference_q is None else np.asarray(reference_q, dtype=float)
        gains = ArmGains.for_bandwidth(joint_inertia(probe, qpos, dofs, q), armature)
    builder.add_arm_actuators(gains)
    model = builder.compile()
    arm_qpos, arm_dofs = _arm_addresses(model, robot.joint_names)
    arm_actuators = np.array([model.actuator(name).id for name in robot.joint_names], dtype=np.intp)
    finger_qpos = np.array([model.jnt_qposadr[model.joint(name).id] for name in fingers], dtype=np.intp)
    gripper = model.actuator(GRIPPER_ACTUATOR).id if fingers else None
    return MujocoModel(
        model=model,
        arm_joints=tuple(robot.joint_names),
        arm_qpos=arm_qpos,
        arm_dofs=arm_dofs,
        arm_actuators=arm_actuators,
        gains=gains,
        finger_joints=tuple(fingers),
        finger_qpos=finger_qpos,
        gripper_actuator=gripper,
        force_sensor_adr=int(model.sensor_adr[model.sensor(FORCE_SENSOR).id]),
        torque_sensor_adr=int(model.sensor_adr[model.sensor(TORQUE_SENSOR).id]),
        flange_body=flange_body,
        cameras=tuple(camera.name for camera in scene.cameras),
    )


def _arm_addresses(model: mujoco.MjModel, joint_names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    ids = [model.joint(name).id for name in joint_names]
    return (np.array([model.jnt_qposadr[i] for i in ids], dtype=np.intp),
            np.array([model.jnt_dofadr[i] for i in ids], dtype=np.intp))
