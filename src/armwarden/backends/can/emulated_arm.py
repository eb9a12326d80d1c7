"""The emulated arm behind the emulated actuators: one rigid body tree moved by the robot model's
forward dynamics (Pinocchio ABA), so the torques the actuators report are the arm's.

Why Pinocchio and not MuJoCo: it runs in the emulator's own thread with no scene file, on exactly
the kinematic tree the policy loads. Its weakness is that the contact observer uses the same model,
so an emulation that matched it exactly would test the observer against itself; the model error
is therefore put in on purpose (all seeded, so a run is reproducible): every body's mass and
inertia perturbed by a few percent (`mass_error`), an undeclared payload, Coulomb and viscous
joint friction, rotor inertia (armature) per joint, and Gaussian noise on the reported torque.

Holding brakes (`brakes`, on by default): while any of the arm's actuators is disabled (before
start-up enables them, after a CAN timeout or a stop frame) or commanded kp = 0 (the backend's
damping mode: a fault, an e-stop) the body is held still, as a cobot's brakes hold it in a safe
stop. Without them (`brakes: false`) the arm falls in damping mode against kd only, as an arm of
brakeless actuators does: the FR3's joint 4 carries ~18 N·m of gravity, which no damping holds.

Each step (semi-implicit Euler at the emulator rate, in simulated time = wall time × time_scale):
every actuator's impedance law gives its motor torque (raw units, zero while disabled or timed out),
converted to joint units by its direction; q̈ = aba(q, q̇, τ_motor − τ_friction + τ_ext), with
τ_ext = Jᵀ F of the current push. The reported torque is the motor torque plus noise (what the
actuator measures), quantised by the protocol when it is encoded.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.backends.can.emulated_actuator import MAX_CATCH_UP_STEPS, EmulatedActuator


@dataclass(frozen=True)
class ArmDynamics:
    """The emulated body's parameters beyond the robot model, per joint in the model's joint order.

    `armature_kgm2` rotor inertia, `viscous_nms` and `coulomb_nm` friction, `torque_noise_nm` the
    standard deviation of the reported torque's noise, `mass_error` the relative standard deviation
    of each body's mass/inertia scale (clipped to ±3σ), `payload_kg` at `payload_com_m` in the
    `payload_frame`'s coordinates, `seed` for every random draw.
    """

    armature_kgm2: tuple[float, ...]
    viscous_nms: tuple[float, ...]
    coulomb_nm: tuple[float, ...]
    torque_noise_nm: float = 0.0
    mass_error: float = 0.0
    payload_kg: float = 0.0
    payload_com_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    payload_frame: str | None = None
    seed: int = 0
    #: holding brakes: the body is held while any actuator is disabled or commanded kp = 0 (damping)
    brakes: bool = True
    #: the velocity [rad/s] over which Coulomb friction rises to its full value (a smooth sign: no chatter at rest)
    coulomb_smoothing_rad_s: float = field(default=0.01)


def perturbed_model(model: pin.Model, dynamics: ArmDynamics, rng: np.random.Generator) -> pin.Model:
    """A copy of `model` with every body's inertia scaled by 1 + N(0, mass_error) (clipped at ±3σ),
    the payload added to the body of `payload_frame`, and the armature set."""
    body = model.copy()
    for jid in range(1, body.njoints):
        scale = 1.0 + float(np.clip(rng.normal(0.0, dynamics.mass_error), -3 * dynamics.mass_error, 3 * dynamics.mass_error)) \
            if dynamics.mass_error > 0 else 1.0
        inertia = body.inertias[jid]
        body.inertias[jid] = pin.Inertia(inertia.mass * scale, inertia.lever.copy(), inertia.inertia * scale)
    if dynamics.payload_kg > 0:
        if dynamics.payload_frame is None:
            raise ValueError("a payload needs the frame its centre of mass is given in")
        frame = body.frames[body.getFrameId(dynamics.payload_frame)]
        com = frame.placement.act(np.asarray(dynamics.payload_com_m, dtype=float))
        body.inertias[frame.parentJoint] += pin.Inertia(dynamics.payload_kg, com, np.zeros((3, 3)))
    body.armature = np.asarray(dynamics.armature_kgm2, dtype=float)
    return body


class EmulatedArm:
    """The arm's joints as one body (see the module docstring); guarded by the emulator's lock
    except `push`/`release_push`/`true_external_torques`, which take their own."""

    def __init__(self, model: pin.Model, actuators: Sequence[EmulatedActuator], direction: Sequence[float],
                 offset: Sequence[float], dynamics: ArmDynamics, *, dt: float, time_scale: float, now: float) -> None:
        if len(actuators) != model.nv:
            raise ValueError(f"the emulated arm has {model.nv} joints but {len(actuators)} actuators")
        for name in ("armature_kgm2", "viscous_nms", "coulomb_nm"):
            if len(getattr(dynamics, name)) != model.nv:
                raise ValueError(f"{name} needs one value per joint ({model.nv})")
        self._rng = np.random.default_rng(dynamics.seed)
        self.model = perturbed_model(model, dynamics, self._rng)
        self.data = self.model.createData()
        self.actuators = list(actuators)
        self.direction = np.asarray(direction, dtype=float)
        self.offset = np.asarray(offset, dtype=float)
        self.dynamics = dynamics
        self._viscous = np.asarray(dynamics.viscous_nms, dtype=float)
        self._coulomb = np.asarray(dynamics.coulomb_nm, dtype=float)
        self.dt = dt  # simulated seconds per step
        self.time_scale = time_scale
        raw = np.array([a.position for a in self.actuators], dtype=float)
        self.q = self.direction * (raw - self.offset)
        self.v = np.zeros(model.nv)
        self.wall_time = now
        self.sim_time = 0.0
        self.steps = 0
        self._push_lock = threading.Lock()
        self._push: tuple[int, np.ndarray, np.ndarray] | None = None  # frame id, force [N] base, point in frame
        self._tau_ext = np.zeros(model.nv)
        for a in self.actuators:
            a.sim_time = now

    # ---------------------------------------------------------------- push
    def push(self, frame: str, force_base: Sequence[float], point: Sequence[float] = (0.0, 0.0, 0.0)) -> None:
        """Apply `force_base` [N] (base frame) at `point` [m] (in `frame`'s coordinates) from now on."""
        if not self.model.existFrame(frame):
            raise KeyError(f"the emulated arm has no frame {frame!r}")
        force = np.asarray(force_base, dtype=float).reshape(3)
        where = np.asarray(point, dtype=float).reshape(3)
        if not (np.all(np.isfinite(force)) and np.all(np.isfinite(where))):
            raise ValueError("a push needs a finite force and point")
        with self._push_lock:
            self._push = (self.model.getFrameId(frame), force, where)

    def release_push(self) -> None:
        with self._push_lock:
            self._push = None
            self._tau_ext = np.zeros(self.model.nv)

    def true_external_torques(self) -> np.ndarray:
        """τ_ext [N·m] the push applied at the last step, in joint coordinates (zeros: none)."""
        with self._push_lock:
            return self._tau_ext.copy()

    def _external(self) -> np.ndarray:
        with self._push_lock:
            push = self._push
        if push is None:
            return np.zeros(self.model.nv)
        fid, force, point = push
        jacobian = pin.computeFrameJacobian(self.model, self.data, self.q, fid, pin.LOCAL_WORLD_ALIGNED)
        rotation = self.data.oMf[fid].rotation
        moment = np.cross(rotation @ point, force)  # the point's offset from the frame origin, base axes
        tau = jacobian[:3].T @ force + jacobian[3:].T @ moment
        with self._push_lock:
            if self._push is push:
                self._tau_ext = tau
        return tau

    # ---------------------------------------------------------------- time
    def advance(self, now: float) -> None:
        """Integrate up to wall time `now`; a backlog beyond `MAX_CATCH_UP_STEPS` is dropped."""
        wall_step = self.dt / self.time_scale
        steps = 0
        while self.wall_time + wall_step <= now and steps < MAX_CATCH_UP_STEPS:
            self.wall_time += wall_step
            self.step(self.wall_time)
            steps += 1
        if self.wall_time + wall_step <= now:
            self.wall_time = now
        for a in self.actuators:
            a.sim_time = self.wall_time

    def step(self, now: float) -> None:
        raw_torque = np.array([a.motor_torque(now) for a in self.actuators])
        if self.dynamics.brakes and not all(a.enabled and a.command.kp > 0 for a in self.actuators):  # held
            self.v = np.zeros(self.model.nv)
            self.sim_time += self.dt
            self.steps += 1
            self._write_back(np.zeros(len(self.actuators)))
            return
        tau_motor = self.direction * raw_torque
        friction = self._viscous * self.v + self._coulomb * np.tanh(self.v / self.dynamics.coulomb_smoothing_rad_s)
        tau = tau_motor - friction + self._external()
        acceleration = pin.aba(self.model, self.data, self.q, self.v, tau)
        self.v = self.v + acceleration * self.dt
        self.q = self.q + self.v * self.dt
        for i, a in enumerate(self.actuators):  # rigid stops (`place_obstacle`): the joint stops dead there
            lo, hi = a.stops
            raw = self.direction[i] * self.q[i] + self.offset[i]
            if not lo <= raw <= hi:
                self.q[i] = self.direction[i] * (min(max(raw, lo), hi) - self.offset[i])
                self.v[i] = 0.0
        self.sim_time += self.dt
        self.steps += 1
        noise = self._rng.normal(0.0, self.dynamics.torque_noise_nm, len(self.actuators)) \
            if self.dynamics.torque_noise_nm > 0 else np.zeros(len(self.actuators))
        self._write_back(noise)

    def _write_back(self, noise: np.ndarray) -> None:
        """The body's state into each actuator's (raw units), with this step's torque noise."""
        raw_q = self.direction * self.q + self.offset
        raw_v = self.direction * self.v
        for i, a in enumerate(self.actuators):
            a.position, a.velocity = float(raw_q[i]), float(raw_v[i])
            a.torque_noise = float(noise[i])

    def gravity(self) -> np.ndarray:
        """g(q) [N·m] of the emulated body now (with its model error and payload)."""
        return pin.computeGeneralizedGravity(self.model, self.data, self.q).copy()


__all__ = ["ArmDynamics", "EmulatedArm", "perturbed_model"]
