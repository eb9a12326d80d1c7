"""The CAN gripper's motion law: a ramp toward a target at a speed, its spring torque capped.

Pure functions and a small record, no I/O: the backend streams one impedance command per servo
tick to the gripper actuator. The commanded position follows a ramp from where the fingers were
to the target at the requested speed, but never further than `torque_cap / kp` from where the
fingers are measured — so the actuator's spring, kp·(setpoint − measured), never pushes harder
than the cap (a grasp's force, a move's torque limit) when the fingers are blocked by an object.
"""

from __future__ import annotations

from dataclasses import dataclass

from armwarden.backends.ramp import Ramp


@dataclass
class ImpedanceFingerMotion:
    """One move or grasp: a ramp in gripper positions [rad] (see `GripperConfig`) on the monotonic
    clock, with the torque its spring may push with."""

    ramp: Ramp
    torque_cap_nm: float
    grasp: bool
    #: the action has ended; a successful grasp keeps squeezing with the capped torque
    settled: bool = False

    def setpoint(self, now: float) -> tuple[float, float]:
        """Where the ramp is [rad] and how fast it goes [rad/s] at `now` (at rest once settled)."""
        if self.settled:
            return self.ramp.target, 0.0
        return self.ramp.position(now), self.ramp.velocity(now)


def capped_setpoint(wanted_rad: float, measured_rad: float, torque_cap_nm: float, kp_nm_per_rad: float) -> float:
    """`wanted_rad`, moved toward `measured_rad` until kp·|setpoint − measured| ≤ `torque_cap_nm`."""
    reach = torque_cap_nm / kp_nm_per_rad
    return measured_rad + min(max(wanted_rad - measured_rad, -reach), reach)


__all__ = ["ImpedanceFingerMotion", "capped_setpoint"]
