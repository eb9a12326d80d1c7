"""Forward kinematics at compiled speed, for one configuration or a batch, derived from the model.

The envelope needs the poses of every collision-carrying link and of the TCP at dozens to
hundreds of samples per motion. Pinocchio has no batched call from Python: one
`forwardKinematics` plus the reads of the placements costs microseconds per sample, most of it
crossing the bindings. This module reads the loaded Pinocchio model once into a compact chain
description (`KinematicChain`) and evaluates it with numba-compiled kernels over float64 arrays.

Nothing here is specific to a robot: for each joint the chain holds its parent, its fixed
placement in the parent joint's frame (`Model.jointPlacements`), its type and axis; for each
frame of interest its parent joint and placement (`Frame.placement`). The recursion is
Pinocchio's own, ``oMi[j] = oMi[parent[j]] · jointPlacement[j] · M_j(q)`` and
``oMf = oMi[parent] · placement``, so the result equals `data.oMi` / `data.oMf` to rounding
(tests/robot/test_batch_fk.py holds it to 1e-12 on random configurations, for the bundled FR3
and for generated arms with unaligned axes).

Supported joints: revolute about x, y, z or any unit axis (`JointModelRX/RY/RZ`,
`JointModelRevoluteUnaligned`) and prismatic alike (`JointModelPX/PY/PZ`,
`JointModelPrismaticUnaligned`). Anything else — free-flyer, planar, spherical, continuous
(two configuration values), helical, mimic, composite — is refused with the joint's name
(`RobotModelError`) rather than approximated.

**Compilation.** The kernels are compiled eagerly (explicit signatures) when this module is
imported, with numba's on-disk cache (`cache=True`, in `__pycache__` beside this file, else
numba's user cache directory): the first import on a machine compiles (1.5–2 s on the project's
machine, more under load), later imports load the machine code (tens of milliseconds, beside
the 0.4 s that importing numba itself costs). Pay it at start-up, never inside a check. Where no cache directory is
writable (a read-only install and an unwritable home, a full disk), numba cannot cache; the
kernels are then compiled in memory at every start-up instead and a warning says so on stderr
— FK still works, only the start-up is slower. Set `NUMBA_CACHE_DIR` to choose the cache
directory.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numba
import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.core.errors import RobotModelError
from armwarden.robot.jit_compile import compile_cached

if TYPE_CHECKING:
    from armwarden.robot.model import RobotModel

__all__ = ["BatchFK", "JointKind", "KinematicChain", "fk_batch_into", "fk_into", "kernels_cached"]

log = logging.getLogger(__name__)


class JointKind:
    """Joint type codes of `KinematicChain.kinds` (ints: the kernels branch on them)."""

    FIXED = 0  # no motion: the universe (its placement is base_from_world) and the frames of interest
    REVOLUTE_X = 1
    REVOLUTE_Y = 2
    REVOLUTE_Z = 3
    REVOLUTE_AXIS = 4  # about `axes[j]`, a unit vector in the joint frame
    PRISMATIC = 5  # along `axes[j]`


#: Pinocchio's joint model short names → (kind, axis in the joint frame; None: read `.axis`)
_SUPPORTED: dict[str, tuple[int, tuple[float, float, float] | None]] = {
    "JointModelRX": (JointKind.REVOLUTE_X, (1.0, 0.0, 0.0)),
    "JointModelRY": (JointKind.REVOLUTE_Y, (0.0, 1.0, 0.0)),
    "JointModelRZ": (JointKind.REVOLUTE_Z, (0.0, 0.0, 1.0)),
    "JointModelRevoluteUnaligned": (JointKind.REVOLUTE_AXIS, None),
    "JointModelPX": (JointKind.PRISMATIC, (1.0, 0.0, 0.0)),
    "JointModelPY": (JointKind.PRISMATIC, (0.0, 1.0, 0.0)),
    "JointModelPZ": (JointKind.PRISMATIC, (0.0, 0.0, 1.0)),
    "JointModelPrismaticUnaligned": (JointKind.PRISMATIC, None),
}


@dataclass(frozen=True)
class KinematicChain:
    """What the kernels need of a Pinocchio model, as flat float64/int64 arrays.

    Index j is Pinocchio's joint id (0 is the universe); parents come before children, as in
    Pinocchio, so one pass in index order evaluates the tree. Poses are 4×4 homogeneous.
    """

    joint_names: tuple[str, ...]
    parents: np.ndarray  # (J,) int64; parents[0] = -1
    kinds: np.ndarray  # (J,) int64, `JointKind`
    q_index: np.ndarray  # (J,) int64: the joint's entry in q (-1 for the universe)
    placements: np.ndarray  # (J, 4, 4): jointPlacement; placements[0] = base_from_world
    axes: np.ndarray  # (J, 3): unit axis in the joint frame (zeros for the universe)
    frame_names: tuple[str, ...]
    frame_joints: np.ndarray  # (F,) int64: parent joint of each frame of interest
    frame_placements: np.ndarray  # (F, 4, 4): the frame in its parent joint's frame
    nq: int

    @classmethod
    def from_model(
        cls, model: pin.Model, frames: Sequence[str], base_from_world: pin.SE3 | None = None
    ) -> KinematicChain:
        """Read `model`'s joints and the named `frames`; refuse any joint type not supported.

        `base_from_world` (default identity) is applied to every pose, so that results come out
        in a base frame as `RobotModel`'s do.
        """
        n_joints = int(model.njoints)
        parents = np.full(n_joints, -1, dtype=np.int64)
        kinds = np.full(n_joints, JointKind.FIXED, dtype=np.int64)
        q_index = np.full(n_joints, -1, dtype=np.int64)
        placements = np.zeros((n_joints, 4, 4))
        axes = np.zeros((n_joints, 3))
        placements[0] = np.eye(4) if base_from_world is None else base_from_world.homogeneous
        for jid in range(1, n_joints):
            joint = model.joints[jid]
            shortname = joint.shortname()
            if shortname not in _SUPPORTED or joint.nq != 1 or joint.nv != 1:
                raise RobotModelError(
                    f"joint {model.names[jid]!r} is a {shortname} (nq={joint.nq}, nv={joint.nv}); batched forward "
                    f"kinematics supports only 1-DoF revolute and prismatic joints ({', '.join(sorted(_SUPPORTED))})"
                )
            kind, axis = _SUPPORTED[shortname]
            if axis is None:
                axis_array = np.asarray(joint.extract().axis, dtype=float)
                norm = float(np.linalg.norm(axis_array))
                if not np.isfinite(norm) or norm == 0.0:
                    raise RobotModelError(f"joint {model.names[jid]!r} has no usable axis {axis_array.tolist()}")
                # Pinocchio normalises the axis it is given; read back, it may differ by rounding only
                axis_array = axis_array / norm
            else:
                axis_array = np.array(axis)
            parent = int(model.parents[jid])
            if not 0 <= parent < jid:
                raise RobotModelError(f"joint {model.names[jid]!r} has parent {parent}, not an earlier joint")
            parents[jid] = parent
            kinds[jid] = kind
            q_index[jid] = int(joint.idx_q)
            placements[jid] = model.jointPlacements[jid].homogeneous
            axes[jid] = axis_array
        frame_ids = [_frame_id(model, name) for name in frames]
        frame_joints = np.array([int(model.frames[f].parentJoint) for f in frame_ids], dtype=np.int64)
        frame_placements = np.array([model.frames[f].placement.homogeneous for f in frame_ids], dtype=float).reshape(-1, 4, 4)
        return cls(
            joint_names=tuple(model.names),
            parents=parents,
            kinds=kinds,
            q_index=q_index,
            placements=placements,
            axes=axes,
            frame_names=tuple(frames),
            frame_joints=frame_joints,
            frame_placements=frame_placements,
            nq=int(model.nq),
        )

    def node_tables(self) -> tuple[np.ndarray, np.ndarray]:
        """The kernels' input: joints then frames as nodes. `node_ints` (K, 3): parent node
        (-1 for the universe), kind, index into q (-1: none). `node_floats` (K, 15): the
        placement's rows [R | t] flattened (12), then the unit axis (3)."""
        n_frames = len(self.frame_names)
        node_ints = np.concatenate(
            [
                np.stack([self.parents, self.kinds, self.q_index], axis=1),
                np.stack([self.frame_joints, np.full(n_frames, JointKind.FIXED), np.full(n_frames, -1)], axis=1),
            ]
        ).astype(np.int64)
        placements = np.concatenate([self.placements, self.frame_placements])
        axes = np.concatenate([self.axes, np.zeros((n_frames, 3))])
        node_floats = np.concatenate([placements[:, :3, :].reshape(-1, 12), axes], axis=1)
        return np.ascontiguousarray(node_ints), np.ascontiguousarray(node_floats, dtype=np.float64)


