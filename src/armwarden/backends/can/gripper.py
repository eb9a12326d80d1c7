"""The CAN gripper as a part of its own: the fingers' actuator, their motion law, action and hold.

The motion law (`ImpedanceFingerMotion`, `capped_setpoint`): the commanded position follows a ramp
from where the fingers were to the target at the requested speed, but never further than
`torque_cap / kp` from where the fingers are measured, less what the damping term adds — so the
actuator's law, kp·(setpoint − measured) + kd·(velocity − measured velocity), never pushes harder
than the cap (a grasp's force, a move's torque limit) when the fingers are blocked by an object.
The ramp's velocity alone, fed forward through kd while the fingers stood on the object, once
squeezed with 3.6 N·m where a grasp asked for 1.6 (found by CI).

The part (`CanFingers`, the cell's `Gripper`): the backend's servo thread asks `frame` for one
impedance command per tick (the ramp of the running action, or the hold, its spring capped); the
event loop runs an action (`move`, `grasp`, `home`: the width and speed checked first) and watches
it end; any thread ends it (`stop_now`, on every stop and fault). One lock orders an action's start
against a stop, so a stop that came first always wins. What the arm decides — its servo loop
alive, no fault, not damped, no stop since the action was decided — the backend hands in as
`FingerGuards`.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from armwarden.backends.can.actuators import Actuator, OutFrame
from armwarden.backends.can.command import MotorCommand
from armwarden.backends.can.config import GripperConfig
from armwarden.backends.gripper_checks import check_grasp_margins, check_gripper_width_speed
from armwarden.backends.parts import Gripper
from armwarden.backends.ramp import Ramp
from armwarden.backends.values import GripperResult
from armwarden.core.errors import BackendError
from armwarden.core.state import GripperState

#: how often an action looks at the replies [s]
POLL_S = 0.002
#: fingers still this long short of their target are blocked (by an object) [s]
BLOCKED_S = 0.05
#: finger speed of `gripper_home` [m/s]
GRIPPER_HOMING_SPEED_MPS = 0.05


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


def capped_setpoint(wanted_rad: float, measured_rad: float, torque_cap_nm: float, kp_nm_per_rad: float,
                    damping_nm: float = 0.0) -> float:
    """`wanted_rad`, moved until the command's torque at the measured state,
    kp·(setpoint − measured) + `damping_nm` (the law's kd·(velocity − measured velocity)), lies
    within ±`torque_cap_nm`; a damping term beyond the cap is pulled back by the spring."""
    low = measured_rad + (-torque_cap_nm - damping_nm) / kp_nm_per_rad
    high = measured_rad + (torque_cap_nm - damping_nm) / kp_nm_per_rad
    return min(max(wanted_rad, low), high)


@dataclass(frozen=True)
class FingerGuards:
    """What the arm says about a gripper action (the fingers move only with the arm's consent)."""

    #: raises `BackendError` unless an action may start: the servo loop runs, no fault, not damped
    ready: Callable[[], None]
    #: raises `BackendError` on a fault while the action runs
    check: Callable[[], None]
    #: a stop came since the running action was decided
    stop_landed: Callable[[], bool]
    #: the fingers' actuator counts as still below this speed [rad/s] (the arm's honest resolution)
    rest_speed_rad_s: Callable[[], float]


class CanFingers(Gripper):
    """The gripper actuator's action and hold; its readings are guarded by the backend's state lock."""

    def __init__(self, actuator: Actuator, config: GripperConfig, state_lock: threading.Lock,
                 command_frame: Callable[[Actuator, MotorCommand], OutFrame], guards: FingerGuards) -> None:
        self.actuator = actuator
        self.config = config
        self.travel_m = config.max_width_m
        self._state_lock = state_lock
        self._command_frame = command_frame
        self._guards = guards
        self._lock = threading.Lock()  # an action's start vs a stop from any thread
        self.motion: ImpedanceFingerMotion | None = None
        self.hold_rad = config.open_position_rad
        self.grasped = False

    def position(self) -> float:
        """The measured gripper position [rad] (see `GripperConfig`)."""
        return self.reading()[0]

    def reading(self) -> tuple[float, float]:
        """The measured gripper position [rad] and when it arrived (monotonic clock [s])."""
        g, a = self.config, self.actuator
        with self._state_lock:
            raw, stamp = a.raw_position, a.reported_at
        if raw is None or stamp is None:
            raise BackendError(f"can backend: {a.label} reported no position")
        return g.direction * (raw - g.homing_offset_rad), stamp

    def stop_now(self) -> None:
        """Any thread, on every stop and fault: end the action and hold where the fingers are."""
        with self._lock:
            self.motion = None
            self.grasped = False
            with contextlib.suppress(BackendError):  # no position yet: keep the previous hold
                self.hold_rad = self.position()

    def frame(self) -> OutFrame:
        """Servo thread, under the servo lock: this tick's command to the gripper (not damping)."""
        g, a = self.config, self.actuator
        now = time.monotonic()
        measured = self.position()
        with self._state_lock:
            measured_velocity = g.direction * a.raw_velocity
        with self._lock:
            motion = self.motion
            if motion is None:
                wanted, velocity, cap = self.hold_rad, 0.0, g.torque_limit_nm
            else:
                (wanted, velocity), cap = motion.setpoint(now), motion.torque_cap_nm
        low, high = sorted((g.open_position_rad, g.closed_position_rad))
        damping = g.kd_nms_per_rad * (velocity - measured_velocity)
        position = min(max(capped_setpoint(wanted, measured, cap, g.kp_nm_per_rad, damping), low), high)
        # the travel clamp can undo the cap: fingers blocked at the end the ramp starts from (an
        # object as wide as the open fingers) need a setpoint beyond it to cancel kd·v, and would
        # be pushed with kd·v, over the cap, while the ramp runs. Cap the velocity fed forward then.
        spring = g.kp_nm_per_rad * (position - measured)
        allowed = min(max(damping, -cap - spring), cap - spring)
        if abs(allowed - damping) > 1e-9 * cap and g.kd_nms_per_rad > 0:  # not the cap's own rounding
            velocity = measured_velocity + allowed / g.kd_nms_per_rad
        return self._command_frame(self.actuator, MotorCommand(g.direction * position + g.homing_offset_rad,
                                                               g.direction * velocity, g.kp_nm_per_rad,
                                                               g.kd_nms_per_rad, 0.0))

    def state(self) -> GripperState:
        motion = self.motion
        position, stamp = self.reading()  # stamped when it arrived, not when it is read
        return GripperState(self.config.width_of(position), self.grasped, motion is not None and not motion.settled,
                            stamp)

    async def move(self, width_m: float, speed_mps: float) -> GripperResult:
        g = self.config
        check_gripper_width_speed(width_m, speed_mps, g.max_width_m)
        return await self._run(g.position_of(width_m), speed_mps, g.torque_limit_nm, grasp=None)

    async def grasp(self, width_m: float, force_n: float, speed_mps: float, epsilon_inner_m: float,
                    epsilon_outer_m: float) -> GripperResult:
        g = self.config
        check_gripper_width_speed(width_m, speed_mps, g.max_width_m)
        check_grasp_margins(epsilon_inner_m, epsilon_outer_m, force_n)
        torque = force_n * abs(g.width_per_rad_m)  # virtual work: F·dw = τ·dθ
        if torque > g.torque_limit_nm:
            raise BackendError(f"gripper grasp: {force_n} N needs {torque:.2f} N·m, above the gripper actuator's "
                               f"torque limit {g.torque_limit_nm} N·m (refused)")
        # close to the inner edge of the band: an object of the expected width blocks the fingers
        # first and is squeezed with (at most) the force
        return await self._run(g.position_of(max(0.0, width_m - epsilon_inner_m)), speed_mps, torque,
                               grasp=(width_m - epsilon_inner_m, width_m + epsilon_outer_m))

    async def home(self) -> GripperResult:
        g = self.config
        return await self._run(g.open_position_rad, GRIPPER_HOMING_SPEED_MPS, g.torque_limit_nm, grasp=None)

    async def _run(self, target_rad: float, speed_mps: float, torque_cap_nm: float,
                   grasp: tuple[float, float] | None) -> GripperResult:
        """Stream a ramp to `target_rad` (torque capped) until the fingers are there or blocked; a
        grasp (`grasp` = the accepted width band [m]) keeps squeezing if it holds something.
        Refused unless the arm's guards let it start; a fault while it runs raises."""
        guards = self._guards
        guards.ready()
        check, stop_landed = guards.check, guards.stop_landed
        g = self.config
        start = self.position()
        motion = ImpedanceFingerMotion(Ramp(start, target_rad, speed_mps / abs(g.width_per_rad_m), time.monotonic()),
                                       torque_cap_nm, grasp is not None)
        with self._lock:  # started atomically with the check: a stop that came first wins
            if stop_landed():
                return GripperResult(False, g.width_of(start), False, "stopped")
            if self.motion is not None and not self.motion.settled:
                raise BackendError("the gripper is already moving; one gripper action at a time")
            self.motion, self.grasped = motion, False
        rest = max(guards.rest_speed_rad_s(), 0.02)
        still_since: float | None = None
        while True:
            await asyncio.sleep(POLL_S)
            check()
            position = self.position()
            width = g.width_of(position)
            if stop_landed() or self.motion is not motion:
                return GripperResult(False, width, False, "stopped")
            with self._state_lock:
                speed = abs(self.actuator.raw_velocity)
            now = time.monotonic()
            still_since = (still_since or now) if speed <= rest else None
            arrived = motion.ramp.done(now) and abs(position - target_rad) <= g.position_tolerance_rad and speed <= rest
            blocked = still_since is not None and now - still_since >= BLOCKED_S and not arrived
            if arrived or blocked:
                break
        if grasp is not None and grasp[0] <= width <= grasp[1]:
            with self._lock:
                if self.motion is motion:
                    motion.settled = True  # keep squeezing at the capped torque
                    self.grasped = True
            return GripperResult(True, width, True, "")
        with self._lock:
            if self.motion is motion:
                self.motion = None
                self.hold_rad = target_rad if arrived else position
        if grasp is not None:
            return GripperResult(False, width, False, f"final width {width:.4f} m outside [{grasp[0]:.4f}, {grasp[1]:.4f}] m")
        if blocked:
            return GripperResult(False, width, False, f"blocked at {width:.4f} m")
        return GripperResult(True, width, False, "")


__all__ = ["BLOCKED_S", "GRIPPER_HOMING_SPEED_MPS", "CanFingers", "FingerGuards", "ImpedanceFingerMotion",
           "capped_setpoint"]
