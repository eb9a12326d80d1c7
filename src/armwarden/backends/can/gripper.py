"""The CAN gripper's motion law: a ramp toward a target at a speed, its spring torque capped.

Pure functions and a small record, no I/O: the backend streams one impedance command per servo
tick to the gripper actuator. The commanded position follows a ramp from where the fingers were
to the target at the requested speed, but never further than `torque_cap / kp` from where the
fingers are measured — so the actuator's spring, kp·(setpoint − measured), never pushes harder
than the cap (a grasp's force, a move's torque limit) when the fingers are blocked by an object.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass
class GripperMotion:
    """One move or grasp in gripper positions [rad] (see `GripperConfig`), monotonic seconds."""

    start_rad: float
    target_rad: float
    speed_rad_s: float
    torque_cap_nm: float
    started: float
    grasp: bool
    #: the action has ended; a successful grasp keeps squeezing with the capped torque
    settled: bool = False

    def ramp(self, now: float) -> tuple[float, float]:
        """The ramp's position [rad] and velocity [rad/s] at `now`."""
        distance = self.target_rad - self.start_rad
        travelled = self.speed_rad_s * max(0.0, now - self.started)
        if self.settled or travelled >= abs(distance):
            return self.target_rad, 0.0
        sign = math.copysign(1.0, distance)
        return self.start_rad + sign * travelled, sign * self.speed_rad_s

    def ramp_done(self, now: float) -> bool:
        return self.speed_rad_s * max(0.0, now - self.started) >= abs(self.target_rad - self.start_rad)


def capped_setpoint(wanted_rad: float, measured_rad: float, torque_cap_nm: float, kp_nm_per_rad: float) -> float:
    """`wanted_rad`, moved toward `measured_rad` until kp·|setpoint − measured| ≤ `torque_cap_nm`."""
    reach = torque_cap_nm / kp_nm_per_rad
    return measured_rad + min(max(wanted_rad - measured_rad, -reach), reach)


__all__ = ["GripperMotion", "capped_setpoint"]
