"""The fake arm's joint torques: what its motors would measure to make the commanded motion.

A kinematic arm follows its setpoint exactly, so the torque its motors deliver is the robot
model's inverse dynamics of that motion, τ = rnea(q, q̇, q̈) = M(q)q̈ + C(q, q̇)q̇ + g(q) (at rest
g(q)), with q̇ and q̈ the trajectory's spread motion (`servo.spread_motion`, which the fake also
publishes as its measured velocity: momentum and torque then agree, as an observer expects),
less what the environment does for them: a test's push, a force F at a point of a link, adds
the external torque Jᵀ F, so the motors measure τ − Jᵀ F (J the point's linear Jacobian).
Optional seeded Gaussian noise [N·m] stands for the sensor's. The sign and units are
`JointState.efforts`' (armwarden.core.state).

The servo thread computes them for each sample, with a Pinocchio `Data` of its own (Data is not
thread safe). A sample carries two readings of the same pose: `moving` (the trajectory's
velocity and acceleration) and `still` (the arm at rest there): a stop holds the arm still from
the instant it lands, in whatever thread issues it, before the servo thread computes again; the
held sample publishes `still`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.backends.servo import Setpoint, frozen
from armwarden.robot.model import RobotModel


@dataclass(frozen=True)
class Push:
    """A force `force_base` [N] (base frame) pushing at `point_in_frame` [m] of the model frame `frame`."""

    frame: str
    frame_id: int
    force_base: np.ndarray
    point_in_frame: np.ndarray


@dataclass(frozen=True)
class Efforts:
    """The joint torques [N·m] of one sample: following the trajectory, and held still at its pose."""

    moving: np.ndarray
    still: np.ndarray

    def published(self, setpoint: Setpoint) -> np.ndarray:
        """What a published sample carries: `moving` while it follows a trajectory, else `still`."""
        return self.moving if setpoint.following else self.still


class JointTorques:
    """Inverse dynamics of the servo thread's setpoints, a test's push and noise (module docstring)."""

    def __init__(self, robot: RobotModel, noise_nm: float = 0.0, seed: int = 0) -> None:
        if not (math.isfinite(noise_nm) and noise_nm >= 0):
            raise ValueError(f"joint_torque_noise_nm must be ≥ 0, got {noise_nm}")
        self.robot = robot
        self._model = robot.model
        self._data = robot.model.createData()  # the servo thread's own
        self._base_id = robot.frame_id(robot.base_frame)
        self.noise_nm = float(noise_nm)
        self._rng = np.random.default_rng(seed)
        #: the push in force (None: nothing touches the arm); replaced whole, read once per sample
        self.push: Push | None = None

    def make_push(self, frame: str, force_base: Sequence[float], point_in_frame: Sequence[float]) -> Push:
        """A checked `Push`: a frame of the model, a finite force and point (`ValueError` otherwise)."""
        force = np.array(force_base, dtype=float)
        point = np.array(point_in_frame, dtype=float)
        if force.shape != (3,) or point.shape != (3,) or not (np.all(np.isfinite(force)) and np.all(np.isfinite(point))):
            raise ValueError(f"a push needs a finite 3-vector force and point, got {force.tolist()} at {point.tolist()}")
        return Push(frame, self.robot.frame_id(frame), frozen(force), frozen(point))

    def compute(self, setpoint: Setpoint) -> Efforts:
        """The torques of `setpoint` (servo thread; also once at construction, before it starts)."""
        model, data = self._model, self._data
        q = setpoint.positions
        still = pin.computeGeneralizedGravity(model, data, q).copy()
        spread = setpoint.spread
        if setpoint.following and spread is not None:
            moving = pin.rnea(model, data, q, spread.velocities, spread.accelerations).copy()
        else:
            moving = still
        push = self.push
        if push is not None:
            external = self.external_torque(q, push)
            still, moving = still - external, moving - external
        if self.noise_nm > 0:
            noise = self._rng.normal(0.0, self.noise_nm, size=q.shape)
            still, moving = still + noise, moving + noise
        return Efforts(frozen(moving), frozen(still))

    def external_torque(self, q: np.ndarray, push: Push) -> np.ndarray:
        """Jᵀ F: the joint torques [N·m] the push exerts (J the pushed point's linear Jacobian,
        world-aligned; the force turned from the base frame into the world's)."""
        model, data = self._model, self._data
        jacobian = pin.computeFrameJacobian(model, data, q, push.frame_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        pin.updateFramePlacements(model, data)
        frame = data.oMf[push.frame_id]
        lever = frame.rotation @ push.point_in_frame  # from the frame's origin to the point, world axes
        linear = jacobian[:3] - pin.skew(lever) @ jacobian[3:]  # v_point = v_origin + ω × lever
        force_world = data.oMf[self._base_id].rotation @ push.force_base
        return linear.T @ force_world


__all__ = ["Efforts", "JointTorques", "Push"]
