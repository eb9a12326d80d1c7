"""The five-value impedance command both protocols carry (MIT mode and RobStride type 1).

The actuator applies τ = kp·(position − p) + kd·(velocity − v) + torque (feed-forward).
Damping is kp = 0, kd > 0; a hold is the measured position with kp, kd > 0.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class MotorCommand:
    """`position` [rad], `velocity` [rad/s], `kp` [N·m/rad], `kd` [N·m·s/rad], `torque` [N·m]."""

    position: float
    velocity: float
    kp: float
    kd: float
    torque: float


__all__ = ["MotorCommand"]
