"""External joint torques from measured joint torques: a generalized-momentum observer.

Why this observer (De Luca et al. 2006; Haddadin, De Luca, Albu-Schäffer, T-RO 2017): it needs
positions, velocities and the motors' torques, never accelerations (which a bus does not report
and differencing velocities would make mostly noise), and its output is a first-order low-pass
of the true external torque per joint — decoupled, with one bandwidth K the policy sets.

With the arm's momentum p = M(q)q̇, the dynamics M q̈ + C q̇ + g + τ_f = τ + τ_ext give
ṗ = τ + Cᵀq̇ − g − τ_f + τ_ext. Over one sample interval h the mean external torque is therefore
(p₁ − p₀)/h − ½(β₀ + β₁) with β = τ + Cᵀq̇ − g − τ_f, and the residual r follows it as
ṙ = K(τ_ext − r). Updating r with the exact solution of that filter for the interval
(r₁ = αr₀ + (1 − α)·mean, α = e^(−Kh)) keeps the observer right for any sample spacing: the
monitor polls on an event loop, so intervals are irregular, and a forward-Euler step would be
unstable once Kh > 2.

The rotor inertia reflected at each joint (armature) is in the mass matrix: a drive spends
torque accelerating its rotor, and without it every acceleration would read as a contact.
τ_f, the joint friction the policy allows for, is Coulomb (smoothed through tanh so a joint at
rest is not flipped between ±c by velocity noise) plus viscous. A payload the policy declares is
added to the model as a point mass at the TCP, so its weight is not a contact.

The first sample starts the residual at the quasi-static estimate g + Cq̇ + τ_f − τ, so a contact
that exists before the motion (the arm resting on a surface) shows at once, not after 1/K.

The model is the loaded robot's Pinocchio model (copied: the observer owns its Model and Data and
is used from one thread). No dynamics is written here by hand.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.core.errors import ConfigurationError

__all__ = ["ContactObserver", "ObserverSettings", "TcpWrenchEstimate", "tcp_wrench_from_joint_torques"]

#: joint speed [rad/s] over which the Coulomb friction model reaches 76 % of its value (tanh(1))
COULOMB_SMOOTHING_RAD_S = 0.02
#: damping of the least-squares TCP wrench [N·m-ish]: matters only near a singularity
WRENCH_DAMPING = 1e-3


@dataclass(frozen=True)
class ObserverSettings:
    """The observer's bandwidth, friction allowance and payload, in SI units, joint order."""

    gain_per_s: float
    coulomb_nm: tuple[float, ...]
    viscous_nms: tuple[float, ...]
    payload_kg: float = 0.0
    payload_com_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: rotor inertia reflected at each joint [kg·m²] (empty: none)
    rotor_inertia_kgm2: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        numbers = (self.gain_per_s, *self.coulomb_nm, *self.viscous_nms, self.payload_kg, *self.payload_com_m,
                   *self.rotor_inertia_kgm2)
        if not all(math.isfinite(v) for v in numbers) or self.gain_per_s <= 0 or self.payload_kg < 0:
            raise ConfigurationError(f"invalid observer settings: {self}")
        if min(self.coulomb_nm + self.viscous_nms + self.rotor_inertia_kgm2, default=0.0) < 0:
            raise ConfigurationError("friction allowances and rotor inertias must not be negative")


@dataclass(frozen=True)
class TcpWrenchEstimate:
    """The TCP wrench that best explains a set of external joint torques, in the base frame.

    `condition` is σ_max/σ_min of the TCP Jacobian: large near a singularity, where a small
    torque error means a large force error (and for an arm with fewer than six joints, where
    some wrench directions cannot be seen at all)."""

    force_n: np.ndarray
    torque_nm: np.ndarray
    condition: float


