"""The gripper as the MuJoCo model builds it: two prismatic fingers coupled to move symmetrically,
one position actuator on their summed opening (the width) with its force capped, and a contact pad
on each finger where an object is gripped.

Pads, because the envelope's finger bodies make poor grasp surfaces: without fitted geometry the
envelope covers both fingers with one capsule spanning every opening (it would collide with any
object between them), so it stays contact-free and each finger gets a box pad inside it at every
opening (tested). With fitted geometry a finger capsule reaching past the plane the fingers meet in
is fitting slack there; its contacts go to a pad inscribed in it with one face on that plane
(`_FingerPads.past_closing_plane`).
"""

# mujoco ships compiled pybind11 modules without type stubs (see model.py)
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

from collections.abc import Collection
from typing import Any

import mujoco
import numpy as np

from armwarden.backends.mujoco.names import ENVELOPE_PREFIX, GRIPPER_ACTUATOR, GRIPPER_TENDON, HIDDEN_GROUP
from armwarden.core.errors import RobotModelError

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

def finger_joints(spec: mujoco.MjSpec, arm_joints: Collection[str]) -> list[str]:
    """Movable joints that are not arm joints: the gripper's fingers (prismatic, two or none)."""
    others = [joint for joint in spec.joints if joint.name not in arm_joints]
    if not others:
        return []
    if len(others) != 2 or any(joint.type != mujoco.mjtJoint.mjJNT_SLIDE for joint in others):
        raise RobotModelError(
            "the MuJoCo backend supports a gripper of exactly two prismatic fingers besides the arm "
            f"joints; the description also has {[joint.name for joint in others]}"
        )
    return [joint.name for joint in others]


def add_gripper(spec: mujoco.MjSpec, fingers: list[str], *, force_limit_n: float, fitted: bool,
                contact_geoms: dict[str, str]) -> None:
    """Couple the fingers, actuate their summed opening (the width) with at most `force_limit_n`,
    give each a contact pad (`fitted`: the envelope's bodies are fitted capsules). Records in
    `contact_geoms` which pad takes an envelope body's contacts."""
    if not any(eq.type == mujoco.mjtEq.mjEQ_JOINT for eq in spec.equalities):
        # a URDF <mimic> already couples them; otherwise the fingers move symmetrically by constraint
        spec.add_equality(type=mujoco.mjtEq.mjEQ_JOINT, name1=fingers[1], name2=fingers[0])
    tendon = spec.add_tendon(name=GRIPPER_TENDON)
    for name in fingers:
        tendon.wrap_joint(name, 1.0)
    low = sum(float(spec.joint(name).range[0]) for name in fingers)
    high = sum(float(spec.joint(name).range[1]) for name in fingers)
    actuator = spec.add_actuator(name=GRIPPER_ACTUATOR, target=GRIPPER_TENDON, trntype=mujoco.mjtTrn.mjTRN_TENDON)
    # 2 kN/m: a 70 N grasp presses the target 35 mm into the object; critically damped
    actuator.set_to_position(kp=2000.0, dampratio=1.0)
    actuator.ctrlrange = [low, high]
    actuator.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
    actuator.forcerange = [-force_limit_n, force_limit_n]
    actuator.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
    bodies = [spec.joint(name).parent.name for name in fingers]
    spec.add_exclude(bodyname1=bodies[0], bodyname2=bodies[1])  # fingers meet when closed
    pads = _FingerPads(spec, contact_geoms)
    if not fitted:
        for name in fingers:
            joint = spec.joint(name)
            axis = np.asarray(joint.axis, dtype=float)
            # inner face on the finger's closing side, 8 mm thick outward, 24 mm tall around the TCP height
            joint.parent.add_geom(name=f"pad/{joint.parent.name}", type=mujoco.mjtGeom.mjGEOM_BOX,
                                  pos=axis * PAD_HALF_SIZE_M[1] + np.array([0.0, 0.0, PAD_CENTER_Z_M]),
                                  size=list(PAD_HALF_SIZE_M), **PAD_GEOM)
        pads.disable_finger_envelope(bodies)
    else:
        for name in fingers:
            pads.past_closing_plane(name, pads.closing_plane_offset(fingers, name))


class _FingerPads:
    """Pads on the fingers of `spec`; `contact_geoms` maps an envelope body to the geom that makes its contacts."""

    def __init__(self, spec: mujoco.MjSpec, contact_geoms: dict[str, str]) -> None:
        self.spec = spec
        self.contact_geoms = contact_geoms

    def closing_plane_offset(self, fingers: list[str], finger: str) -> float:
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

    def past_closing_plane(self, finger: str, offset: float) -> None:
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

    def disable_finger_envelope(self, finger_bodies: list[str]) -> None:
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

__all__ = ["PAD_HALF_SIZE_M", "add_gripper", "capsule_contains", "finger_joints", "finger_pad_corners"]
