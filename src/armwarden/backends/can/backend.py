"""The CAN backend: an arm of MIT-mode and RobStride actuators driven directly over python-can.

`CanBackend` composes the parts: the actuators (`actuators.py`), the frames out
(`command_stream.py`), the fingers (`gripper.py`, the cell's only optional part: `self.cell`), the
bus (`bus.py`) and, when simulated, the emulator; the arm's servo thread, executions, stops and
faults are `CanArm` (`arm.py`).

Start-up (`_open`): the actuators pinged, read and configured (`bring_up`), refused on any fault
condition or a joint outside the policy limits, and enabled only at the very end, when the servo
loop is about to hold them. A missing reply refuses to open (the daemon exits 2).

Calibration: joint = direction·(raw − homing_offset_rad); velocity and torque: direction only
(the published joint torques, `JointState.efforts`, are direction · the feedback's torque).
Zeroing and id/baud changes are maintenance operations: no code path here sends them.
See docs/backends/can.md.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING

import anyio
import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.backends.arm_state import ArmEvent
from armwarden.backends.can import mit
from armwarden.backends.can import robstride as rs
from armwarden.backends.can.actuators import Actuator, ArrivalClock, ReplyDecoder
from armwarden.backends.can.arm import POLL_S, CanArm
from armwarden.backends.can.bring_up import (
    build_emulator,
    command_frame,
    configure_actuators,
    disable_frame,
    enable_frame,
)
from armwarden.backends.can.bus import BusFactory, CanBus, FrameKind, open_interface
from armwarden.backends.can.command_stream import CommandStream
from armwarden.backends.can.config import Config, JointConfig, check_against_policy
from armwarden.backends.can.emulator import ActuatorEmulator
from armwarden.backends.can.gripper import CanFingers, FingerGuards
from armwarden.backends.can.ranges import Protocol
from armwarden.backends.parts import Cell
from armwarden.backends.servo import ServoLoop
from armwarden.backends.watchdog import Heartbeat
from armwarden.core.errors import BackendError
from armwarden.robot.model import RobotModel

if TYPE_CHECKING:
    from armwarden.policy import Policy

logger = logging.getLogger(__name__)


class CanBackend(CanArm):
    """The arm of CAN actuators and their gripper (see the module docstring and `CanArm`)."""

    name = "can"
    #: the servo loop; python-can's reader thread reads only before it starts and after it is gone
    worker_threads = ("servo",)

    def __init__(self, robot: RobotModel, config: Config, joints: tuple[JointConfig, ...], *,
                 lower: Iterable[float], upper: Iterable[float], home: Iterable[float], start_tolerance_rad: float,
                 bus_factory: BusFactory = open_interface) -> None:
        actuators = [
            Actuator(i, j, j.ranges, mit.PositionUnwrapper(j.ranges.position.lo, j.ranges.position.hi)
                      if j.protocol is Protocol.MIT else None)
            for i, j in enumerate(joints)
        ]
        gripper = config.gripper
        gripper_actuator = None if gripper is None else Actuator(
            -1, gripper, gripper.ranges, mit.PositionUnwrapper(gripper.ranges.position.lo, gripper.ranges.position.hi)
            if gripper.protocol is Protocol.MIT else None)
        everyone = [*actuators, *([] if gripper_actuator is None else [gripper_actuator])]
        state_lock = threading.Lock()
        #: the gripper (the servo thread streams it; the event loop starts and watches its actions)
        fingers = None if gripper_actuator is None or gripper is None else CanFingers(
            gripper_actuator, gripper, state_lock, command_frame,
            FingerGuards(ready=self._fingers_may_move, check=self._raise_if_faulted,
                         stop_landed=self._gripper_stop_landed, rest_speed_rad_s=lambda: self.rest_speed_rad_s))
        direction = np.array([j.direction for j in joints], dtype=float)
        offset = np.array([j.homing_offset_rad for j in joints], dtype=float)
        lower_limits = np.asarray(tuple(lower), dtype=float)
        upper_limits = np.asarray(tuple(upper), dtype=float)
        stream = CommandStream(robot.joint_names, actuators, everyone, fingers, direction=direction, offset=offset,
                               lower=lower_limits, upper=upper_limits, state_lock=state_lock, bus=lambda: self.bus,
                               on_damping=lambda: self._arm_event(ArmEvent.DAMP),
                               gravity=gravity_feedforward(robot, config))
        super().__init__(robot.joint_names, config, actuators, everyone, stream, state_lock=state_lock,
                         direction=direction, offset=offset, start_tolerance_rad=start_tolerance_rad)
        self._lower, self._upper = lower_limits, upper_limits
        self._home = np.asarray(tuple(home), dtype=float)
        self._fingers = fingers
        self._robstride = {a.joint.can_id: a for a in everyone if a.joint.protocol is Protocol.ROBSTRIDE}
        self._mit = {a.joint.can_id: a for a in everyone if a.joint.protocol is Protocol.MIT}
        self._speedup = config.simulate.speedup if config.simulate is not None else 1.0
        self._bus_factory = bus_factory
        self._robot = robot
        self.emulator: ActuatorEmulator | None = None
        self._replies = ReplyDecoder(self._robstride, self._mit, state_lock, config.host_id, config.mit_reply_id,
                                     ArrivalClock.for_interface(config.bus.interface))
        # every feedback frame reports the torque, published as the joints' when the config says it is
        # the arm's (`joint_torques`); an emulated bus may run faster than real time
        self.cell = Cell(gripper=fingers, joint_torques=config.joint_torques, time_scale=float(self._speedup),
                         joint_state_interval_s=1.0 / config.control_rate_hz)

    # ================================================================ lifecycle
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
            self.emulator = build_emulator(config, self._actuators, self._home, self._robot)
            self.emulator.start()
        self.bus = CanBus(config.bus, self._replies.on_frame, bus_factory=self._bus_factory)
        self.bus.open()
        await configure_actuators(self._everyone, config, self._stream.send_batch, self._await_all)
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
            self._stream.send_batch([enable_frame(a, config.host_id)], FrameKind.MODE)
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
                    self._stream.send_batch([disable_frame(a, self.config.host_id)], FrameKind.MODE)
                except BackendError:
                    logger.exception("can backend: disabling %s failed", a.label)
            await asyncio.sleep(5 * POLL_S)  # let the replies come back before the reader stops
        if bus is not None:
            bus.close()
        if self.emulator is not None:
            self.emulator.close()

    # ================================================================ the evaluation's injected death
    def why_no_injected_death(self) -> str | None:
        """Only the emulator on python-can's in-process bus can die on request (the rule of
        `armwarden.evaluation.targets`): with real actuators, or a bus another process may bridge
        to hardware, there is nothing to break but a real arm."""
        reasons = []
        if self.config.simulate is None:
            reasons.append("it has no `simulate` section (its actuators are real ones)")
        if self.config.bus.interface != "virtual":
            reasons.append(f"its bus interface is {self.config.bus.interface!r}, not 'virtual' (a real CAN bus)")
        return f"the can backend may drive a real arm: {'; '.join(reasons)}" if reasons else None

    def _inject_death(self) -> str:
        """Evaluation only (`armwarden.backends.death`): the emulator stops, so every emulated
        actuator goes silent and still at once, as a bus or power failure looks to the host; the
        servo loop's RX timeout then finds it (`health.fault_conditions`) and damps and reports it."""
        emulator = self.emulator
        if emulator is None:
            raise BackendError("can backend: no emulator runs (the actuators are real)")
        emulator.close()
        return "the emulator stopped: every emulated actuator is silent"

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

    # ================================================================ health
    def health(self) -> dict[str, object]:
        """A small report: the active fault, the bus's latched flags and frame counters."""
        bus = self.bus.health() if self.bus is not None else None
        return {
            "fault": self.fault,
            "damping": self._stream.damping,
            "estopped": self._estopped,
            "bus_flags": None if bus is None else str(bus.flags),
            "command_frames_sent": None if bus is None else bus.command_frames_sent,
            "motion_frames": self.motion_frames,
        }

    # ================================================================ gripper (the `CanFingers` part)
    def _fingers_may_move(self) -> None:
        """A gripper action starts only with the servo loop running, no fault and no damping."""
        self._require_servo().require_running()
        self._raise_if_faulted()
        if self._stream.damping:
            raise BackendError("can backend: the actuators are damped (e-stop or fault); the gripper does not move")


