"""The joint torques the fake FR3 cell's actuators "measure": Pinocchio's inverse dynamics of the
robot model the cell already moves, with contact forces and optional sensor noise.

`ArmDynamics.efforts` is τ in M(q)q̈ + C(q, q̇)q̇ + g(q) = τ + τ_ext (the `JointState.efforts`
contract): `pin.rnea(q, q̇, q̈)` minus Jᵀ F for every force F pushing at a point of a link (so an
arm at rest with nothing touching it reads g(q), and a push changes that by −Jᵀ F), plus seeded
Gaussian noise when asked. It owns a Pinocchio Data of its own (Data is not thread safe): one
`ArmDynamics` is used by one thread, the cell's clock thread.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.robot import RobotModel

#: a 3-vector: a force [N] or a point [m]
Vector3 = Sequence[float] | np.ndarray


@dataclass(frozen=True)
class Contact:
    """A force [N] in the robot's base frame at a point [m] given in a frame's own coordinates."""

    frame: str
    frame_id: int
    force_base: np.ndarray
    point_in_frame: np.ndarray


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


class ArmDynamics:
    """Inverse dynamics of `robot`'s arm (its policy joints; the locked joints' inertia merged)."""

    def __init__(self, robot: RobotModel, noise_nm: float = 0.0, seed: int = 0) -> None:
        if not np.isfinite(noise_nm) or noise_nm < 0.0:
            raise ValueError(f"torque noise must be a finite standard deviation >= 0 N·m, not {noise_nm}")
        self.model = robot.model
        self.data = robot.model.createData()
        self.noise_nm = noise_nm
        self._rng = np.random.default_rng(seed)
        self._base_id = robot.frame_id(robot.base_frame)
        self._tcp_id = robot.frame_id(robot.tcp_frame)
        self.tcp_frame = robot.tcp_frame

    def contact(self, frame: str, force_base: Vector3, point_in_frame: Vector3 = (0.0, 0.0, 0.0)) -> Contact:
        """A checked `Contact`: `frame` one of the model's frames, force and point finite 3-vectors."""
        if not self.model.existFrame(frame):
            names = ", ".join(f.name for f in self.model.frames)
            raise ValueError(f"no frame {frame!r} in the robot model (frames: {names})")
        force, point = np.array(force_base, dtype=float), np.array(point_in_frame, dtype=float)
        if force.shape != (3,) or point.shape != (3,) or not (np.all(np.isfinite(force)) and np.all(np.isfinite(point))):
            raise ValueError(f"a push needs a finite force [N] and point [m] of 3 values each, not {force_base}, "
                             f"{point_in_frame}")
        return Contact(frame, self.model.getFrameId(frame), force, point)

    def tcp_contact(self, force_base: Vector3) -> Contact:
        return self.contact(self.tcp_frame, force_base)

    def tcp_position(self, q: np.ndarray) -> np.ndarray:
        """The TCP's position [m] in the base frame."""
        pin.framesForwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        base, tcp = self.data.oMf[self._base_id], self.data.oMf[self._tcp_id]
        return (base.actInv(tcp)).translation.copy()

    def efforts(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, contacts: Sequence[Contact] = ()) -> np.ndarray:
        """τ for the motion (q, q̇, q̈) with `contacts` pushing on the arm, plus noise [N·m]."""
        q = np.asarray(q, dtype=float)
        tau = np.array(pin.rnea(self.model, self.data, q, np.asarray(qd, dtype=float), np.asarray(qdd, dtype=float)))
        if contacts:
            pin.computeJointJacobians(self.model, self.data, q)
            pin.updateFramePlacements(self.model, self.data)
            world_from_base = self.data.oMf[self._base_id].rotation
            for contact in contacts:
                tau -= self._point_jacobian(contact).T @ (world_from_base @ contact.force_base)
        if self.noise_nm > 0.0:
            tau += self._rng.normal(0.0, self.noise_nm, tau.shape)
        return tau

    def _point_jacobian(self, contact: Contact) -> np.ndarray:
        """3×nv: the world velocity of the contact point (after `computeJointJacobians`)."""
        jac = pin.getFrameJacobian(self.model, self.data, contact.frame_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        lever = self.data.oMf[contact.frame_id].rotation @ contact.point_in_frame  # frame origin -> point, world axes
        return jac[:3] - _skew(lever) @ jac[3:]


__all__ = ["ArmDynamics", "Contact", "Vector3"]
