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
limits from the URDF `effort`, gravity compensation counted against those limits, and gains sized
from the arm's own joint-space inertia (`ArmGains.for_bandwidth`). `MujocoModel.arm_ctrl` turns a
sampled trajectory point (q, q̇) into the control that makes that actuator a PD law with velocity
feed-forward, so tracking does not lag by kv·q̇/kp.
"""

# mujoco ships compiled pybind11 modules, star-imported into `mujoco`, without type stubs: pyright
# sees none of its names, so attribute checks are off in this file only
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.backends.mujoco.camera_mounts import CameraSpec, look_at_quat, profile_cameras
from armwarden.core.errors import RobotModelError
from armwarden.robot.capsules import capsule_from_geometry
from armwarden.robot.model import RobotModel

if TYPE_CHECKING:
    from armwarden.policy import Policy

#: standard gravity [m/s²], also used to compensate the hand's weight in the wrench estimate
GRAVITY_MPS2 = 9.81
#: prefix of the envelope capsules' geom names (then the capsule's name)
ENVELOPE_PREFIX = "envelope/"
#: name of the site at the flange carrying the force/torque sensor
FLANGE_SITE = "flange"
FORCE_SENSOR = "flange_force"
TORQUE_SENSOR = "flange_torque"
#: tendon (sum of the two finger openings = gripper width [m]) and its actuator
GRIPPER_TENDON = "gripper_width"
GRIPPER_ACTUATOR = "gripper"
TABLE_GEOM = "table"
FLOOR_GEOM = "floor"
#: geom group of shapes that exist for the envelope only (not rendered by default, no contacts)
HIDDEN_GROUP = 3


@dataclass(frozen=True)
class SceneObject:
    """A loose rigid object in the cell (a free body): a box or an upright cylinder.

    `position_m` is its centre in the base frame, `yaw_rad` its rotation about the vertical;
    `size_m` the box's full (x, y, z) extents or the cylinder's (diameter, —, height)."""

    name: str
    shape: str  # "box" | "cylinder"
    position_m: tuple[float, float, float]
    size_m: tuple[float, float, float]
    mass_kg: float
    yaw_rad: float = 0.0
    friction: float = 1.0
    rgba: tuple[float, float, float, float] = (0.85, 0.2, 0.15, 1.0)


@dataclass(frozen=True)
class SceneSpec:
    """The cell around the robot; lengths [m] in the policy's base frame."""

    #: height of the table top = the policy's workspace floor (`workspace.box.min[2]`)
    table_top_z_m: float
    #: table footprint (x_min, y_min, x_max, y_max), e.g. the workspace box's
    table_xy_m: tuple[float, float, float, float]
    #: the floor lies this far below the table top
    table_height_m: float = 0.75
    table_thickness_m: float = 0.04
    table_friction: float = 0.8
    #: the robot profile's mounts for a built-in robot (`scene_for_policy`)
    cameras: tuple[CameraSpec, ...] = ()
    objects: tuple[SceneObject, ...] = ()
    #: physics step [s]
    timestep_s: float = 0.001
    #: largest grasp force the finger actuator can apply [N] (the policy's `gripper.max_grasp_force_n`)
    gripper_force_limit_n: float = 70.0


def scene_for_policy(policy: Policy, **overrides: Any) -> SceneSpec:
    """The cell the policy describes: the table top is the workspace floor and covers the workspace
    box's footprint; the finger force limit is the policy's grasp force cap; the cameras are the
    robot profile's (`profile_cameras`). `overrides` replace any other `SceneSpec` field."""
    box = policy.workspace.box
    cameras = overrides.get("cameras")
    scene = SceneSpec(table_top_z_m=float(box.min[2]),
                      table_xy_m=(float(box.min[0]), float(box.min[1]), float(box.max[0]), float(box.max[1])),
                      cameras=profile_cameras(policy.robot.description) if cameras is None else cameras)
    if policy.gripper is not None:
        scene = replace(scene, gripper_force_limit_n=float(policy.gripper.max_grasp_force_n))
    return replace(scene, **overrides)


