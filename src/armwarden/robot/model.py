"""RobotModel: the robot description loaded with Pinocchio, reduced to the policy's joints.

It owns one Pinocchio `Model`/`Data` pair (allocated once, reused on every call; not thread
safe — the caller serialises access) and answers the kinematic questions the planners and the
envelope ask: TCP and frame poses, Jacobians, and the placement of every collision capsule for
a batch of configurations. All positions it returns are in the policy's base frame.

No forward kinematics is written here by hand: every pose comes from Pinocchio.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.core.errors import RobotModelError
from armwarden.robot.capsules import checked_capsules, moving_links, neighbour_rule_pairs, urdf_capsules
from armwarden.robot.description_files import load_description
from armwarden.robot.fitted_bodies import fitted_capsules, fitted_pairs
from armwarden.robot.fitted_file import FittedGeometry, FittingError, load_fitted
from armwarden.robots import BUILTIN_PREFIX, RobotProfile, load_profile

#: `robot.collision_geometry` values that are not a file
COLLISION_AUTO = "auto"
COLLISION_URDF = "urdf"


def _builtin_profile(value: str, what: str) -> RobotProfile | None:
    """The profile `builtin:<name>` names (None for a file path)."""
    if not value.startswith(BUILTIN_PREFIX):
        return None
    try:
        return load_profile(value[len(BUILTIN_PREFIX):])
    except RobotModelError as exc:
        raise RobotModelError(f"unknown built-in {what} {value!r}: {exc}") from exc


def _readable_file(value: str, what: str) -> Path:
    path = Path(value).expanduser()
    if not path.is_file():
        raise RobotModelError(f"{what} {value!r} is not a readable file")
    return path


def resolve_description(description: str) -> Path:
    """Path of the URDF named by `robot.description` (`builtin:<name>`: a shipped robot's, or a file path)."""
    profile = _builtin_profile(description, "robot description")
    return profile.file(profile.description) if profile is not None else _readable_file(description, "robot description")


def resolve_collision_geometry(collision_geometry: str, description: str) -> FittedGeometry | None:
    """The fitted collision geometry `robot.collision_geometry` names, or None for the URDF's own
    collision primitives (each turned into one capsule).

    `auto`: the fitted file of a shipped robot's description, else the URDF's primitives;
    `urdf`: the URDF's primitives; `builtin:<name>`: a shipped robot's fitted file; else a file path."""
    if collision_geometry == COLLISION_URDF:
        return None
    if collision_geometry == COLLISION_AUTO:
        profile = _builtin_profile(description, "robot description")
        if profile is None or profile.collision_geometry is None:
            return None
        path = profile.file(profile.collision_geometry)
    else:
        profile = _builtin_profile(collision_geometry, "collision geometry")
        if profile is None:
            path = _readable_file(collision_geometry, "collision geometry")
        elif profile.collision_geometry is None:
            raise RobotModelError(f"the built-in robot {profile.name!r} ships no fitted collision geometry; "
                                  f"use {COLLISION_AUTO} or {COLLISION_URDF}")
        else:
            path = profile.file(profile.collision_geometry)
    try:
        return load_fitted(path)
    except FittingError as exc:
        raise RobotModelError(str(exc)) from exc


@dataclass(frozen=True)
class Pose:
    """A pose in the base frame: position [m] and rotation matrix."""

    position: np.ndarray
    rotation: np.ndarray

    @property
    def quaternion_xyzw(self) -> np.ndarray:
        return pin.Quaternion(self.rotation).coeffs().copy()

    def as_se3(self) -> pin.SE3:
        return pin.SE3(self.rotation, self.position)


class RobotModel:
    """Kinematics of the arm named by the policy (extra joints such as fingers are locked)."""

    def __init__(
        self,
        urdf_path: Path,
        joint_names: Sequence[str],
        base_frame: str,
        tcp_frame: str,
        locked_positions: dict[str, float] | None = None,
        check_links: Sequence[str] | None = None,
        fitted: FittedGeometry | None = None,
    ) -> None:
        # with fitted capsules the description's own collision shapes are never read: a policy with
        # fitted geometry needs no manufacturer's meshes at run time
        description = load_description(urdf_path, with_collision=fitted is None)
        full_model = description.model
        full_geometry = description.collision if description.collision is not None else pin.GeometryModel()

        names = list(full_model.names)
        unknown = [name for name in joint_names if name not in names]
        if unknown:
            movable = names[1:]
            raise RobotModelError(f"unknown joint(s) {unknown}; the description has {movable}")
        reference = pin.neutral(full_model)
        for name, value in (locked_positions or {}).items():
            if name not in names:
                raise RobotModelError(f"cannot lock unknown joint {name!r}")
            reference[full_model.joints[full_model.getJointId(name)].idx_q] = value
        to_lock = [jid for jid in range(1, full_model.njoints) if names[jid] not in joint_names]
        self.model, self.geometry = pin.buildReducedModel(full_model, full_geometry, to_lock, reference)
        self.data = self.model.createData()

        reduced_names = list(self.model.names)[1:]
        if reduced_names != list(joint_names):
            order = {n: i for i, n in enumerate(reduced_names)}
            raise RobotModelError(
                f"joint_names must follow the kinematic order of the description: {reduced_names} "
                f"(got {list(joint_names)}; positions {[order[n] for n in joint_names]})"
            )
        for jid in range(1, self.model.njoints):
            joint = self.model.joints[jid]
            if joint.nq != 1 or joint.nv != 1:
                raise RobotModelError(
                    f"joint {self.model.names[jid]!r} ({joint.shortname()}) is not a 1-DoF revolute or "
                    "prismatic joint; only those are supported"
                )
        self.joint_names: tuple[str, ...] = tuple(joint_names)
        self.nq = self.model.nq
        self.lower = self.model.lowerPositionLimit.copy()
        self.upper = self.model.upperPositionLimit.copy()

        self.base_frame = base_frame
        self.tcp_frame = tcp_frame
        self._base_from_world = self._fixed_frame_inverse(base_frame)
        self._tcp_frame_id = self._named_frame_id("TCP frame", tcp_frame)
        tcp = self.model.frames[self._tcp_frame_id]
        self._tcp_joint = int(tcp.parentJoint)
        self._tcp_in_joint = tcp.placement.translation.copy()

        self.fitted = fitted
        if fitted is None:
            candidates = urdf_capsules(self.model, self.geometry)
        else:
            candidates = fitted_capsules(full_model, self.model, fitted, reference)
        self.capsules = checked_capsules(candidates, check_links, self.link_names())
        self.self_collision_pairs = (
            fitted_pairs(self.capsules, fitted) if fitted is not None else neighbour_rule_pairs(self.capsules)
        )
        self._build_batch_tables()

    def set_position_limits(self, lower: np.ndarray, upper: np.ndarray) -> None:
        """Narrow the joint limits (from the policy); IK and planners respect these."""
        self.lower = np.array(lower, dtype=float)
        self.upper = np.array(upper, dtype=float)
        self.model.lowerPositionLimit = self.lower.copy()
        self.model.upperPositionLimit = self.upper.copy()

    # ------------------------------------------------------------------ construction helpers
    @classmethod
    def from_description(
        cls,
        description: str,
        joint_names: Sequence[str],
        base_frame: str,
        tcp_frame: str,
        check_links: Sequence[str] | None = None,
        collision_geometry: str = COLLISION_AUTO,
    ) -> RobotModel:
        fitted = resolve_collision_geometry(collision_geometry, description)
        return cls(resolve_description(description), joint_names, base_frame, tcp_frame, check_links=check_links,
                   fitted=fitted)

    def frame_id(self, frame: str) -> int:
        if not self.model.existFrame(frame):
            raise RobotModelError(f"unknown frame {frame!r}; valid frames: {', '.join(self.frame_names())}")
        return int(self.model.getFrameId(frame))

    def frame_names(self) -> list[str]:
        return [f.name for f in self.model.frames if f.name != "universe"]

    def link_names(self) -> list[str]:
        return [f.name for f in self.model.frames if f.type == pin.FrameType.BODY]

    def _named_frame_id(self, role: str, frame: str) -> int:
        """`frame_id`, its error saying which configured frame is unknown (`robot.base_frame` or
        `robot.tcp_frame`): the list of valid frames names joints too, so the message alone is ambiguous."""
        if not self.model.existFrame(frame):
            raise RobotModelError(f"{role} {frame!r} is unknown; valid frames: {', '.join(self.frame_names())}")
        return int(self.model.getFrameId(frame))

    def _moves_with(self, joint_id: int, moving_joint_id: int) -> bool:
        """Whether a body on joint `joint_id` moves with joint `moving_joint_id` (it is on its chain)."""
        while joint_id > 0:
            if joint_id == moving_joint_id:
                return True
            joint_id = int(self.model.parents[joint_id])
        return False

    def tcp_frame_candidates(self) -> list[str]:
        """Body and operational frames that move with the last driven joint: the valid TCP frames."""
        last = self.model.njoints - 1
        kinds = (pin.FrameType.BODY, pin.FrameType.OP_FRAME)
        return [f.name for f in self.model.frames if f.type in kinds and self._moves_with(int(f.parentJoint), last)]

    def require_tcp_beyond_last_joint(self) -> None:
        """Refuse a TCP frame that does not move with the last driven joint.

        The TCP path length is what `motion.max_cartesian_step_m` caps and pose targets refer to;
        a TCP on the base (or on an inner link) does not follow the tool, so the cap would measure
        nothing (a frame on the base never moves) and pose targets would not mean the tool."""
        last = self.model.njoints - 1
        if not self._moves_with(self._tcp_joint, last):
            raise RobotModelError(
                f"TCP frame {self.tcp_frame!r} does not move with the last joint {self.model.names[last]}, so the "
                "TCP path length cap (motion.max_cartesian_step_m) and pose targets would not follow the tool; "
                f"candidates: {', '.join(self.tcp_frame_candidates())}"
            )

    def _fixed_frame_inverse(self, frame: str) -> pin.SE3 | None:
        frame_id = self._named_frame_id("base frame", frame)
        placement = self.model.frames[frame_id]
        if placement.parentJoint != 0:
            raise RobotModelError(f"base frame {frame!r} must be fixed to the world (it moves with a joint)")
        pin.framesForwardKinematics(self.model, self.data, pin.neutral(self.model))
        world_from_base = self.data.oMf[frame_id]
        if world_from_base.isIdentity():
            return None
        return world_from_base.inverse()

    def moving_links_with_geometry(self) -> list[str]:
        """Links that move with a driven joint and carry collision capsules, in description order:
        the bodies the workspace and keep-out checks look at."""
        return moving_links(self.capsules)

    def _build_batch_tables(self) -> None:
        """Index tables so a batch of configurations maps to capsule end points in a few numpy ops."""
        joints = sorted({c.joint_index for c in self.capsules} | {self._tcp_joint})
        self._joint_refs = [self.data.oMi[j] for j in joints]  # live references into Data
        slot = {j: k for k, j in enumerate(joints)}
        self._capsule_slot = np.array([slot[c.joint_index] for c in self.capsules], dtype=np.intp)
        self._capsule_p0 = np.array([c.p0_m for c in self.capsules], dtype=float).reshape(-1, 3)
        self._capsule_p1 = np.array([c.p1_m for c in self.capsules], dtype=float).reshape(-1, 3)
        self.capsule_radii = np.array([c.radius_m for c in self.capsules], dtype=float)
        self._tcp_slot = slot[self._tcp_joint]
        # homogeneous local points: every capsule's p0 then the TCP, then every capsule's p1 then the TCP
        slots = np.concatenate([self._capsule_slot, [self._tcp_slot]])
        self._point_slot = np.concatenate([slots, slots])
        p0 = np.vstack([self._capsule_p0, self._tcp_in_joint[None]])
        p1 = np.vstack([self._capsule_p1, self._tcp_in_joint[None]])
        self._points_h = np.hstack([np.vstack([p0, p1]), np.ones((2 * len(slots), 1))])
        self._point_index = np.arange(len(self._point_slot))
        self.reach = self._compute_reach()

    def _compute_reach(self) -> np.ndarray:
        """`reach[i, b]`: bound on how far a point of body b moves per unit motion of joint i.

        Body index `len(capsules)` is the TCP point. For a revolute joint i the bound is the
        largest distance from joint i's origin to the body over all configurations: the sum of
        the joint-to-joint offsets along the chain plus the body's farthest end point. For a
        prismatic joint it is 1 (metres per metre). Zero when the body is not distal to joint i.
        """
        model = self.model
        n_bodies = len(self.capsules) + 1
        reach = np.zeros((self.nq, n_bodies))
        # points per body, in their joint frame
        body_points = [(c.joint_index, [np.array(c.p0_m), np.array(c.p1_m)]) for c in self.capsules]
        body_points.append((self._tcp_joint, [self._tcp_in_joint]))
        for b, (joint, points) in enumerate(body_points):
            far = max(float(np.linalg.norm(p)) for p in points)
            chain = []
            j = joint
            while j > 0:
                chain.append(j)
                j = model.parents[j]
            # chain: [joint, parent, ..., first]; offsets accumulate from the body back to joint i
            offset_sum = 0.0
            for k, jid in enumerate(chain):
                if k > 0:
                    offset_sum += float(np.linalg.norm(model.jointPlacements[chain[k - 1]].translation))
                idx = model.joints[jid].idx_q
                shortname = model.joints[jid].shortname()
                if "JointModelP" in shortname:
                    reach[idx, b] = 1.0
                else:
                    reach[idx, b] = offset_sum + far
        return reach

    # ------------------------------------------------------------------ single-configuration queries
    def _to_base(self, placement: pin.SE3) -> pin.SE3:
        return placement if self._base_from_world is None else self._base_from_world * placement

    def frame_pose(self, q: np.ndarray, frame: str) -> Pose:
        return self._frame_pose(q, self.frame_id(frame))

    def _frame_pose(self, q: np.ndarray, frame_id: int) -> Pose:
        pin.forwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        placement = self._to_base(pin.updateFramePlacement(self.model, self.data, frame_id))
        return Pose(placement.translation.copy(), placement.rotation.copy())

    def tcp_pose(self, q: np.ndarray) -> Pose:
        return self._frame_pose(q, self._tcp_frame_id)  # the id looked up once: every state poll asks

    def tcp_jacobian(self, q: np.ndarray) -> np.ndarray:
        """6×nq Jacobian of the TCP, linear part first, in the world-aligned TCP frame."""
        q = np.asarray(q, dtype=float)
        jac = pin.computeFrameJacobian(
            self.model, self.data, q, self._tcp_frame_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        )
        if self._base_from_world is not None:
            rot = self._base_from_world.rotation
            jac = np.vstack([rot @ jac[:3], rot @ jac[3:]])
        return jac

    def tcp_pose_and_jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """TCP position, rotation and 6×nq world-aligned Jacobian from one kinematics pass (IK's inner loop)."""
        model, data = self.model, self.data
        pin.computeJointJacobians(model, data, q)
        placement = pin.updateFramePlacement(model, data, self._tcp_frame_id)
        jac = pin.getFrameJacobian(model, data, self._tcp_frame_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        if self._base_from_world is not None:
            placement = self._base_from_world * placement
            rot = self._base_from_world.rotation
            jac = np.vstack([rot @ jac[:3], rot @ jac[3:]])
        return placement.translation.copy(), placement.rotation.copy(), jac

    def within_limits(self, q: np.ndarray, margin_rad: float = 0.0) -> bool:
        q = np.asarray(q, dtype=float)
        return bool(np.all(q >= self.lower + margin_rad) and np.all(q <= self.upper - margin_rad))

    # ------------------------------------------------------------------ batch queries (the envelope's hot path)
    def joint_frames(self, qs: np.ndarray) -> np.ndarray:
        """Homogeneous placements (N, J, 4, 4) of the joints that carry capsules or the TCP."""
        return self._placements(qs, self._joint_refs)

    def tcp_points(self, qs: np.ndarray) -> np.ndarray:
        """TCP positions (N, 3) of a batch of configurations, base frame, metres: `body_points`'
        TCP alone, reading one joint placement per configuration instead of every body's."""
        placements = self._placements(qs, self._joint_refs[self._tcp_slot:self._tcp_slot + 1])[:, 0]
        return placements[:, :3, :3] @ self._tcp_in_joint + placements[:, :3, 3]

    def _placements(self, qs: np.ndarray, refs: Sequence[pin.SE3]) -> np.ndarray:
        """Homogeneous placements (N, len(refs), 4, 4), base frame, of the joints `refs` (live
        references into Data) after forward kinematics of each configuration in `qs`."""
        model, data = self.model, self.data
        forward = pin.forwardKinematics
        frames = []
        append = frames.append
        for q in qs:
            forward(model, data, q)
            for ref in refs:
                append(ref.np)  # the 4×4 homogeneous matrix; the cheapest read pinocchio offers
        out = np.array(frames).reshape(len(qs), len(refs), 4, 4)
        if self._base_from_world is not None:
            out = np.einsum("ij,nkjl->nkil", self._base_from_world.homogeneous, out)
        return out

    def body_points(self, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Segment end points (N, B+1, 3) of every capsule plus the TCP (last, as a point).

        One batched matrix product from the `joint_frames` output; base frame, metres.
        """
        # every point through every joint's transform (one BLAS call), then keep each point's own joint
        through_all = np.tensordot(frames[:, :, :3, :], self._points_h, axes=([3], [1]))  # (N, J, 3, P)
        world = through_all[:, self._point_slot, :, self._point_index].transpose(1, 0, 2)  # (N, P, 3)
        n_bodies = len(self.capsules) + 1
        return world[:, :n_bodies], world[:, n_bodies:]