def _frame_id(model: pin.Model, name: str) -> int:
    if not model.existFrame(name):
        valid = ", ".join(f.name for f in model.frames if f.name != "universe")
        raise RobotModelError(f"unknown frame {name!r}; valid frames: {valid}")
    return int(model.getFrameId(name))


# ---------------------------------------------------------------------------------------- kernels
# Plain Python functions, compiled below by `compile_cached`. The chain is flattened into "nodes": the
# joints (index = Pinocchio joint id) then the frames of interest (`KinematicChain.node_tables`).
# Node k's pose is its parent's pose · its fixed placement · its joint motion (none for a frame or
# the universe, whose parent is -1 and whose placement is base_from_world). Few arguments on
# purpose: numba's dispatcher costs about 0.1 µs per argument on every call from Python.


def _fk_into(q, node_ints, node_floats, out):  # pragma: no cover - compiled
    """One configuration: the pose of every node into `out` (K, 4, 4). False, with nothing
    written, when q holds a non-finite value."""
    for k in range(q.shape[0]):
        if not np.isfinite(q[k]):
            return False
    for k in range(node_ints.shape[0]):
        p = node_ints[k, 0]
        kind = node_ints[k, 1]
        m = node_floats[k]  # placement rows [R | t] flattened (12), then the axis (3)
        if p < 0:
            b00, b01, b02, t0 = m[0], m[1], m[2], m[3]
            b10, b11, b12, t1 = m[4], m[5], m[6], m[7]
            b20, b21, b22, t2 = m[8], m[9], m[10], m[11]
        else:
            # B = parent.R · M.R ; t = parent.R · M.t + parent.t
            a = out[p]
            b00 = a[0, 0] * m[0] + a[0, 1] * m[4] + a[0, 2] * m[8]
            b01 = a[0, 0] * m[1] + a[0, 1] * m[5] + a[0, 2] * m[9]
            b02 = a[0, 0] * m[2] + a[0, 1] * m[6] + a[0, 2] * m[10]
            b10 = a[1, 0] * m[0] + a[1, 1] * m[4] + a[1, 2] * m[8]
            b11 = a[1, 0] * m[1] + a[1, 1] * m[5] + a[1, 2] * m[9]
            b12 = a[1, 0] * m[2] + a[1, 1] * m[6] + a[1, 2] * m[10]
            b20 = a[2, 0] * m[0] + a[2, 1] * m[4] + a[2, 2] * m[8]
            b21 = a[2, 0] * m[1] + a[2, 1] * m[5] + a[2, 2] * m[9]
            b22 = a[2, 0] * m[2] + a[2, 1] * m[6] + a[2, 2] * m[10]
            t0 = a[0, 0] * m[3] + a[0, 1] * m[7] + a[0, 2] * m[11] + a[0, 3]
            t1 = a[1, 0] * m[3] + a[1, 1] * m[7] + a[1, 2] * m[11] + a[1, 3]
            t2 = a[2, 0] * m[3] + a[2, 1] * m[7] + a[2, 2] * m[11] + a[2, 3]
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = b00, b01, b02, b10, b11, b12, b20, b21, b22
        if kind == 5:  # prismatic: R = B, t += B · axis · q
            value = q[node_ints[k, 2]]
            ux = m[12] * value
            uy = m[13] * value
            uz = m[14] * value
            t0 += b00 * ux + b01 * uy + b02 * uz
            t1 += b10 * ux + b11 * uy + b12 * uz
            t2 += b20 * ux + b21 * uy + b22 * uz
        elif kind != 0:
            value = q[node_ints[k, 2]]
            c = np.cos(value)
            s = np.sin(value)
            if kind == 1:  # R = B · Rx(q): columns 1 and 2 turn
                r01, r11, r21 = c * b01 + s * b02, c * b11 + s * b12, c * b21 + s * b22
                r02, r12, r22 = c * b02 - s * b01, c * b12 - s * b11, c * b22 - s * b21
            elif kind == 2:  # R = B · Ry(q): columns 0 and 2 turn
                r00, r10, r20 = c * b00 - s * b02, c * b10 - s * b12, c * b20 - s * b22
                r02, r12, r22 = c * b02 + s * b00, c * b12 + s * b10, c * b22 + s * b20
            elif kind == 3:  # R = B · Rz(q): columns 0 and 1 turn
                r00, r10, r20 = c * b00 + s * b01, c * b10 + s * b11, c * b20 + s * b21
                r01, r11, r21 = c * b01 - s * b00, c * b11 - s * b10, c * b21 - s * b20
            else:  # R = B · E with E = Rodrigues(axis, q), as Pinocchio's toRotationMatrix
                ux = m[12]
                uy = m[13]
                uz = m[14]
                v = 1.0 - c
                e00 = c + v * ux * ux
                e11 = c + v * uy * uy
                e22 = c + v * uz * uz
                e01 = v * ux * uy - s * uz
                e10 = v * ux * uy + s * uz
                e02 = v * ux * uz + s * uy
                e20 = v * ux * uz - s * uy
                e12 = v * uy * uz - s * ux
                e21 = v * uy * uz + s * ux
                r00 = b00 * e00 + b01 * e10 + b02 * e20
                r01 = b00 * e01 + b01 * e11 + b02 * e21
                r02 = b00 * e02 + b01 * e12 + b02 * e22
                r10 = b10 * e00 + b11 * e10 + b12 * e20
                r11 = b10 * e01 + b11 * e11 + b12 * e21
                r12 = b10 * e02 + b11 * e12 + b12 * e22
                r20 = b20 * e00 + b21 * e10 + b22 * e20
                r21 = b20 * e01 + b21 * e11 + b22 * e21
                r22 = b20 * e02 + b21 * e12 + b22 * e22
        o = out[k]
        o[0, 0] = r00
        o[0, 1] = r01
        o[0, 2] = r02
        o[0, 3] = t0
        o[1, 0] = r10
        o[1, 1] = r11
        o[1, 2] = r12
        o[1, 3] = t1
        o[2, 0] = r20
        o[2, 1] = r21
        o[2, 2] = r22
        o[2, 3] = t2
        o[3, 0] = 0.0
        o[3, 1] = 0.0
        o[3, 2] = 0.0
        o[3, 3] = 1.0
    return True