def gravity_feedforward(robot: RobotModel, config: Config) -> Callable[[np.ndarray], np.ndarray] | None:
    """g(q) of `robot` on a Data of its own (the servo thread's), or None when `config` says no or,
    unset, when the model has no masses or the emulated actuators carry their own 1-DOF loads
    (`simulate.dynamics: per_actuator`: no arm gravity to hold up)."""
    model = robot.model
    wanted = config.gravity_feedforward
    if wanted is None:
        per_actuator = config.simulate is not None and config.simulate.dynamics == "per_actuator"
        wanted = not per_actuator and sum(model.inertias[j].mass for j in range(1, model.njoints)) > 0
    if not wanted:
        return None
    data = model.createData()
    return lambda q: np.asarray(pin.computeGeneralizedGravity(model, data, q), dtype=float).copy()


def create_backend(robot: RobotModel, policy: Policy, config: Config, *,
                   bus_factory: BusFactory = open_interface) -> CanBackend:
    """Registry factory: the actuators `config` names, checked against `policy`'s joints and limits."""
    r = policy.robot
    joints = check_against_policy(config, tuple(r.joint_names), r.lower_limits, r.upper_limits, r.velocity_limits,
                                  None if policy.gripper is None else policy.gripper.max_speed_mps)
    return CanBackend(robot, config, joints, lower=r.lower_limits, upper=r.upper_limits, home=r.home_joint_positions,
                      start_tolerance_rad=policy.motion.start_tolerance_rad, bus_factory=bus_factory)


__all__ = ["CanBackend", "Config", "create_backend"]
