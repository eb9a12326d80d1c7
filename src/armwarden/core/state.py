"""What the arm measured: joint state, gripper state, the external wrench at the TCP and frame
transforms, as the backends report them and every layer above reads them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class JointState:
    """Measured joint positions [rad] and velocities [rad/s]; `stamp` on the monotonic clock [s].

    `efforts`: the joint torques [N·m] the actuators measured (a motor's torque or current), in the
    joint's positive direction, gravity included — what Pinocchio calls τ in
    M(q)q̈ + C(q, q̇)q̇ + g(q) = τ + τ_ext. None when the arm does not measure them; measured in the
    same sample as the positions (one stamp for both)."""

    names: tuple[str, ...]
    positions: np.ndarray
    velocities: np.ndarray
    stamp: float
    efforts: np.ndarray | None = None


@dataclass(frozen=True)
class Wrench:
    """Estimated external wrench at the TCP in the base frame: force [N], torque [N·m]."""

    force: np.ndarray
    torque: np.ndarray
    stamp: float

    @property
    def force_norm_n(self) -> float:
        return float(np.linalg.norm(self.force))

    @property
    def torque_norm_nm(self) -> float:
        return float(np.linalg.norm(self.torque))


@dataclass(frozen=True)
class GripperState:
    width_m: float
    is_grasped: bool
    moving: bool
    stamp: float


@dataclass(frozen=True)
class Transform:
    """Pose of a source frame in a target frame, from the backend's own frame tree (ROS tf):
    translation [m], rotation as a unit quaternion (x, y, z, w); `stamp` on the monotonic clock [s]."""

    translation: np.ndarray
    rotation_xyzw: np.ndarray
    stamp: float