def _fk_batch_into(qs, node_ints, node_floats, out):  # pragma: no cover - compiled
    """Every row of `qs` (N, nq) into `out` (N, K, 4, 4). Returns the index of the first row
    holding a non-finite value (rows from there on are not written), or -1."""
    for n in range(qs.shape[0]):
        if not fk_into(qs[n], node_ints, node_floats, out[n]):
            return n
    return -1


_SINGLE = numba.boolean(numba.float64[::1], numba.int64[:, ::1], numba.float64[:, ::1], numba.float64[:, :, ::1])
_BATCH = numba.int64(numba.float64[:, ::1], numba.int64[:, ::1], numba.float64[:, ::1], numba.float64[:, :, :, ::1])

#: compiled `_fk_into(q, node_ints, node_floats, out) -> bool`; callable from other numba kernels
fk_into, _single_cached = compile_cached(_fk_into, _SINGLE)
#: compiled `_fk_batch_into(qs, node_ints, node_floats, out) -> int`; callable from other numba kernels
fk_batch_into, _batch_cached = compile_cached(_fk_batch_into, _BATCH)


def kernels_cached() -> bool:
    """Whether the kernels use numba's on-disk cache (False: compiled in memory at start-up)."""
    return _single_cached and _batch_cached


def _kernel_array(values: Any) -> np.ndarray:
    """`values` as the kernels' signatures take it (C-contiguous, writable float64): itself when it
    is one already (the common case, checked in ~0.2 µs; `np.require` alone costs ~1.3 µs)."""
    if type(values) is np.ndarray and values.dtype == np.float64 and values.flags.c_contiguous and values.flags.writeable:
        return values
    return np.require(values, dtype=np.float64, requirements=["C", "W"])


