"""The numbers the envelope enforces (`EnvelopeLimits`, built from the policy), the boxes it
enforces them against, and what a check reports (`EnvelopeReport`): kept apart from the checks
so the per-waypoint checks and the envelope read the same record without importing each other."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from armwarden.robot.model import Pose
from armwarden.safety.violations import Violation


@dataclass(frozen=True)
class Box:
    """An axis-aligned box in the base frame [m]."""

    name: str
    lo: np.ndarray
    hi: np.ndarray

    @classmethod
    def of(cls, name: str, lo, hi) -> Box:
        return cls(name, np.asarray(lo, dtype=float), np.asarray(hi, dtype=float))


@dataclass(frozen=True)
class EnvelopeLimits:
    """The numbers the envelope enforces (built from the policy; see `from_policy`)."""

    lower_rad: np.ndarray
    upper_rad: np.ndarray
    max_velocity_rad_s: np.ndarray
    max_acceleration_rad_s2: np.ndarray
    max_velocity_scaling: float
    max_acceleration_scaling: float
    max_joint_step_rad: float
    soft_joint_step_rad: float | None
    max_cartesian_step_m: float
    joint_limit_margin_rad: float
    sweep_resolution_m: float
    check_resolution_rad: float
    workspace: Box
    keep_out: tuple[Box, ...] = ()
    link_padding_m: float = 0.0
    #: per link, replaces `link_padding_m` for that link's bodies [m]
    padding_by_link_m: Mapping[str, float] = field(default_factory=dict)
    self_collision: bool = True

    @classmethod
    def from_policy(cls, policy) -> EnvelopeLimits:
        robot = policy.robot
        motion = policy.motion
        ws = policy.workspace
        return cls(
            lower_rad=np.array(robot.lower_limits),
            upper_rad=np.array(robot.upper_limits),
            max_velocity_rad_s=np.array(robot.velocity_limits),
            max_acceleration_rad_s2=np.array(robot.acceleration_limits),
            max_velocity_scaling=motion.max_velocity_scaling,
            max_acceleration_scaling=motion.max_acceleration_scaling,
            max_joint_step_rad=motion.max_joint_step_rad,
            soft_joint_step_rad=motion.soft_joint_step_rad,
            max_cartesian_step_m=motion.max_cartesian_step_m,
            joint_limit_margin_rad=motion.joint_limit_margin_rad,
            sweep_resolution_m=motion.sweep_resolution_m,
            check_resolution_rad=motion.check_resolution_rad,
            workspace=Box.of("workspace", ws.box.min, ws.box.max),
            keep_out=tuple(Box.of(z.name, z.min, z.max) for z in ws.keep_out),
            link_padding_m=ws.link_padding_m,
            padding_by_link_m=dict(ws.padding_by_link_m),
            self_collision=ws.self_collision,
        )


@dataclass(frozen=True)
class EnvelopeReport:
    violations: tuple[Violation, ...]
    max_joint_velocity_ratio: float = 0.0
    max_joint_acceleration_ratio: float = 0.0
    max_joint_travel_rad: float = 0.0
    tcp_path_length_m: float = 0.0
    final_tcp_pose: Pose | None = None
    samples_checked: int = 0

    @property
    def hard(self) -> tuple[Violation, ...]:
        return tuple(v for v in self.violations if v.is_hard)

    @property
    def soft(self) -> tuple[Violation, ...]:
        return tuple(v for v in self.violations if not v.is_hard)
