"""The CAN backend: an arm of MIT-mode and RobStride actuators driven directly over python-can.

Start-up (`_open`): the actuators pinged, read and configured (`bring_up`), refused on any fault
condition or a joint outside the policy limits, and enabled only at the very end, when the servo
loop is about to hold them. A missing reply refuses to open (the daemon exits 2).

The servo loop (`armwarden.backends.servo.ServoLoop`) ticks at `control_rate_hz` whether moving
or not — the stream of frames is what feeds the actuators' watchdogs. Each tick sends one
impedance command per joint: the trajectory sample while following, the measured position (with
the tracking gains) while holding, or kp = 0, kd > 0 while damping. It never sends a position
outside the policy's joint limits: such a setpoint is not sent but turned into a fault. Replies
are parsed on the bus's reader thread; what is published is what the actuators measured, stamped
with the time of the oldest reply it contains (silent actuators make it age; the Guard refuses it).

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

Calibration: joint = direction·(raw − homing_offset_rad); velocity and torque: direction only.
Zeroing and id/baud changes are maintenance operations: no code path here sends them.
See docs/backends/can.md.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import replace
from typing import TYPE_CHECKING

import anyio
import numpy as np

from armwarden.backends.base import Capabilities
from armwarden.backends.can import mit
from armwarden.backends.can import robstride as rs
from armwarden.backends.can.actuators import Actuator, OutFrame, ReplyDecoder
from armwarden.backends.can.bring_up import (
    build_emulator,
    command_frame,
    configure_actuators,
    disable_frame,
    enable_frame,
)
from armwarden.backends.can.bus import BusFactory, CanBus, FrameKind, open_interface
from armwarden.backends.can.command import MotorCommand
from armwarden.backends.can.config import Config, GripperConfig, JointConfig, check_against_policy
from armwarden.backends.can.emulator import ActuatorEmulator
from armwarden.backends.can.gripper import GRIPPER_HOMING_SPEED_MPS, CanFingers
from armwarden.backends.can.health import fault_conditions
from armwarden.backends.can.ranges import Protocol
from armwarden.backends.gripper_checks import check_grasp_margins, check_gripper_width_speed
from armwarden.backends.servo import ServoBackend, ServoLoop, Setpoint, frozen
from armwarden.backends.settle import settle
from armwarden.backends.values import ExecutionResult, GripperResult, ProgressCallback
from armwarden.backends.watchdog import Heartbeat
from armwarden.core.errors import BackendError
from armwarden.core.state import GripperState, JointState
from armwarden.core.trajectory import JointTrajectory
from armwarden.robot.model import RobotModel

if TYPE_CHECKING:
    from armwarden.policy import Policy

logger = logging.getLogger(__name__)

#: how often start-up and settling look at the replies [s]
POLL_S = 0.002
#: the share of a servo period the tick may spend handling received frames (the rest wait a tick)
DRAIN_BUDGET = 0.3
#: ... but it always handles this many replies per actuator first: a tick brings one reply each,
#: so the backlog shrinks however often a loaded host preempts the drain past its budget
DRAIN_FLOOR_PER_ACTUATOR = 2


class CanBackend(ServoBackend):
    """The arm of CAN actuators (see the module docstring)."""

    name = "can"
    #: the servo loop; python-can's reader thread reads only before it starts and after it is gone
    worker_threads = ("servo",)

    def __init__(self, robot: RobotModel, config: Config, joints: tuple[JointConfig, ...], *,
                 lower: Iterable[float], upper: Iterable[float], home: Iterable[float], start_tolerance_rad: float,
                 bus_factory: BusFactory = open_interface) -> None:
        super().__init__(robot.joint_names, start_tolerance_rad=start_tolerance_rad)
        self.config = config
        self._lower = np.asarray(tuple(lower), dtype=float)
        self._upper = np.asarray(tuple(upper), dtype=float)
        self._home = np.asarray(tuple(home), dtype=float)
        self._actuators = [
            Actuator(i, j, j.ranges, mit.PositionUnwrapper(j.ranges.position.lo, j.ranges.position.hi)
                      if j.protocol is Protocol.MIT else None)
            for i, j in enumerate(joints)
        ]
        gripper = config.gripper
        self._gripper = None if gripper is None else Actuator(
            -1, gripper, gripper.ranges, mit.PositionUnwrapper(gripper.ranges.position.lo, gripper.ranges.position.hi)
            if gripper.protocol is Protocol.MIT else None)
        #: the arm's actuators, then the gripper's: start-up, health, damping and frames cover all
        self._everyone = [*self._actuators, *([] if self._gripper is None else [self._gripper])]
        self._robstride = {a.joint.can_id: a for a in self._everyone if a.joint.protocol is Protocol.ROBSTRIDE}
        self._mit = {a.joint.can_id: a for a in self._everyone if a.joint.protocol is Protocol.MIT}
        self._direction = np.array([j.direction for j in joints], dtype=float)
        self._offset = np.array([j.homing_offset_rad for j in joints], dtype=float)
        # honest accuracies: a few position LSBs of the coarsest model; velocity noise of 12-bit fields
        position_lsb = max(a.ranges.position.span / 0xFFFF for a in self._actuators)
        velocity_lsb = max(a.ranges.velocity.span / (0xFFF if a.ranges.protocol is Protocol.MIT else 0xFFFF)
                           for a in self._actuators)
        self.goal_accuracy_rad = max(2e-3, 4 * position_lsb)
        self.hold_accuracy_rad = max(2e-3, 4 * position_lsb)
        self.rest_speed_rad_s = max(0.01, 2.5 * velocity_lsb)
        self.period_s = 1.0 / config.control_rate_hz
        self._speedup = config.simulate.speedup if config.simulate is not None else 1.0
        self._bus_factory = bus_factory
        self.bus: CanBus | None = None
        self.emulator: ActuatorEmulator | None = None
        self.servo: ServoLoop | None = None
        self._state_lock = threading.Lock()
        self._replies = ReplyDecoder(self._robstride, self._mit, self._state_lock, config.host_id, config.mit_reply_id)
        self._fault_lock = threading.Lock()
        #: the active fault ("joint ...: why; ..."), None when healthy; damping while set
        self.fault: str | None = None
        self._damping = False
        self._estopped = False  # an e-stop damps until the next admitted execution
        self._enabled = False  # every actuator confirmed run mode at start-up
        self._limit_violation: str | None = None  # a setpoint refused under the servo lock
        self._published: JointState | None = None
        self._tracking_peak_rad = 0.0
        self._following: np.ndarray | None = None  # the previous tick's trajectory sample
        #: command frames sent while following a trajectory (not holds, not damping): motion at the bus
        self.motion_frames = 0
        #: executions that sent at least one motion frame
        self.moving_executions = 0
        #: the gripper (the servo thread streams it; the event loop starts and watches its actions)
        self._fingers = None if self._gripper is None or gripper is None else CanFingers(
            self._gripper, gripper, self._state_lock, command_frame)
        if gripper is not None:
            self.gripper_travel_m = gripper.max_width_m
        self._moved_this_execution = False

    # ================================================================ lifecycle
    @property
    def capabilities(self) -> Capabilities:
        return Capabilities(gripper=self.config.gripper is not None)

    async def _open(self) -> None:
        try:
            await self._start_up()
        except BaseException:
            with anyio.CancelScope(shield=True):
                await self._release()
            raise

    async def _start_up(self) -> None:
        config = self.config
        if config.simulate is not None:
            self.emulator = build_emulator(config, self._actuators, self._home)
            self.emulator.start()
        self.bus = CanBus(config.bus, self._replies.on_frame, bus_factory=self._bus_factory)
        self.bus.open()
        await configure_actuators(self._everyone, config, self._send_batch, self._await_all)
        # 4. nothing wrong before anything is enabled
        problems = self._conditions(time.monotonic())
        if problems:
            raise BackendError(f"can backend: refusing to enable the actuators: {'; '.join(problems)}")
        q = self._measured_positions()
        outside = [f"{n} at {v:.4f} rad (limits [{lo:.4f}, {hi:.4f}])"
                   for n, v, lo, hi in zip(self.joint_names, q, self._lower, self._upper, strict=True) if not lo <= v <= hi]
        if outside:
            raise BackendError(f"can backend: refusing to enable: joints outside the policy limits: {', '.join(outside)}")
        # 5. the servo loop holds the measured positions from its first tick; enable last
        self._publish()
        if self._fingers is not None:
            self._fingers.hold_rad = self._fingers.position()
        self.servo = ServoLoop(self, q, period_s=self.period_s, idle_period_s=self.period_s, speedup=self._speedup,
                               name="can backend", realtime_priority=self.config.realtime_priority)
        await anyio.to_thread.run_sync(self.bus.hand_over_reading)  # each tick reads what arrived before it
        await self.servo.start("armwarden-can-servo")
        for a in self._everyone:
            self._send_batch([enable_frame(a, config.host_id)], FrameKind.MODE)
        await self._await_all(lambda a: a.joint.protocol is Protocol.MIT or a.mode is rs.MotorMode.RUN,
                              "did not enter run mode")
        # 6. a fault the servo loop found while the actuators were enabled (over-current on enable)
        # refuses the start-up as one found before it would (the actuators are then disabled)
        if self.fault is not None:
            raise BackendError(f"can backend: refusing to start: a fault while enabling the actuators: {self.fault}")
        self._enabled = True
        logger.info("can backend: %d actuators enabled at %.0f Hz", len(self._actuators), config.control_rate_hz)

    async def _close(self) -> None:
        await self._release()

    def _worker_heartbeats(self) -> tuple[Heartbeat, ...]:
        """The servo loop's ticks. A hung loop sends nothing: the watchdog's e-stop sends the damping
        frames from its own side (`_emergency_stop_now` needs the servo lock, the state lock and the
        bus's send lock, none of which a tick holds while it prepares or reads the bus), after which
        the actuators' CAN timeout disables them."""
        return (self._require_servo().heartbeat("servo"),)

    async def _release(self) -> None:
        self._enabled = False
        if self.servo is not None:
            await self.servo.shutdown()
        bus = self.bus
        if bus is not None:
            bus.take_back_reading()  # the servo loop read the bus; the disable replies still come in
        if bus is not None and bus.is_open:
            for a in self._everyone:  # disable: zero torque (the actuators' watchdog would do it anyway)
                try:
                    self._send_batch([disable_frame(a, self.config.host_id)], FrameKind.MODE)
                except BackendError:
                    logger.exception("can backend: disabling %s failed", a.label)
            await asyncio.sleep(5 * POLL_S)  # let the replies come back before the reader stops
        if bus is not None:
            bus.close()
        if self.emulator is not None:
            self.emulator.close()

    async def _await_all(self, ready: Callable[[Actuator], bool], what: str) -> None:
        deadline = time.monotonic() + self.config.startup_timeout_s
        while True:
            with self._state_lock:
                missing = [a for a in self._everyone if not ready(a)]
            if not missing:
                return
            if self.servo is not None:  # it reads the bus once it runs: its death is the cause, not the actuators
                self.servo.require_running()
            if time.monotonic() > deadline:
                names = ", ".join(a.label for a in missing)
                raise BackendError(f"can backend: {names} {what} within {self.config.startup_timeout_s} s")
            await asyncio.sleep(POLL_S)

    # ================================================================ state
    def _latest_joint_state(self) -> JointState:
        servo = self._require_servo()
        servo.require_running()
        published = self._published
        assert published is not None
        return published

    async def _read_joint_state(self) -> JointState:
        return self._latest_joint_state()

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
            replies = [a.reported_at for a in self._actuators]
        stamp = 0.0 if None in replies else min(r for r in replies if r is not None)
        self._published = JointState(self.joint_names, frozen(self._direction * (raw - self._offset)),
                                     frozen(self._direction * raw_velocity), stamp)

    def health(self) -> dict[str, object]:
        """A small report: the active fault, the bus's latched flags and frame counters."""
        bus = self.bus.health() if self.bus is not None else None
        return {
            "fault": self.fault,
            "damping": self._damping,
            "estopped": self._estopped,
            "bus_flags": None if bus is None else str(bus.flags),
            "command_frames_sent": None if bus is None else bus.command_frames_sent,
            "motion_frames": self.motion_frames,
        }

    # ================================================================ motion
    async def _execute(self, trajectory: JointTrajectory, progress: ProgressCallback) -> ExecutionResult:
        servo = self._require_servo()
        servo.require_running()
        if self.fault is not None or self._estopped:
            self._recover()
        self._tracking_peak_rad = 0.0
        self._following = None
        self._moved_this_execution = False
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
            self.fault, self._damping, self._limit_violation, self._estopped = None, False, None, False
        logger.warning("can backend: damping ended after a reset; holding again")

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
            self._estopped = self._damping = True
            servo.hold()  # the running execution ends "stopped"; the hold is sent as damping
        servo.require_running()

    def _require_servo(self) -> ServoLoop:
        if self.servo is None:
            raise BackendError("can backend: the servo loop is not running")
        return self.servo

    # ================================================================ gripper (the `CanFingers` part)
    def _require_fingers(self) -> CanFingers:
        if self._fingers is None:
            raise BackendError("can backend has no gripper")
        return self._fingers

    def _stop_fingers(self) -> None:
        """Any thread, on every stop and fault (`Backend._stop_fingers`): end the gripper's action
        and hold where it is."""
        if self._fingers is not None:
            self._fingers.stop()

    def _latest_gripper_state(self) -> GripperState:
        return self._require_fingers().state()

    def _check_gripper_width_speed(self, width_m: float, speed_mps: float) -> GripperConfig:
        g = self._require_fingers().config
        check_gripper_width_speed(width_m, speed_mps, g.max_width_m)
        return g

    async def _gripper_move(self, width_m: float, speed_mps: float) -> GripperResult:
        g = self._check_gripper_width_speed(width_m, speed_mps)
        return await self._gripper_run(g.position_of(width_m), speed_mps, g.torque_limit_nm, grasp=None)

    async def _gripper_grasp(self, width_m: float, force_n: float, speed_mps: float, epsilon_inner_m: float,
                             epsilon_outer_m: float) -> GripperResult:
        g = self._check_gripper_width_speed(width_m, speed_mps)
        check_grasp_margins(epsilon_inner_m, epsilon_outer_m, force_n)
        torque = force_n * abs(g.width_per_rad_m)  # virtual work: F·dw = τ·dθ
        if torque > g.torque_limit_nm:
            raise BackendError(f"gripper grasp: {force_n} N needs {torque:.2f} N·m, above the gripper actuator's "
                               f"torque limit {g.torque_limit_nm} N·m (refused)")
        # close to the inner edge of the band: an object of the expected width blocks the fingers
        # first and is squeezed with (at most) the force
        return await self._gripper_run(g.position_of(max(0.0, width_m - epsilon_inner_m)), speed_mps, torque,
                                       grasp=(width_m - epsilon_inner_m, width_m + epsilon_outer_m))

    async def _gripper_home(self) -> GripperResult:
        g = self._require_fingers().config
        return await self._gripper_run(g.open_position_rad, GRIPPER_HOMING_SPEED_MPS, g.torque_limit_nm, grasp=None)

    async def _gripper_run(self, target_rad: float, speed_mps: float, torque_cap_nm: float,
                           grasp: tuple[float, float] | None) -> GripperResult:
        """An action of the fingers (`CanFingers.run`), refused while faulted or damped."""
        fingers = self._require_fingers()
        servo = self._require_servo()
        servo.require_running()
        self._raise_if_faulted()
        if self._damping:
            raise BackendError("can backend: the actuators are damped (e-stop or fault); the gripper does not move")
        return await fingers.run(target_rad, speed_mps, torque_cap_nm, grasp, rest_speed_rad_s=self.rest_speed_rad_s,
                                 check=self._raise_if_faulted, stop_landed=self._gripper_stop_landed)

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
        if self._limit_violation is not None:
            problems.insert(0, self._limit_violation)
        if setpoint.following and not self._damping:
            problems.extend(self._outside_limits(setpoint.positions, "commanded"))
        if problems and self.fault is None:
            self._enter_fault(problems)

    def servo_command(self, setpoint: Setpoint) -> None:
        self._send_commands(setpoint.positions, setpoint.velocities, following=setpoint.following)

    def servo_hold_positions(self, commanded: np.ndarray) -> np.ndarray:
        measured = self._measured_positions()
        return np.where(np.isfinite(measured), measured, commanded)

    def servo_hold(self, setpoint: Setpoint) -> None:
        self._send_commands(setpoint.positions, setpoint.velocities, following=False)

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
            self._damping = True
        logger.error("can backend fault: %s; damping every joint", self.fault)
        self._bump_stop_epoch()
        self._stop_fingers()
        self._require_servo().hold()  # damping frames now, and the running execution ends
        self._report_fault(f"can backend fault: {self.fault}")

    def _conditions(self, now: float) -> list[str]:
        """Every fault condition present now, naming the joint (or the bus): `fault_conditions`."""
        return fault_conditions(self._everyone, self._state_lock, self.bus, self.config, enabled=self._enabled, now=now)

    def _outside_limits(self, positions: np.ndarray, what: str) -> list[str]:
        if bool(np.all((positions >= self._lower) & (positions <= self._upper))):
            return []  # the common case, checked at once (NaN fails it and is named below)
        return [f"joint {n}: {what} position {q:.4f} rad outside the policy limits [{lo:.4f}, {hi:.4f}] (refused)"
                for n, q, lo, hi in zip(self.joint_names, positions, self._lower, self._upper, strict=True)
                if not lo <= q <= hi]

    # ================================================================ frames out (under the servo lock)
    def _send_commands(self, positions: np.ndarray, velocities: np.ndarray, *, following: bool) -> None:
        """This tick's command to every actuator: every frame is encoded (a value the model
        cannot carry refuses the whole tick before anything is sent), then sent as one batch."""
        frames: list[OutFrame] = []
        if not self._damping:
            bad = self._outside_limits(positions, "commanded" if following else "hold")
            if bad:  # never sent: damp instead, and the next tick turns it into a fault
                self._limit_violation = bad[0]
                self._damping = True
        if not self._damping:
            try:
                frames = self._following_frames(positions, velocities)
            except BackendError as exc:  # a value the model cannot carry (a velocity beyond its field):
                self._limit_violation = str(exc)  # never sent; damp as for a position past a limit
                self._damping = True
        if self._damping:  # every actuator that can be damped is, whatever another one refuses
            frames, refused = [], []
            for a in self._everyone:
                raw = a.raw_position if a.raw_position is not None else 0.0
                raw = min(max(raw, a.ranges.position.lo), a.ranges.position.hi)  # kp = 0: the position has no effect
                try:
                    frames.append(command_frame(a, MotorCommand(raw, 0.0, 0.0, a.joint.damping_kd_nms_per_rad, 0.0)))
                except BackendError as exc:
                    refused.append(exc)
            self._send_batch(frames, FrameKind.COMMAND)
            if refused:
                raise refused[0]
            return
        self._send_batch(frames, FrameKind.COMMAND)
        if following:
            self.motion_frames += len(self._actuators)
            if not self._moved_this_execution:
                self._moved_this_execution = True
                self.moving_executions += 1

    def _following_frames(self, positions: np.ndarray, velocities: np.ndarray) -> list[OutFrame]:
        """Every actuator's stiff command of this tick (the gripper's too), all encoded before any is
        sent; `BackendError` if one cannot be."""
        raw = (self._direction * positions + self._offset).tolist()
        raw_velocity = (self._direction * velocities).tolist()
        frames = [command_frame(a, MotorCommand(raw[a.index], raw_velocity[a.index], a.joint.kp_nm_per_rad,
                                                      a.joint.kd_nms_per_rad, 0.0))
                  for a in self._actuators]
        if self._fingers is not None:
            frames.append(self._fingers.frame())
        return frames

    def _send_batch(self, frames: list[OutFrame], kind: FrameKind) -> None:
        """Send `frames` in order; each actuator now owes an answer (its RX timeout runs from the
        oldest unanswered frame)."""
        bus = self.bus
        if bus is None:
            raise BackendError("can backend: the bus is not open")
        now = time.monotonic()
        with self._state_lock:
            for frame in frames:
                if frame.actuator.unanswered_since is None:
                    frame.actuator.unanswered_since = now
        # a refused send latches TX overrun
        bus.send_frames([(f.arbitration_id, f.data, f.extended) for f in frames], kind)


def create_backend(robot: RobotModel, policy: Policy, config: Config, *,
                   bus_factory: BusFactory = open_interface) -> CanBackend:
    """Registry factory: the actuators `config` names, checked against `policy`'s joints and limits."""
    r = policy.robot
    joints = check_against_policy(config, tuple(r.joint_names), r.lower_limits, r.upper_limits, r.velocity_limits,
                                  None if policy.gripper is None else policy.gripper.max_speed_mps)
    return CanBackend(robot, config, joints, lower=r.lower_limits, upper=r.upper_limits, home=r.home_joint_positions,
                      start_tolerance_rad=policy.motion.start_tolerance_rad, bus_factory=bus_factory)


__all__ = ["CanBackend", "Config", "create_backend"]
