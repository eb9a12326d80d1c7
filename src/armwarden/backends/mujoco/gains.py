"""The arm actuators' gains in the MuJoCo model: each joint's rotor inertia (armature), from the
robot profile's `actuators` (or a generic rule by drive size), and the stiffness and damping of its
position servo, sized from the arm's own joint-space inertia so that each joint, alone with its
inertia, has the same closed-loop bandwidth and damping ratio.
"""

# mujoco ships compiled pybind11 modules without type stubs (see model.py)
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from armwarden.core.errors import RobotModelError
from armwarden.robots import RobotProfile


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


def generic_armature(efforts_nm: Sequence[float]) -> tuple[float, ...]:
    """Reflected rotor inertia [kg·m²] by drive size, for a robot whose profile gives none: 0.1
    for a drive of at least 50 N·m, else 0.05 (the FR3's drives, as the nearest known arm). It
    also keeps light distal joints stiff enough to simulate at 1 kHz."""
    return tuple(0.1 if effort >= 50.0 else 0.05 for effort in efforts_nm)


def armature_from_profile(profile: RobotProfile | None, joint_names: Sequence[str]) -> tuple[float, ...] | None:
    """Each arm joint's armature [kg·m²] from the robot profile's `actuators`, in `joint_names`'
    order; None without a profile or without that section (the generic rule then applies).
    Refuses a profile that leaves out one of the arm's joints: a guessed drive is not a simulated one."""
    if profile is None or profile.actuators is None:
        return None
    missing = [joint for joint in joint_names if joint not in profile.actuators]
    if missing:
        raise RobotModelError(f"no actuator for the arm joints {', '.join(missing)} in the robot profile "
                              f"{profile.name!r} (it lists {', '.join(profile.actuators)})")
    return tuple(profile.actuators[joint].armature_kg_m2 for joint in joint_names)


def joint_inertia(model: mujoco.MjModel, arm_qpos: np.ndarray, arm_dofs: np.ndarray, q: np.ndarray) -> np.ndarray:
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


__all__ = ["ArmGains", "armature_from_profile", "generic_armature", "joint_inertia"]