@dataclass(frozen=True)
class ArmGains:
    """Per-joint gains of the arm's position actuators: stiffness kp [N·m/rad], damping kv
    [N·m·s/rad], and the rotor inertia (armature) [kg·m²] added to each joint."""

    kp: tuple[float, ...]
    kv: tuple[float, ...]
    armature: tuple[float, ...]

    @classmethod
    def for_bandwidth(cls, inertia: Sequence[float] | np.ndarray, armature: Sequence[float], bandwidth_rad_s: float = 60.0,
                      damping_ratio: float = 1.0) -> ArmGains:
        """Gains that give each joint, alone with its inertia [kg·m²] (armature included), the
        closed-loop natural frequency `bandwidth_rad_s` and `damping_ratio`."""
        inertia = np.asarray(inertia, dtype=float)
        kp = bandwidth_rad_s**2 * inertia
        kv = 2.0 * damping_ratio * bandwidth_rad_s * inertia
        return cls(tuple(map(float, kp)), tuple(map(float, kv)), tuple(map(float, armature)))


def default_armature(efforts_nm: Sequence[float]) -> tuple[float, ...]:
    """Reflected rotor inertia [kg·m²] by drive size: the FR3's large drives (effort ≥ 50 N·m)
    0.1, its small ones 0.05. It also keeps the light distal joints stiff enough to simulate."""
    return tuple(0.1 if effort >= 50.0 else 0.05 for effort in efforts_nm)


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

    def _to_world(self, point: Sequence[float] | np.ndarray) -> np.ndarray:
        return self.world_from_base.act(np.asarray(point, dtype=float))

    # ------------------------------------------------------------------ robot
    def replace_collision_geometry(self) -> None:
        """Drop the URDF's shapes; add the envelope's bodies as geoms on their links' bodies: the
        fitted capsules (`robot.fitted`, link frame) when the robot has them, else one capsule per
        URDF collision primitive."""
        for geom in list(self.spec.geoms):
            self.spec.delete(geom)
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

    def finger_joints(self) -> list[str]:
        """Movable joints that are not arm joints: the gripper's fingers (prismatic, two or none)."""
        arm = set(self.robot.joint_names)
        others = [joint for joint in self.spec.joints if joint.name not in arm]
        if not others:
            return []
        if len(others) != 2 or any(joint.type != mujoco.mjtJoint.mjJNT_SLIDE for joint in others):
            raise RobotModelError(
                "the MuJoCo backend supports a gripper of exactly two prismatic fingers besides the arm "
                f"joints; the description also has {[joint.name for joint in others]}"
            )
        return [joint.name for joint in others]

    def add_gripper(self, fingers: list[str]) -> None:
        """Couple the fingers, actuate their summed opening (the width), give each a contact pad."""
        if not any(eq.type == mujoco.mjtEq.mjEQ_JOINT for eq in self.spec.equalities):
            # a URDF <mimic> already couples them; otherwise the fingers move symmetrically by constraint
            self.spec.add_equality(type=mujoco.mjtEq.mjEQ_JOINT, name1=fingers[1], name2=fingers[0])
        tendon = self.spec.add_tendon(name=GRIPPER_TENDON)
        for name in fingers:
            tendon.wrap_joint(name, 1.0)
        low = sum(float(self.spec.joint(name).range[0]) for name in fingers)
        high = sum(float(self.spec.joint(name).range[1]) for name in fingers)
        actuator = self.spec.add_actuator(name=GRIPPER_ACTUATOR, target=GRIPPER_TENDON,
                                          trntype=mujoco.mjtTrn.mjTRN_TENDON)
        # 2 kN/m: a 70 N grasp presses the target 35 mm into the object; critically damped
        actuator.set_to_position(kp=2000.0, dampratio=1.0)
        actuator.ctrlrange = [low, high]
        actuator.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        limit = self.scene.gripper_force_limit_n
        actuator.forcerange = [-limit, limit]
        actuator.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        bodies = [self.spec.joint(name).parent.name for name in fingers]
        self.spec.add_exclude(bodyname1=bodies[0], bodyname2=bodies[1])  # fingers meet when closed
        if self.robot.fitted is None:
            for name in fingers:
                joint = self.spec.joint(name)
                axis = np.asarray(joint.axis, dtype=float)
                # inner face on the finger's closing side, 8 mm thick outward, 24 mm tall around the TCP height
                joint.parent.add_geom(name=f"pad/{joint.parent.name}", type=mujoco.mjtGeom.mjGEOM_BOX,
                                      pos=axis * PAD_HALF_SIZE_M[1] + np.array([0.0, 0.0, PAD_CENTER_Z_M]),
                                      size=list(PAD_HALF_SIZE_M), **PAD_GEOM)
            self._disable_finger_envelope(bodies)
        else:
            for name in fingers:
                self._pad_past_closing_plane(name, self._closing_plane_offset(fingers, name))

    def _closing_plane_offset(self, fingers: list[str], finger: str) -> float:
        """Where the fingers meet when closed, in `finger`'s frame: the plane axis·x = offset (axis:
        its joint's, pointing away from the other finger), midway between both fingers' frames at
        their lower limits. Refuses fingers that do not travel toward each other along one line."""
        joints = [self.spec.joint(name) for name in fingers]
        origins, directions = [], []
        for joint in joints:
            body = joint.parent
            rotation = np.zeros(9)
            mujoco.mju_quat2Mat(rotation, np.asarray(body.quat, dtype=float))
            direction = rotation.reshape(3, 3) @ np.asarray(joint.axis, dtype=float)
            direction /= np.linalg.norm(direction)
            directions.append(direction)
            origins.append(np.asarray(body.pos, dtype=float) + direction * float(joint.range[0]))
        if float(directions[0] @ directions[1]) > -1.0 + 1e-9:
            raise RobotModelError(f"the fingers {fingers} do not travel along one line in opposite directions; "
                                  "the MuJoCo backend cannot place their grasp surfaces")
        mid = (origins[0] + origins[1]) / 2.0
        index = fingers.index(finger)
        joint = joints[index]
        return float(directions[index] @ (mid - np.asarray(joint.parent.pos, dtype=float))) - float(joint.range[0])

    def _pad_past_closing_plane(self, finger: str, offset: float) -> None:
        """The fitted capsules of `finger` that reach past the closing plane leave their contacts
        to a pad: nothing of a real finger lies past that plane (the fingers meet there when
        closed), so a capsule's rounding beyond it is fitting slack, and an object between the
        fingers would meet that slack before the finger's real face — the width would read too
        wide by the slack on each side. Such a capsule stays (hidden, contact-free) and its pad is
        the box inside it with one face on the plane: centred on its segment, as thick as twice the
        segment's distance c from the plane, and as wide and as far past each end of the segment
        as the rest of the radius allows, equally (sqrt((r² − c²)/2), less 10 µm). The box's
        corners lie inside the capsule, so the pad lies inside the envelope's finger body."""
        joint = self.spec.joint(finger)
        body = joint.parent
        axis = np.asarray(joint.axis, dtype=float)
        axis /= np.linalg.norm(axis)
        for geom in list(body.geoms):
            if not geom.name.startswith(ENVELOPE_PREFIX):
                continue
            radius = float(geom.size[0])
            if geom.type == mujoco.mjtGeom.mjGEOM_CAPSULE:
                a, b = np.asarray(geom.fromto[:3], dtype=float), np.asarray(geom.fromto[3:], dtype=float)
            else:
                a = b = np.asarray(geom.pos, dtype=float)
            distances = (float(axis @ a) - offset, float(axis @ b) - offset)
            if min(distances) >= radius:
                continue  # wholly on the finger's own side of the plane
            if abs(distances[0] - distances[1]) > 1e-9 or distances[0] <= 0.0:
                raise RobotModelError(
                    f"fitted finger body {geom.name[len(ENVELOPE_PREFIX):]!r} reaches past the plane the fingers "
                    "meet in, and its segment is not parallel to that plane on the finger's own side; the MuJoCo "
                    "backend cannot put a grasp surface on the plane inside it"
                )
            depth = distances[0]
            side = float(np.sqrt((radius**2 - depth**2) / 2.0)) - PAD_INSET_M
            segment = b - a
            half_length = float(np.linalg.norm(segment)) / 2.0
            along = segment / (2.0 * half_length) if half_length > 0.0 else _perpendicular(axis)
            across = np.cross(axis, along)
            centre = (a + b) / 2.0
            # the box's frame: x along the segment, y across it, z along the finger's travel
            rotation = np.column_stack([along, across, axis])
            quat = np.zeros(4)
            mujoco.mju_mat2Quat(quat, rotation.reshape(-1))
            name = geom.name[len(ENVELOPE_PREFIX):]
            body.add_geom(name=f"pad/{name}", type=mujoco.mjtGeom.mjGEOM_BOX, pos=centre, quat=quat,
                          size=[half_length + side, side, depth], **PAD_GEOM)
            self.contact_geoms[name] = f"pad/{name}"
            geom.contype = 0
            geom.conaffinity = 0
            geom.group = HIDDEN_GROUP

    def _disable_finger_envelope(self, finger_bodies: list[str]) -> None:
        """Envelope capsules on the fingers' parent that contain both pads at every opening cover the
        finger sweep: keep them (hidden) for the envelope, take them out of contact."""
        parent = self.spec.body(finger_bodies[0]).parent
        for geom in parent.geoms:
            if geom.name.startswith(ENVELOPE_PREFIX) and self._covers_pads(geom, finger_bodies):
                geom.contype = 0
                geom.conaffinity = 0
                geom.group = HIDDEN_GROUP

    def _covers_pads(self, geom: mujoco.MjsGeom, finger_bodies: list[str]) -> bool:
        if geom.type != mujoco.mjtGeom.mjGEOM_CAPSULE:
            return False
        a, b = np.asarray(geom.fromto[:3]), np.asarray(geom.fromto[3:])
        return all(
            capsule_contains(a, b, float(geom.size[0]), corner)
            for corner in finger_pad_corners(self.spec, finger_bodies)
        )

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

    # ------------------------------------------------------------------ cell
    def add_cell(self) -> None:
        scene = self.scene
        world = self.spec.worldbody
        rotation = self.world_from_base.rotation
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, rotation.reshape(-1))
        x0, y0, x1, y1 = scene.table_xy_m
        top = scene.table_top_z_m
        world.add_geom(name=TABLE_GEOM, type=mujoco.mjtGeom.mjGEOM_BOX,
                       pos=self._to_world(((x0 + x1) / 2, (y0 + y1) / 2, top - scene.table_thickness_m / 2)),
                       quat=quat, size=[(x1 - x0) / 2, (y1 - y0) / 2, scene.table_thickness_m / 2],
                       friction=[scene.table_friction, 0.005, 0.0001], rgba=[0.55, 0.42, 0.3, 1.0])
        world.add_geom(name=FLOOR_GEOM, type=mujoco.mjtGeom.mjGEOM_PLANE,
                       pos=self._to_world((0.0, 0.0, top - scene.table_height_m)), quat=quat,
                       size=[0, 0, 0.05], rgba=[0.8, 0.8, 0.8, 1.0])
        world.add_light(name="key", pos=self._to_world((0.5, -1.0, 2.5)), dir=rotation @ np.array([-0.2, 0.4, -1.0]),
                        diffuse=[0.7, 0.7, 0.7], castshadow=True)
        world.add_light(name="fill", pos=self._to_world((-1.0, 1.0, 2.0)), dir=rotation @ np.array([0.4, -0.4, -1.0]),
                        diffuse=[0.3, 0.3, 0.3], castshadow=False)
        for camera in scene.cameras:
            self._add_camera(camera)
        for item in scene.objects:
            self._add_object(item)

    def _add_object(self, item: SceneObject) -> None:
        if item.shape not in ("box", "cylinder"):
            raise RobotModelError(f"scene object {item.name!r}: shape must be 'box' or 'cylinder', not {item.shape!r}")
        rotation = self.world_from_base.rotation @ pin.utils.rpyToMatrix(0.0, 0.0, item.yaw_rad)
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, rotation.reshape(-1))
        body = self.spec.worldbody.add_body(name=item.name, pos=self._to_world(item.position_m), quat=quat)
        body.add_freejoint(name=item.name)
        if item.shape == "box":
            shape, size = mujoco.mjtGeom.mjGEOM_BOX, [v / 2.0 for v in item.size_m]
        else:
            shape, size = mujoco.mjtGeom.mjGEOM_CYLINDER, [item.size_m[0] / 2.0, item.size_m[2] / 2.0, 0.0]
        body.add_geom(name=item.name, type=shape, size=size, mass=item.mass_kg, condim=4,
                      friction=[item.friction, 0.02, 0.001], rgba=list(item.rgba))

    def _add_camera(self, camera: CameraSpec) -> None:
        position = np.asarray(camera.position_m, dtype=float)
        target = np.asarray(camera.target_m, dtype=float)
        up = np.asarray(camera.up, dtype=float)
        if camera.body is None:
            body = self.spec.worldbody
            position, target = self._to_world(position), self._to_world(target)
            up = self.world_from_base.rotation @ up
        else:
            body = self.spec.body(camera.body)
            if body is None:
                raise RobotModelError(f"camera {camera.name!r}: MuJoCo has no body {camera.body!r}")
        body.add_camera(name=camera.name, pos=position, quat=look_at_quat(position, target, up), fovy=camera.fovy_deg)

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


