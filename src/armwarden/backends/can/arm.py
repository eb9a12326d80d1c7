"""The CAN backend's arm: its servo thread, the published state, executions, stops and faults.

`CanArm` is the part of `CanBackend` (`backend.py`) that moves the arm; the backend builds the
actuators, the frames out (`CommandStream`) and the fingers, and hands them to it. It is a base
class rather than a member because the servo loop calls its hooks on the backend itself.

The servo loop (`armwarden.backends.servo.ServoLoop`) ticks at `control_rate_hz` whether moving
or not — the stream of frames is what feeds the actuators' watchdogs. A tick, in this order:
`servo_prepare` reads what arrived (the bus drained), publishes it, tracks the error and checks
health; then, under the servo lock, `servo_command` sends one impedance command per joint
(`CommandStream.send`): the trajectory sample while following, the measured position (with the
tracking gains) while holding, or kp = 0, kd > 0 while damping. It never sends a position outside
the policy's joint limits: such a setpoint is not sent but turned into a fault. What is published
is what the actuators measured, stamped with the time of the oldest reply it contains (silent
actuators make it age; the Guard refuses it): positions, velocities and the joint torques their
feedback reports (`JointState.efforts`: direction · raw torque, NaN for an actuator whose replies
carried none yet — passed on, never replaced by zero or an older value).

Health, every tick (`health.fault_conditions`): RX timeouts, fault bits and frames, over-temperature,
invalid frames, an actuator out of run mode, the bus's latched flags. ANY fault: damping frames on
every joint from that tick on, the stop epoch bumped, the running execution ended (`execute`
raises `BackendError` naming the joint and the fault, which makes the Guard latch its e-stop), and
the fault reported through the backend's fault listener (the Guard latches the e-stop when idle
too). Damping lasts until an execution is admitted again (only after a human reset the e-stop)
*and* no fault condition is present any more; otherwise that execution is refused. A servo loop
that dies, or hangs (no tick within its deadline: the backend's watchdog, `_worker_heartbeats`),
is a fault for good: damping frames once from another thread, then silence, and the actuators'
CAN timeout disables them.

`stop` holds position (the tracking gains at the measured position); the e-stop
(`emergency_stop` / `emergency_stop_now`: the `estop` tool, the stop channel, SIGUSR1) damps every
joint like a fault — from the calling thread at once, then every tick — until the next admitted
execution, which recovers to a hold at the measured position first.

The arm state (`armwarden.backends.arm_state`) is reported where the flags change: `damped` where
damping begins (an e-stop, a fault before it is reported `faulted`, a setpoint the frames out
refuse), `recover` where `_recover` clears them. The flags (`fault`, `_estopped`,
`CommandStream.damping`) stay what the servo thread reads rather than derive from the state: the
state is `closed` while the servo loop already runs during start-up (damping there must still
damp), and a refused setpoint damps a tick before it is a fault, which `_recover` must not clear.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Sequence
from dataclasses import replace

import anyio
import numpy as np

from armwarden.backends.arm_state import ArmEvent
from armwarden.backends.can.actuators import Actuator
from armwarden.backends.can.bus import CanBus
from armwarden.backends.can.command_stream import CommandStream
from armwarden.backends.can.config import Config
from armwarden.backends.can.health import fault_conditions
from armwarden.backends.can.ranges import Protocol
from armwarden.backends.servo import ServoBackend, ServoLoop, Setpoint, frozen
from armwarden.backends.settle import settle
from armwarden.backends.state_history import JointStateHistory
from armwarden.backends.values import ExecutionResult, ProgressCallback
from armwarden.core.errors import BackendError
from armwarden.core.state import JointState
from armwarden.core.trajectory import JointTrajectory

logger = logging.getLogger(__name__)

#: how often start-up and settling look at the replies [s]
POLL_S = 0.002
#: the share of a servo period the tick may spend handling received frames (the rest wait a tick)
DRAIN_BUDGET = 0.3
#: ... but it always handles this many replies per actuator first: a tick brings one reply each,
#: so the backlog shrinks however often a loaded host preempts the drain past its budget
DRAIN_FLOOR_PER_ACTUATOR = 2


class CanArm(ServoBackend):
    """The arm of CAN actuators (see the module docstring); `CanBackend` opens and closes it."""

    def __init__(self, joint_names: Sequence[str], config: Config, actuators: list[Actuator],
                 everyone: list[Actuator], stream: CommandStream, *, state_lock: threading.Lock,
                 direction: np.ndarray, offset: np.ndarray, start_tolerance_rad: float) -> None:
        super().__init__(joint_names, start_tolerance_rad=start_tolerance_rad)
        self.config = config
        self._actuators = actuators
        #: the arm's actuators, then the gripper's: start-up, health, damping and frames cover all
        self._everyone = everyone
        self._stream = stream
        self._state_lock = state_lock
        self._direction, self._offset = direction, offset
        # honest accuracies: a few position LSBs of the coarsest model; velocity noise of 12-bit fields
        position_lsb = max(a.ranges.position.span / 0xFFFF for a in actuators)
        velocity_lsb = max(a.ranges.velocity.span / (0xFFF if a.ranges.protocol is Protocol.MIT else 0xFFFF)
                           for a in actuators)
        self.goal_accuracy_rad = max(2e-3, 4 * position_lsb)
        self.hold_accuracy_rad = max(2e-3, 4 * position_lsb)
        self.rest_speed_rad_s = max(0.01, 2.5 * velocity_lsb)
        self.period_s = 1.0 / config.control_rate_hz
        self.bus: CanBus | None = None
        self.servo: ServoLoop | None = None
        self._fault_lock = threading.Lock()
        #: the active fault ("joint ...: why; ..."), None when healthy; damping while set
        self.fault: str | None = None
        self._estopped = False  # an e-stop damps until the next admitted execution
        self._enabled = False  # every actuator confirmed run mode at start-up
        self._published: JointState | None = None
        #: complete samples (every actuator replied since the last one), for the contact observer
        self.joint_history = JointStateHistory()
        self._history_replies: list[float] | None = None  # each actuator's reply time in the last one kept
        self._tracking_peak_rad = 0.0
        self._following: np.ndarray | None = None  # the previous tick's trajectory sample

    @property
    def motion_frames(self) -> int:
        """Command frames sent while following a trajectory (not holds, not damping): motion at the bus."""
        return self._stream.motion_frames

    @property
    def moving_executions(self) -> int:
        """Executions that sent at least one motion frame."""
        return self._stream.moving_executions

    # ================================================================ state
    def _latest_joint_state(self) -> JointState:
        servo = self._require_servo()
        servo.require_running()
        published = self._published
        assert published is not None
        return published

    async def _read_joint_state(self) -> JointState:
        return self._latest_joint_state()

    def _joint_states_since(self, stamp: float) -> Sequence[JointState]:
        self._require_servo().require_running()
        return self.joint_history.since_or_latest(stamp)

    def _measured_positions(self) -> np.ndarray:
        with self._state_lock:
            raw = np.array([a.raw_position if a.raw_position is not None else np.nan for a in self._actuators])
        return self._direction * (raw - self._offset)

    def _publish(self) -> None:
        """Publish what the arm's actuators last reported, stamped with the oldest of those
        replies (monotonic [s]; 0 while one never replied): a state is as old as its oldest
        part, so silent actuators make it age — and the Guard refuse it — instead of every servo
        tick passing their last positions off as new (found by review: 10 s of silence, fresh
        stamps). Never goes backwards: each actuator's reply time only grows."""
        with self._state_lock:
            raw = np.array([a.raw_position if a.raw_position is not None else np.nan for a in self._actuators])
            raw_velocity = np.array([a.raw_velocity for a in self._actuators])
            raw_torque = np.array([a.raw_torque if a.raw_torque is not None else np.nan for a in self._actuators])
            replies = [a.reported_at for a in self._actuators]
        stamp = 0.0 if None in replies else min(r for r in replies if r is not None)
        efforts = frozen(self._direction * raw_torque) if self.config.joint_torques else None
        published = JointState(self.joint_names, frozen(self._direction * (raw - self._offset)),
                               frozen(self._direction * raw_velocity), stamp, efforts)
        self._published = published
        self._keep_if_complete(published, replies)

    def _keep_if_complete(self, state: JointState, replies: list[float | None]) -> None:
        """Keep `state` for the contact observer when every actuator replied since the last kept
        one. A tick that drained only some replies (a stalled servo thread catching up) publishes
        a state that mixes this cycle's positions with an older cycle's; the observer divides its
        momentum change by the stamps' interval and read such mixes as contacts (on the emulator,
        after a stall, replies up to 147 ms apart in one sample). The Guard's other reads still get
        the latest state, stamped by its oldest part."""
        answered = [reply for reply in replies if reply is not None]
        if len(answered) < len(replies):  # one never replied: no state is complete yet
            return
        previous = self._history_replies
        if previous is not None and not all(now > then for now, then in zip(answered, previous, strict=True)):
            return
        self._history_replies = answered
        self.joint_history.append(state)

    # ================================================================ motion
    async def _execute(self, trajectory: JointTrajectory, progress: ProgressCallback) -> ExecutionResult:
        servo = self._require_servo()
        servo.require_running()
        if self.fault is not None or self._estopped:
            self._recover()
        if self._stream.damping:  # a setpoint the frames out refused damps a tick before the fault latches
            raise BackendError("can backend: the actuators are damping after a setpoint outside the policy "
                               "limits; motion refused (a fault follows)")
        self._tracking_peak_rad = 0.0
        self._following = None
        self._stream.moved_this_execution = False
        result = await servo.run(trajectory, progress, preempted=self._stop_landed)
        self._raise_if_faulted()
        if result.completed:
            result = await self._settle(servo, trajectory.goal)
        return replace(result, max_tracking_error_rad=self._tracking_peak_rad)

    async def _settle(self, servo: ServoLoop, goal: np.ndarray) -> ExecutionResult:
        """The goal is commanded; wait until the measured arm is there and still (`settle`; a stop
        ends it where the servo last commanded, a fault raises)."""
        async def commanded() -> np.ndarray:
            return servo.latest.positions.copy()

        return await settle(goal, measure=self._latest_joint_state, check=self._raise_if_faulted,
                            stop_landed=self._stop_landed, rest_position=commanded,
                            accuracy_rad=self.goal_accuracy_rad, rest_speed_rad_s=self.rest_speed_rad_s,
                            timeout_s=self.config.settle_timeout_s, poll_s=POLL_S)

    def _raise_if_faulted(self) -> None:
        fault = self.fault
        if fault is not None:
            raise BackendError(f"can backend fault, motion aborted, actuators damped: {fault}")

    async def _fault_behind_stale_data(self) -> str | None:
        """Whether the actuators are why the data stopped (the Guard asks once the force monitor
        found no usable wrench and stopped the arm). Silent actuators — a bus or power failure —
        stop the joint states and the wrench together, and a wrench timeout shorter than
        `rx_timeout_s` sees it first: so wait until every actuator has answered since this call (the
        bus lives: None, the wrench alone is stale) or the servo loop's health check finds the fault
        (its RX timeout), at most `rx_timeout_s` and a few ticks; still silent then, the silence is
        the fault (fail closed). Found by the evaluation's backend death: with the emulator
        stopped, this answered "no fault of its own" half a second before the RX timeout said
        otherwise."""
        asked = time.monotonic()
        deadline = asked + self.config.rx_timeout_s + 10 * self.period_s
        while True:
            if (fault := self.fault) is not None:
                return f"can backend fault: {fault}"
            with self._state_lock:
                silent = [a.label for a in self._everyone if a.unanswered_since is not None and a.unanswered_since <= asked]
            if not silent:
                return None
            if time.monotonic() > deadline:
                return (f"can backend: {', '.join(silent)}: no reply for {time.monotonic() - asked:.3f} s "
                        f"(rx_timeout_s {self.config.rx_timeout_s:g} s)")
            await anyio.sleep(POLL_S)

    def _recover(self) -> None:
        """Leave damping (a fault's or an e-stop's) for an execution the Guard admitted (so a human
        reset the e-stop): clear what latched, then refuse if any fault condition is still present."""
        with self._state_lock:
            for a in self._everyone:
                a.fault_frames, a.invalid_frames = (), 0
        if self.bus is not None:
            self.bus.clear_flags()
        problems = self._conditions(time.monotonic())
        if problems:
            raise BackendError(f"can backend: the fault has not cleared, nothing moves: {'; '.join(problems)}")
        with self._fault_lock:
            if self._stop_landed():  # an e-stop or fault since this execution was decided: stay damped
                return  # (the servo loop refuses the trajectory as "stopped before it started")
            # hold where the arm is *before* damping ends: a tick between the two would otherwise
            # send the setpoint frozen when damping began, stiffly, to an arm that sagged since
            self._stop_fingers()  # the fingers hold where damping left them
            self._require_servo().hold()
            self.fault = None
            self._stream.damping, self._stream.limit_violation = False, None
            self._estopped = False
            self._arm_event(ArmEvent.RECOVER)
        logger.warning("can backend: damping ended after a reset; holding again")

    # ================================================================ stops
    async def _stop(self) -> None:
        self._stop_now()

    def _stop_now(self) -> None:
        servo = self._require_servo()
        self._stop_fingers()
        servo.hold()
        servo.require_running()

    async def _emergency_stop(self) -> None:
        self._emergency_stop_now()

    def _emergency_stop_now(self) -> None:
        """The e-stop: damping frames on every joint now, from the calling thread, and from every
        later tick, until an execution is admitted again (after a human reset) — as for a fault."""
        servo = self._require_servo()
        self._stop_fingers()
        with self._fault_lock:  # against `_recover` leaving damping at the same moment
            self._estopped = self._stream.damping = True
            servo.hold()  # the running execution ends "stopped"; the hold is sent as damping
            self._arm_event(ArmEvent.DAMP)
        servo.require_running()

    def _require_servo(self) -> ServoLoop:
        if self.servo is None:
            raise BackendError("can backend: the servo loop is not running")
        return self.servo

    # ================================================================ servo hooks
    def servo_prepare(self, setpoint: Setpoint) -> None:
        """Servo thread: publish the measured state, track the error, check health."""
        servo = self.servo
        if servo is None or threading.current_thread() is not servo.thread:
            return
        self._worker_checkpoint("servo")
        if self.bus is not None:  # the frames that arrived before this tick, a fault among them, count now
            self.bus.drain(budget_s=DRAIN_BUDGET * self.period_s, at_least=DRAIN_FLOOR_PER_ACTUATOR * len(self._everyone))
        now = time.monotonic()
        self._publish()
        measured = self._published.positions if self._published is not None else None
        if self._following is not None and measured is not None:
            self._tracking_peak_rad = max(self._tracking_peak_rad, float(np.max(np.abs(measured - self._following))))
        self._following = setpoint.positions if setpoint.following else None
        problems = self._conditions(now)
        if self._stream.limit_violation is not None:
            problems.insert(0, self._stream.limit_violation)
        if setpoint.following and not self._stream.damping:
            problems.extend(self._stream.outside_limits(setpoint.positions, "commanded"))
        if problems and self.fault is None:
            self._enter_fault(problems)

    def servo_command(self, setpoint: Setpoint) -> None:
        self._stream.send(setpoint.positions, setpoint.velocities, following=setpoint.following)

    def servo_hold_positions(self, commanded: np.ndarray) -> np.ndarray:
        measured = self._measured_positions()
        return np.where(np.isfinite(measured), measured, commanded)

    def servo_hold(self, setpoint: Setpoint) -> None:
        self._stream.send(setpoint.positions, setpoint.velocities, following=False)

    def servo_failed(self, error: BaseException) -> None:
        with self._fault_lock:  # the health report says why nothing is commanded any more
            if self.fault is None:
                self.fault = f"all joints: the servo loop died ({error}); nothing is commanded"
        if self.bus is not None:  # the servo loop read the bus: the reader thread reads again (bus-off, faults)
            self.bus.take_back_reading()
        self._worker_died("servo", error)  # damping frames once; then the actuators' CAN timeout disables them

    # ================================================================ faults (servo thread)
    def _enter_fault(self, problems: list[str]) -> None:
        with self._fault_lock:
            if self.fault is not None:
                return
            self.fault = "; ".join(problems)
            self._stream.damping = True
        logger.error("can backend fault: %s; damping every joint", self.fault)
        self._bump_stop_epoch()
        self._stop_fingers()
        self._require_servo().hold()  # damping frames now, and the running execution ends
        self._arm_event(ArmEvent.DAMP)
        self._report_fault(f"can backend fault: {self.fault}")

    def _conditions(self, now: float) -> list[str]:
        """Every fault condition present now, naming the joint (or the bus): `fault_conditions`."""
        return fault_conditions(self._everyone, self._state_lock, self.bus, self.config, enabled=self._enabled, now=now)


__all__ = ["DRAIN_BUDGET", "DRAIN_FLOOR_PER_ACTUATOR", "POLL_S", "CanArm"]
