"""What the CAN servo loop sends each tick: the stream of command frames, stiff or damping.

Not to be confused with `command.py`: that is the single five-value impedance command
(`MotorCommand`) the codecs encode; this module decides which commands each tick sends, and sends
them. Every tick sends one frame per actuator — the stream is what feeds the actuators' watchdogs:
the trajectory sample or the hold (the tracking gains), or kp = 0, kd > 0 while damping. A position
outside the policy's joint limits, or a value a codec cannot carry, is never sent: the stream
damps instead, and records why (`limit_violation`), which the next tick turns into a fault.

Stiff commands carry the gravity feed-forward when the stream has a `gravity` (g(q*) of the robot
model, through each joint's direction): without it an arm under gravity sags by g/kp. A
feed-forward beyond a joint's `torque_limit_nm` is refused (damped) like any other value that
cannot be sent, never clipped. Damping frames carry the gravity of the measured pose too
(kp = 0: a damped arm without brakes would otherwise drop under its own weight), or none at all
when that is unknown.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence

import numpy as np

from armwarden.backends.can.actuators import Actuator, OutFrame
from armwarden.backends.can.bring_up import command_frame
from armwarden.backends.can.bus import CanBus, FrameKind
from armwarden.backends.can.command import MotorCommand
from armwarden.backends.can.gripper import CanFingers
from armwarden.core.errors import BackendError


class CommandStream:
    """The frames out, under the servo lock (or from the thread that stops); readings of the
    actuators are guarded by the backend's state lock."""

    def __init__(self, joint_names: Sequence[str], actuators: list[Actuator], everyone: list[Actuator],
                 fingers: CanFingers | None, *, direction: np.ndarray, offset: np.ndarray, lower: np.ndarray,
                 upper: np.ndarray, state_lock: threading.Lock, bus: Callable[[], CanBus | None],
                 on_damping: Callable[[], object],
                 gravity: Callable[[np.ndarray], np.ndarray] | None = None) -> None:
        self._joint_names = tuple(joint_names)
        self._actuators = actuators  # the arm's
        self._everyone = everyone  # the arm's, then the gripper's: damping covers all
        self._fingers = fingers
        self._direction, self._offset = direction, offset
        self._lower, self._upper = lower, upper
        self._state_lock = state_lock
        self._bus = bus
        self._gravity = gravity  # q [rad] -> g(q) [N·m], on the servo thread only
        self._torque_limit = np.array([a.joint.torque_limit_nm for a in actuators], dtype=float)
        self._on_damping = on_damping  # told (under the servo lock) when a refused setpoint starts damping
        #: damping frames from this tick on (a fault, an e-stop, a setpoint refused)
        self.damping = False
        #: why a setpoint was refused (never sent); the next tick makes it a fault
        self.limit_violation: str | None = None
        #: command frames sent while following a trajectory (not holds, not damping): motion at the bus
        self.motion_frames = 0
        #: executions that sent at least one motion frame
        self.moving_executions = 0
        self.moved_this_execution = False

    def outside_limits(self, positions: np.ndarray, what: str) -> list[str]:
        """Each joint of `positions` outside the policy limits, named (NaN included)."""
        if bool(np.all((positions >= self._lower) & (positions <= self._upper))):
            return []  # the common case, checked at once (NaN fails it and is named below)
        return [f"joint {n}: {what} position {q:.4f} rad outside the policy limits [{lo:.4f}, {hi:.4f}] (refused)"
                for n, q, lo, hi in zip(self._joint_names, positions, self._lower, self._upper, strict=True)
                if not lo <= q <= hi]

    def send(self, positions: np.ndarray, velocities: np.ndarray, *, following: bool) -> None:
        """This tick's command to every actuator: every frame is encoded (a value the model
        cannot carry refuses the whole tick before anything is sent), then sent as one batch."""
        frames: list[OutFrame] = []
        if not self.damping:
            bad = self.outside_limits(positions, "commanded" if following else "hold")
            if bad:  # never sent: damp instead, and the next tick turns it into a fault
                self.limit_violation = bad[0]
                self.damping = True
                self._on_damping()
        if not self.damping:
            try:
                frames = self._following_frames(positions, velocities)
            except BackendError as exc:  # a value the model cannot carry (a velocity beyond its field):
                self.limit_violation = str(exc)  # never sent; damp as for a position past a limit
                self.damping = True
                self._on_damping()
        if self.damping:  # every actuator that can be damped is, whatever another one refuses
            frames, refused = self._damping_frames()
            self.send_batch(frames, FrameKind.COMMAND)
            if refused:
                raise refused[0]
            return
        self.send_batch(frames, FrameKind.COMMAND)
        if following:
            self.motion_frames += len(self._actuators)
            if not self.moved_this_execution:
                self.moved_this_execution = True
                self.moving_executions += 1

    def _following_frames(self, positions: np.ndarray, velocities: np.ndarray) -> list[OutFrame]:
        """Every actuator's stiff command of this tick (the gripper's too), all encoded before any is
        sent; `BackendError` if one cannot be."""
        raw = (self._direction * positions + self._offset).tolist()
        raw_velocity = (self._direction * velocities).tolist()
        feedforward = [0.0] * len(self._actuators)
        if self._gravity is not None:
            torque = self._gravity(positions)
            over = [f"{a.label}: gravity feed-forward {t:.2f} N·m beyond its torque_limit_nm {a.joint.torque_limit_nm:g}"
                    for a, t in zip(self._actuators, torque, strict=True) if not abs(t) <= a.joint.torque_limit_nm]
            if over:
                raise BackendError(f"can backend: command refused: {over[0]}")
            feedforward = (self._direction * torque).tolist()
        frames = [command_frame(a, MotorCommand(raw[a.index], raw_velocity[a.index], a.joint.kp_nm_per_rad,
                                                      a.joint.kd_nms_per_rad, feedforward[a.index]))
                  for a in self._actuators]
        if self._fingers is not None:
            frames.append(self._fingers.frame())
        return frames

    def _damping_frames(self) -> tuple[list[OutFrame], list[BackendError]]:
        """kp = 0, kd > 0 for every actuator that can carry it, and why the others cannot."""
        frames: list[OutFrame] = []
        refused: list[BackendError] = []
        holding = self._damping_gravity()
        for a in self._everyone:
            raw = a.raw_position if a.raw_position is not None else 0.0
            raw = min(max(raw, a.ranges.position.lo), a.ranges.position.hi)  # kp = 0: the position has no effect
            feedforward = holding[a.index] if holding is not None and a.index >= 0 else 0.0
            try:
                frames.append(command_frame(a, MotorCommand(raw, 0.0, 0.0, a.joint.damping_kd_nms_per_rad, feedforward)))
            except BackendError as exc:
                refused.append(exc)
        return frames, refused

    def _damping_gravity(self) -> list[float] | None:
        """The raw gravity feed-forward of the measured pose for the damping frames (a damped arm
        without brakes does not drop under its own weight), or None — no feed-forward, plain
        damping — when there is no gravity model, a position is unknown or not finite, or a torque
        would exceed its joint's limit: damping always goes out."""
        if self._gravity is None:
            return None
        raw = [a.raw_position for a in self._actuators]
        if any(r is None or not np.isfinite(r) for r in raw):
            return None
        q = self._direction * (np.array(raw, dtype=float) - self._offset)
        torque = self._gravity(q)
        if not bool(np.all(np.abs(torque) <= self._torque_limit)):
            return None
        return (self._direction * torque).tolist()

    def send_batch(self, frames: list[OutFrame], kind: FrameKind) -> None:
        """Send `frames` in order; each actuator now owes an answer (its RX timeout runs from the
        oldest unanswered frame)."""
        bus = self._bus()
        if bus is None:
            raise BackendError("can backend: the bus is not open")
        now = time.monotonic()
        with self._state_lock:
            for frame in frames:
                if frame.actuator.unanswered_since is None:
                    frame.actuator.unanswered_since = now
        # a refused send latches TX overrun
        bus.send_frames([(f.arbitration_id, f.data, f.extended) for f in frames], kind)


__all__ = ["CommandStream"]