#: finger pad half sizes (x, y = thickness, z) [m] and centre height on the finger [m]
PAD_HALF_SIZE_M = (0.009, 0.004, 0.012)
PAD_CENTER_Z_M = 0.0416
#: stiff pad contacts (time constant 4 ms = 4 physics steps, critically damped; hard impedance):
#: MuJoCo's default, 20 ms, lets a 70 N grasp sink the pads millimetres into the object
PAD_CONTACT: dict[str, Any] = {"solref": [0.004, 1.0], "solimp": [0.95, 0.99, 0.001, 0.5, 2.0]}
#: everything a finger pad geom gets besides its placement: grip friction, torsional friction, stiff contacts
PAD_GEOM: dict[str, Any] = {"friction": [1.0, 0.02, 0.001], "condim": 4, **PAD_CONTACT, "rgba": [0.2, 0.2, 0.2, 1.0]}
#: a pad inscribed in a fitted finger capsule stays this far inside its surface [m]
PAD_INSET_M = 1e-5


def _perpendicular(vector: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to `vector` (unit)."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(vector[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    side = np.cross(vector, helper)
    return side / np.linalg.norm(side)


def finger_pad_corners(spec: mujoco.MjSpec, finger_bodies: list[str]) -> list[np.ndarray]:
    """Every pad corner, in the fingers' parent frame, at both ends of each finger's travel."""
    corners = []
    for name in finger_bodies:
        body = spec.body(name)
        joint = body.joints[0]
        axis = np.asarray(joint.axis, dtype=float)
        origin = np.asarray(body.pos, dtype=float)
        center = axis * PAD_HALF_SIZE_M[1] + np.array([0.0, 0.0, PAD_CENTER_Z_M])
        half = np.asarray(PAD_HALF_SIZE_M)
        for opening in joint.range:
            for signs in np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3):
                corners.append(origin + axis * opening + center + signs * half)
    return corners


