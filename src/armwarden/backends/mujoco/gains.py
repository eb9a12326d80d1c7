"""The arm actuators' gains in the MuJoCo model: each joint's rotor inertia (armature) and the
stiffness and damping of its position servo, sized from the arm's own joint-space inertia so that
each joint, alone with its inertia, has the same closed-loop bandwidth and damping ratio.
"""

# mujoco ships compiled pybind11 modules without type stubs (see model.py)
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np


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


__all__ = ["ArmGains", "default_armature", "joint_inertia"]