class BatchFK:
    """Poses of the frames of interest (and of every joint) for one configuration or a batch.

    Built once per model; calls only read its tables, so one instance may be shared between
    threads (each call allocates its own output unless given one; the kernels release the GIL).
    Poses are 4×4 homogeneous, in the base frame (`KinematicChain.from_model`).
    """

    def __init__(self, chain: KinematicChain) -> None:
        self.chain = chain
        self.nq = chain.nq
        self.frame_names = chain.frame_names
        self.n_joints = len(chain.joint_names)
        self.n_frames = len(chain.frame_names)
        self.n_nodes = self.n_joints + self.n_frames
        self.node_ints, self.node_floats = chain.node_tables()

    @classmethod
    def from_model(cls, model: pin.Model, frames: Sequence[str], base_from_world: pin.SE3 | None = None) -> BatchFK:
        return cls(KinematicChain.from_model(model, frames, base_from_world))

    @classmethod
    def for_robot(cls, robot: RobotModel) -> BatchFK:
        """The frames the envelope checks: every moving link that carries collision geometry,
        then the TCP (last), in the robot's base frame like every `RobotModel` pose."""
        base = robot.model.frames[robot.frame_id(robot.base_frame)]
        base_from_world = None if base.placement.isIdentity() else base.placement.inverse()
        frames = [*robot.moving_links_with_geometry(), robot.tcp_frame]
        return cls.from_model(robot.model, frames, base_from_world)

    # ------------------------------------------------------------------ single configuration
    def poses(self, q: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """(K, 4, 4) poses of every node for configuration `q` (nq,): rows [0, J) the joints by
        Pinocchio id (0: the base itself), rows [J, K) the frames of interest in `frame_names`
        order. `out`, if given, must be a C-contiguous float64 (K, 4, 4) array; it is returned."""
        q = _kernel_array(q)
        if q.shape != (self.nq,):
            raise ValueError(f"a configuration has {self.nq} values; got shape {q.shape}")
        if out is None:
            out = np.empty((self.n_nodes, 4, 4))
        elif out.shape != (self.n_nodes, 4, 4):  # the kernels do not check bounds
            raise ValueError(f"out must have shape {(self.n_nodes, 4, 4)}; got {out.shape}")
        if not fk_into(q, self.node_ints, self.node_floats, out):
            raise ValueError(f"configuration holds a non-finite value: {q.tolist()}")
        return out

    def frame_poses(self, q: np.ndarray) -> np.ndarray:
        """(F, 4, 4) poses of the frames of interest, in `frame_names` order."""
        return self.poses(q)[self.n_joints:]

    def joint_poses(self, q: np.ndarray) -> np.ndarray:
        """(J, 4, 4) poses of every joint, indexed by Pinocchio joint id."""
        return self.poses(q)[: self.n_joints]

    # ------------------------------------------------------------------ batch
    def poses_batch(self, qs: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """(N, K, 4, 4): `poses` of each row of `qs` (N, nq)."""
        qs = _kernel_array(qs)
        if qs.ndim != 2 or qs.shape[1] != self.nq:
            raise ValueError(f"a batch of configurations has shape (N, {self.nq}); got {qs.shape}")
        if out is None:
            out = np.empty((qs.shape[0], self.n_nodes, 4, 4))
        elif out.shape != (qs.shape[0], self.n_nodes, 4, 4):  # the kernels do not check bounds
            raise ValueError(f"out must have shape {(qs.shape[0], self.n_nodes, 4, 4)}; got {out.shape}")
        bad = fk_batch_into(qs, self.node_ints, self.node_floats, out)
        if bad >= 0:
            raise ValueError(f"configuration {bad} of the batch holds a non-finite value: {qs[bad].tolist()}")
        return out

    def frame_poses_batch(self, qs: np.ndarray) -> np.ndarray:
        """(N, F, 4, 4) poses of the frames of interest for each row of `qs`."""
        return self.poses_batch(qs)[:, self.n_joints:]

    def joint_poses_batch(self, qs: np.ndarray) -> np.ndarray:
        """(N, J, 4, 4) poses of every joint for each row of `qs`."""
        return self.poses_batch(qs)[:, : self.n_joints]