def capsule_contains(a: np.ndarray, b: np.ndarray, radius: float, point: np.ndarray) -> bool:
    """Whether `point` lies in the capsule of segment a–b and `radius` (same frame)."""
    segment = b - a
    length2 = float(segment @ segment)
    t = 0.0 if length2 == 0.0 else float(np.clip((point - a) @ segment / length2, 0.0, 1.0))
    return float(np.linalg.norm(point - (a + t * segment))) <= radius


def _joint_inertia(model: mujoco.MjModel, arm_qpos: np.ndarray, arm_dofs: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Diagonal of the joint-space inertia at `q` [kg·m²], armature included."""
    data = mujoco.MjData(model)
    data.qpos[arm_qpos] = q
    mujoco.mj_forward(model, data)
    diagonal = np.zeros(len(arm_dofs))
    unit, column = np.zeros(model.nv), np.zeros(model.nv)
    for index, dof in enumerate(arm_dofs):  # M·e_i: the same call across MuJoCo versions, unlike mj_fullM
        unit[:] = 0.0
        unit[dof] = 1.0
        mujoco.mj_mulM(model, data, column, unit)
        diagonal[index] = column[dof]
    return diagonal


def build_model(urdf_path: Path, robot: RobotModel, scene: SceneSpec, *, gains: ArmGains | None = None,
                reference_q: np.ndarray | None = None) -> MujocoModel:
    """Compile the cell for `robot` (loaded from `urdf_path`). Without `gains`, they are sized for
    a 60 rad/s, critically damped joint servo at `reference_q` (default: mid-range), each joint
    alone with its inertia there."""
    builder = _Builder(urdf_path, robot, scene)
    builder.replace_collision_geometry()
    builder.configure_arm()
    efforts = builder.arm_efforts()
    fingers = builder.finger_joints()
    if fingers:
        builder.add_gripper(fingers)
    builder.exclude_links_in_contact()
    flange_body = builder.add_flange_sensor()
    builder.add_cell()
    builder.set_options()
    armature = default_armature(efforts) if gains is None else gains.armature
    if len(armature) != len(robot.joint_names):
        raise RobotModelError(f"gains for {len(armature)} joints; the arm has {len(robot.joint_names)}")
    if gains is None:
        for index, name in enumerate(robot.joint_names):
            builder.spec.joint(name).armature = armature[index]
        probe = builder.compile()
        qpos, dofs = _arm_addresses(probe, robot.joint_names)
        q = (robot.lower + robot.upper) / 2.0 if reference_q is None else np.asarray(reference_q, dtype=float)
        gains = ArmGains.for_bandwidth(_joint_inertia(probe, qpos, dofs, q), armature)
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