class ContactObserver:
    """The momentum observer of one robot model (see the module docstring); one thread."""

    def __init__(self, model: pin.Model, tcp_frame: str, base_frame: str, settings: ObserverSettings) -> None:
        nv = model.nv
        if len(settings.coulomb_nm) != nv or len(settings.viscous_nms) != nv:
            raise ConfigurationError(f"friction allowances need {nv} values per model (one per joint)")
        if settings.rotor_inertia_kgm2 and len(settings.rotor_inertia_kgm2) != nv:
            raise ConfigurationError(f"rotor inertias need {nv} values (one per joint)")
        self.model = pin.Model(model)  # our own copy: the payload and the rotors are added to it
        if settings.rotor_inertia_kgm2:  # Pinocchio adds the armature to the mass matrix's diagonal
            self.model.armature = np.asarray(settings.rotor_inertia_kgm2, dtype=float)
        self._tcp = self.model.getFrameId(tcp_frame)
        if self._tcp >= len(self.model.frames):
            raise ConfigurationError(f"the robot model has no frame {tcp_frame!r}")
        if settings.payload_kg > 0:
            frame = self.model.frames[self._tcp]
            com_in_joint = frame.placement.act(np.asarray(settings.payload_com_m, dtype=float))
            joint = frame.parentJoint
            self.model.inertias[joint] = self.model.inertias[joint] + pin.Inertia(
                settings.payload_kg, com_in_joint, np.zeros((3, 3)))
        self.data = self.model.createData()
        base = self.model.getFrameId(base_frame)
        if base >= len(self.model.frames):
            raise ConfigurationError(f"the robot model has no frame {base_frame!r}")
        pin.framesForwardKinematics(self.model, self.data, pin.neutral(self.model))
        #: world → base rotation (the base frame is fixed: it does not depend on q)
        self._base_from_world = self.data.oMf[base].rotation.T.copy()
        self.settings = settings
        self._gain = settings.gain_per_s
        self._coulomb = np.asarray(settings.coulomb_nm, dtype=float)
        self._viscous = np.asarray(settings.viscous_nms, dtype=float)
        self._residual: np.ndarray | None = None
        self._momentum = np.zeros(nv)
        self._beta = np.zeros(nv)
        self._stamp = 0.0

    @property
    def started(self) -> bool:
        return self._residual is not None

    @property
    def residual(self) -> np.ndarray:
        """The latest external-torque estimate [N·m] per joint (zeros before the first sample)."""
        return np.zeros(self.model.nv) if self._residual is None else self._residual.copy()

    def friction(self, velocities: np.ndarray) -> np.ndarray:
        """The friction torque [N·m] the policy allows for at these joint speeds (opposing motion)."""
        return self._coulomb * np.tanh(velocities / COULOMB_SMOOTHING_RAD_S) + self._viscous * velocities

    def update(self, positions: np.ndarray, velocities: np.ndarray, torques: np.ndarray, stamp: float) -> np.ndarray:
        """Feed one measured sample (stamps in seconds, increasing); returns the residual [N·m].

        A sample whose stamp does not advance changes nothing (the same joint state read twice)."""
        q = np.asarray(positions, dtype=float)
        v = np.asarray(velocities, dtype=float)
        tau = np.asarray(torques, dtype=float)
        if not (q.shape == v.shape == tau.shape == (self.model.nv,)):
            raise ValueError(f"expected {self.model.nv} positions, velocities and torques")
        if self._residual is not None and stamp <= self._stamp:
            return self._residual.copy()
        model, data = self.model, self.data
        mass = pin.crba(model, data, q)
        mass = np.triu(mass) + np.triu(mass, 1).T  # crba fills the upper triangle only
        coriolis = pin.computeCoriolisMatrix(model, data, q, v)
        gravity = pin.computeGeneralizedGravity(model, data, q)
        friction = self.friction(v)
        momentum = mass @ v
        beta = tau + coriolis.T @ v - gravity - friction
        if self._residual is None:  # quasi-static start: what holds the arm besides its motors now
            residual = gravity + coriolis @ v + friction - tau
        else:
            h = stamp - self._stamp
            mean_external = (momentum - self._momentum) / h - 0.5 * (beta + self._beta)
            alpha = math.exp(-self._gain * h)
            residual = alpha * self._residual + (1.0 - alpha) * mean_external
        self._residual, self._momentum, self._beta, self._stamp = residual, momentum, beta, float(stamp)
        return residual.copy()

    def rebase(self, positions: np.ndarray, velocities: np.ndarray, torques: np.ndarray, stamp: float) -> np.ndarray:
        """Take this sample as the next interval's start without updating the residual: for an
        interval too long for its torques to be integrated from its two ends (see
        `JointTorqueContact`). Returns the residual, unchanged."""
        if self._residual is None:
            return self.update(positions, velocities, torques, stamp)
        q, v = np.asarray(positions, dtype=float), np.asarray(velocities, dtype=float)
        model, data = self.model, self.data
        mass = pin.crba(model, data, q)
        mass = np.triu(mass) + np.triu(mass, 1).T
        coriolis = pin.computeCoriolisMatrix(model, data, q, v)
        gravity = pin.computeGeneralizedGravity(model, data, q)
        self._momentum = mass @ v
        self._beta = np.asarray(torques, dtype=float) + coriolis.T @ v - gravity - self.friction(v)
        self._stamp = float(stamp)
        return self._residual.copy()

    def tcp_wrench(self, positions: np.ndarray, external_torques: np.ndarray) -> TcpWrenchEstimate:
        """The TCP wrench that best explains `external_torques` at `positions`."""
        return tcp_wrench_from_joint_torques(self.model, self.data, self._tcp, self._base_from_world,
                                             np.asarray(positions, dtype=float), np.asarray(external_torques, dtype=float))


def tcp_wrench_from_joint_torques(model: pin.Model, data: pin.Data, tcp_frame_id: int, base_from_world: np.ndarray,
                                  q: np.ndarray, external_torques: np.ndarray) -> TcpWrenchEstimate:
    """Solve Jᵀw = τ_ext for the wrench w at the TCP by damped least squares,
    w = (J Jᵀ + λ²I)⁻¹ J τ_ext, with J the TCP Jacobian in world-aligned axes; returned in the base frame."""
    jacobian = pin.computeFrameJacobian(model, data, q, tcp_frame_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    gram = jacobian @ jacobian.T + WRENCH_DAMPING ** 2 * np.eye(6)
    wrench = np.linalg.solve(gram, jacobian @ external_torques)
    singular = np.linalg.svd(jacobian, compute_uv=False)
    rank_deficient = jacobian.shape[1] < 6 or singular[-1] <= 1e-12
    condition = math.inf if rank_deficient else float(singular[0] / singular[-1])
    return TcpWrenchEstimate(base_from_world @ wrench[:3], base_from_world @ wrench[3:], condition)
