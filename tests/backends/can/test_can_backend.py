"""The CAN backend on emulated actuators: the backend contract for both protocols, tracking,
calibration through the bus, every injected fault ending in damping frames and a latched e-stop,
host silence stopping the actuators by their own CAN timeout, and start-up refusals."""

from __future__ import annotations

import asyncio
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import anyio
import can
import numpy as np
import pytest
import yaml
from mcp import Client, StdioServerParameters

from armwarden.assembly import build_guard
from armwarden.backends import parse_backend_config, realtime
from armwarden.backends.base import Backend
from armwarden.backends.can import mit
from armwarden.backends.can import robstride as rs
from armwarden.backends.can import robstride_device as rs_device
from armwarden.backends.can import robstride_frames as rs_frames
from armwarden.backends.can.backend import CanBackend, create_backend
from armwarden.backends.can.bus import FrameKind, HealthFlag
from armwarden.backends.can.command import MotorCommand
from armwarden.backends.can.config import Config
from armwarden.backends.can.emulated_actuator import ActuatorSpec
from armwarden.backends.can.emulator import ActuatorEmulator
from armwarden.backends.can.ranges import model_ranges
from armwarden.core.errors import BackendError, ConfigurationError
from armwarden.policy import load_policy
from armwarden.policy.loading import bundled_policy
from armwarden.robot import build_robot
from tests.backends.can.polling import unique_channel
from tests.backends.contract import BackendContract, straight_line, wait_until
from tests.helpers import REPO, SRC

POLICY = load_policy(bundled_policy("fr3"))
ROBOT = build_robot(POLICY)
EXAMPLES = Path(__file__).resolve().parents[3] / "examples"
ROBSTRIDE_SIM = EXAMPLES / "can_sim.yaml"
MIT_SIM = EXAMPLES / "can_sim_mit.yaml"


#: the emulated actuators answer from threads of the test process, which a loaded host can stall
#: past the examples' 0.25 s (a gripper "no reply for 269 ms" was seen beside the parallel lane,
#: "no reply for 623 ms" beside two CPU hogs and the parallel workers); the scenario harness's
#: figures (tests/server/harness.py), still short against a long motion, so silence is still found
IN_PROCESS_RX_TIMEOUT_S = 1.0
#: ... and the actuators' own CAN timeout: a test process stalled past the examples' 0.5 s left the
#: emulated actuators disabled ("left run mode (RESET)") though the servo loop never stopped sending
IN_PROCESS_CAN_TIMEOUT_S = 2.0


def config_document(path: Path = ROBSTRIDE_SIM, **top: Any) -> dict[str, Any]:
    document = yaml.safe_load(path.read_text())
    document["bus"]["channel"] = unique_channel()
    document["rx_timeout_s"] = IN_PROCESS_RX_TIMEOUT_S
    document["can_timeout_s"] = IN_PROCESS_CAN_TIMEOUT_S
    document.update(top)
    return document


def build(path: Path = ROBSTRIDE_SIM, **top: Any) -> CanBackend:
    config = parse_backend_config("can", config_document(path, **top))
    assert isinstance(config, Config)
    return create_backend(ROBOT, POLICY, config)


class TestCanRobStrideContract(BackendContract):
    def build(self) -> Backend:
        return build(ROBSTRIDE_SIM)


class TestCanMitContract(BackendContract):
    def build(self) -> Backend:
        return build(MIT_SIM)


# ---------------------------------------------------------------------------- a bus spy
@dataclass(frozen=True)
class Seen:
    """One frame seen on the bus, decoded as far as the test needs."""

    index: int
    msg: can.Message
    motor: int | None  # command frames: the motor addressed
    command: MotorCommand | None  # command frames: what was commanded

    @property
    def damping(self) -> bool:
        return self.command is not None and self.command.kp == 0.0 and self.command.kd > 0.0


class FrameLog:
    """Frames in some order, decoded as far as the tests need (`seen`)."""

    def __init__(self, backend: CanBackend) -> None:
        self.backend = backend
        self.frames: list[can.Message] = []
        self._lock = threading.Lock()
        actuators = [*backend.config.joints, *([backend.config.gripper] if backend.config.gripper else [])]
        self._ranges = {j.can_id: j.ranges for j in actuators}
        self._protocol = {j.can_id: j.protocol.value for j in actuators}

    def _log(self, *messages: can.Message) -> None:
        with self._lock:
            self.frames.extend(messages)

    def close(self) -> None:
        """Stop logging."""

    def seen(self) -> list[Seen]:
        with self._lock:
            frames = list(self.frames)
        out = []
        for i, msg in enumerate(frames):
            motor, command = None, None
            if not msg.is_error_frame and msg.is_extended_id and rs.split_id(msg.arbitration_id).comm_type == rs.CommType.CONTROL:
                motor = msg.arbitration_id & 0xFF
                command = rs_device.unpack_control(msg.arbitration_id, bytes(msg.data), self._ranges[motor])[1]
            elif (not msg.is_error_frame and not msg.is_extended_id and msg.arbitration_id in self._protocol
                  and len(msg.data) == 8 and mit.special_of(bytes(msg.data)) is None):
                motor = msg.arbitration_id
                command = mit.unpack_command(bytes(msg.data), self._ranges[motor])
            out.append(Seen(i, msg, motor, command))
        return out


class Spy(FrameLog):
    """Every frame on a virtual channel, in the bus's order (python-can's virtual bus delivers to
    every other bus), read by a bus of the test's own."""

    def __init__(self, backend: CanBackend) -> None:
        super().__init__(backend)
        self.bus = can.Bus(interface="virtual", channel=backend.config.bus.channel)
        self._notifier = can.Notifier(self.bus, [self._log], timeout=0.05)

    def close(self) -> None:
        self._notifier.stop()
        self.bus.shutdown()


class HandlingOrder(FrameLog):
    """The frames in the order the backend dealt with them: each frame it sent, once sent, and
    each frame it received, once handled. A frame on the bus may wait in the backend's queue
    for a tick or two on a loaded host (the servo tick's drain has a budget); what the backend
    owes is what it does once it has read the frame, which this order shows whatever the host's
    load."""

    def __init__(self, backend: CanBackend, monkeypatch: pytest.MonkeyPatch) -> None:
        super().__init__(backend)
        bus = backend.bus
        assert bus is not None
        received, send = bus._received, bus._send_messages

        def handled(msg: can.Message) -> None:
            received(msg)
            self._log(msg)

        def sent(messages: Sequence[can.Message], kind: FrameKind) -> int:
            count = send(messages, kind)
            self._log(*messages)
            return count

        monkeypatch.setattr(bus, "_received", handled)
        monkeypatch.setattr(bus, "_send_messages", sent)


def assert_damping_within_one_period(seen: list[Seen], evidence: int, motors: set[int]) -> None:
    """After frame `evidence` (the first sign of the fault), each motor gets at most one
    more non-damping command (the tick already under way) before its damping frames, and once
    damping has begun every later command frame is damping."""
    after = [s for s in seen if s.index > evidence and s.command is not None]
    first_damping = next(s.index for s in after if s.damping)
    for motor in motors:
        before = [s for s in after if s.motor == motor and s.index < first_damping]
        assert len(before) <= 1, f"motor {motor}: {len(before)} non-damping commands after the fault"
    late = [s for s in after if s.index >= first_damping and not s.damping]
    assert late == [], f"non-damping commands after damping began: {late[:3]}"
    damped = {s.motor for s in after if s.index >= first_damping and s.damping}
    assert damped == motors


def all_motors(backend: CanBackend) -> set[int]:
    gripper = backend.config.gripper
    return {j.can_id for j in backend.config.joints} | ({gripper.can_id} if gripper else set())


async def long_motion(backend: CanBackend, reach: float = 0.3, duration_s: float = 4.0):
    q = (await backend.read_joint_state()).positions.copy()
    return straight_line(backend.joint_names, q, q + reach, duration_s)


async def moving(backend: CanBackend, trajectory) -> asyncio.Task:
    q = (await backend.read_joint_state()).positions.copy()
    task = asyncio.create_task(backend.execute(trajectory))

    async def moved() -> bool:
        return bool(np.max(np.abs((await backend.read_joint_state()).positions - q)) > 0.01)

    await wait_until(moved)
    return task


# ---------------------------------------------------------------------------- config
def test_config_errors_name_their_yaml_path():
    document = config_document()
    document["joints"][2]["kp_nm_per_rad"] = float("nan")
    document["joints"][3]["gains"] = 1
    with pytest.raises(ConfigurationError) as caught:
        parse_backend_config("can", document)
    message = str(caught.value)
    assert "joints[2].kp_nm_per_rad" in message and "joints[3].gains" in message


def test_config_refuses_duplicate_ids_and_a_model_of_the_other_protocol():
    document = config_document()
    document["joints"][1]["can_id"] = 1
    with pytest.raises(ConfigurationError, match="duplicate can_id: 1"):
        parse_backend_config("can", document)
    document = config_document()
    document["joints"][0]["model"] = "AK80-9"
    with pytest.raises(ConfigurationError, match="speaks mit, not robstride"):
        parse_backend_config("can", document)


def test_every_policy_joint_must_be_configured_exactly_once():
    document = config_document()
    document["joints"][6]["name"] = "elbow"
    document["simulate"]["loads"].pop("fr3_joint7")
    config = parse_backend_config("can", document)
    assert isinstance(config, Config)
    with pytest.raises(ConfigurationError, match="missing fr3_joint7; not in the policy: elbow"):
        create_backend(ROBOT, POLICY, config)


# ---------------------------------------------------------------------------- start-up
@pytest.mark.anyio
async def test_start_up_refuses_naming_the_actuators_that_do_not_answer():
    document = config_document(simulate=None)
    config = parse_backend_config("can", document)
    assert isinstance(config, Config)
    actuators = [*config.joints, *([config.gripper] if config.gripper else [])]
    present = [ActuatorSpec(can_id=j.can_id, model=j.model) for j in actuators if j.can_id not in (3, 6)]
    with ActuatorEmulator(config.bus.channel, present, host_id=config.host_id):
        backend = create_backend(ROBOT, POLICY, config)
        with pytest.raises(BackendError, match=r"fr3_joint3 \(can id 3\), joint fr3_joint6 \(can id 6\) did not answer"):
            await backend.open()
        await backend.close()


@pytest.mark.anyio
async def test_start_up_refuses_a_robstride_actuator_not_in_operation_mode_naming_the_joint():
    document = config_document(simulate=None)
    config = parse_backend_config("can", document)
    assert isinstance(config, Config)
    actuators = [*config.joints, *([config.gripper] if config.gripper else [])]
    with ActuatorEmulator(config.bus.channel, [ActuatorSpec(can_id=j.can_id, model=j.model) for j in actuators],
                          host_id=config.host_id) as emulator:
        emulator.set_run_mode(5, rs.RunMode.VELOCITY)
        backend = create_backend(ROBOT, POLICY, config)
        with pytest.raises(BackendError, match=r"fr3_joint5 \(can id 5\) is in run_mode 2 \(VELOCITY\)"):
            await backend.open()
        await backend.close()
        assert not any(emulator.snapshot(j.can_id).enabled for j in actuators)


@pytest.mark.anyio
async def test_start_up_writes_each_robstride_torque_limit(arm: CanBackend):
    assert arm.emulator is not None
    for joint in arm.config.joints:
        assert arm.emulator.torque_limit(joint.can_id) == pytest.approx(joint.torque_limit_nm)


@pytest.mark.anyio
async def test_start_up_writes_the_can_timeout_and_enables_last(arm: CanBackend):
    assert arm.emulator is not None
    for joint in arm.config.joints:
        snapshot = arm.emulator.snapshot(joint.can_id)
        assert snapshot.enabled
    # the emulator reads the timeout back from what the backend wrote (0x7028)
    assert all(a.parameters[rs.CAN_TIMEOUT.index] == rs.can_timeout_ticks(arm.config.can_timeout_s) for a in arm._actuators)


# ---------------------------------------------------------------------------- motion
@pytest.mark.anyio
async def test_a_safe_move_tracks_the_trajectory_and_stops_where_planned(arm: CanBackend):
    q = (await arm.read_joint_state()).positions.copy()
    goal = q + np.array([0.4, -0.3, 0.3, 0.3, -0.4, 0.4, 0.5])
    result = await arm.execute(straight_line(arm.joint_names, q, goal, 1.5))
    assert result.completed
    assert result.max_tracking_error_rad is not None and 0 < result.max_tracking_error_rad < 0.05
    assert np.max(np.abs(result.final_positions - goal)) <= arm.goal_accuracy_rad
    assert arm.motion_frames > 0 and arm.moving_executions == 1


@pytest.mark.anyio
async def test_calibration_direction_and_offset_hold_both_ways_through_the_bus(arm: CanBackend):
    """Joint 2 is configured direction −1, homing offset 0.1 rad: the actuator sits at −q + 0.1
    and the command frames on the bus carry −q_goal + 0.1."""
    assert arm.emulator is not None
    spy = Spy(arm)
    try:
        q = (await arm.read_joint_state()).positions.copy()
        goal = q.copy()
        goal[1] += 0.25
        assert (await arm.execute(straight_line(arm.joint_names, q, goal, 0.5))).completed
        measured = (await arm.read_joint_state()).positions
        assert arm.emulator.snapshot(2).position_rad == pytest.approx(-measured[1] + 0.1, abs=2e-3)
        assert arm.emulator.snapshot(1).position_rad == pytest.approx(measured[0], abs=2e-3)
        last = [s.command for s in spy.seen() if s.motor == 2 and s.command is not None][-1]
        assert last.position == pytest.approx(-goal[1] + 0.1, abs=1e-3)
    finally:
        spy.close()


@pytest.mark.anyio
async def test_a_setpoint_outside_the_joint_limits_is_never_sent_it_is_a_fault(arm: CanBackend):
    spy = Spy(arm)
    try:
        q = (await arm.read_joint_state()).positions.copy()
        goal = q.copy()
        goal[0] = POLICY.robot.upper_limits[0] + 0.2  # the Guard would refuse this plan; the backend must too
        start = np.array(q)
        trajectory = straight_line(arm.joint_names, start, goal, 0.3)
        with pytest.raises(BackendError, match=r"fr3_joint1.*outside the policy limits"):
            await arm.execute(trajectory)
        sent = [s.command.position for s in spy.seen() if s.motor == 1 and s.command is not None and s.command.kp > 0]
        assert max(sent) <= POLICY.robot.upper_limits[0] + 1e-3
    finally:
        spy.close()


# ---------------------------------------------------------------------------- faults
def _first(seen: list[Seen], predicate: Callable[[can.Message], bool]) -> int:
    return next(s.index for s in seen if predicate(s.msg))


def _feedback_from(motor: int, check: Callable[[rs.Feedback], bool]) -> Callable[[can.Message], bool]:
    ranges = model_ranges("RS03")

    def predicate(msg: can.Message) -> bool:
        if msg.is_error_frame or not msg.is_extended_id:
            return False
        fields = rs.split_id(msg.arbitration_id)
        if fields.comm_type != rs.CommType.FEEDBACK or (fields.data2 & 0xFF) != motor or len(msg.data) != 8:
            return False
        return check(rs_frames.parse_feedback(msg.arbitration_id, bytes(msg.data), ranges, host_id=0xFD))

    return predicate


FAULTS: dict[str, tuple[Callable[[ActuatorEmulator], None], Callable[[ActuatorEmulator], None], str,
                        Callable[[can.Message], bool] | None]] = {
    "silent actuator": (lambda e: e.silence(3), lambda e: e.silence(3, False), r"fr3_joint3 \(can id 3\).*RX timeout", None),
    "fault bit": (lambda e: e.raise_fault(3, rs.FeedbackFault.OVER_CURRENT), lambda e: e.clear_faults(3),
                  r"fr3_joint3 \(can id 3\): fault OVER_CURRENT", _feedback_from(3, lambda f: bool(f.faults))),
    "over-temperature": (lambda e: e.overheat(3, 95.0), lambda e: e.overheat(3, 30.0),
                         r"fr3_joint3 \(can id 3\): over-temperature 95", _feedback_from(3, lambda f: f.temperature_c > 80)),
    "garbage frames": (lambda e: e.send_garbage(3, 3), lambda e: None, r"fr3_joint3 \(can id 3\): \d invalid frame",
                       lambda m: m.is_extended_id and len(m.data) == 3),
    "bus-off": (lambda e: e.emit_error_frame(0x40), lambda e: None, "all joints: CAN bus BUS_OFF",
                lambda m: m.is_error_frame),
}


@pytest.mark.anyio
@pytest.mark.parametrize("fault", sorted(FAULTS))
async def test_an_injected_fault_damps_every_joint_aborts_the_motion_naming_it_and_latches(
        arm: CanBackend, fault: str, monkeypatch: pytest.MonkeyPatch):
    inject, clear, message, evidence = FAULTS[fault]
    emulator = arm.emulator
    assert emulator is not None
    reported: list[str] = []
    arm.set_fault_listener(reported.append)
    spy = HandlingOrder(arm, monkeypatch)
    try:
        task = await moving(arm, await long_motion(arm))
        epoch = arm.stop_epoch
        inject(emulator)
        with pytest.raises(BackendError, match=message):
            await task
        assert arm.stop_epoch > epoch
        await wait_until(lambda: _async_true(len(reported) == 1))  # reported right after the damping frames
        assert "fr3_joint3" in reported[0] or "all joints" in reported[0]
        motors = all_motors(arm)  # the arm's and the gripper's
        await wait_until(lambda: _async_true({s.motor for s in spy.seen() if s.damping} == motors))
        seen = spy.seen()
        if evidence is not None:
            assert_damping_within_one_period(seen, _first(seen, evidence), motors)
        else:  # silence has no frame of its own: the switch to damping is still one tick for all joints
            first = next(s.index for s in seen if s.damping)
            assert_damping_within_one_period(seen, first - 1, motors)
        # nothing moves while the fault is active
        if fault in ("silent actuator", "fault bit", "over-temperature"):
            frames = arm.motion_frames
            with pytest.raises(BackendError, match="has not cleared"):
                await arm.execute(await long_motion(arm, 0.05, 0.2))
            assert arm.motion_frames == frames
        clear(emulator)  # garbage and bus-off latched: the reset (an admitted execution) clears them

        async def cleared() -> bool:
            return not [p for p in arm._conditions(time.monotonic()) if "invalid" not in p and "BUS_OFF" not in p]

        await wait_until(cleared)

        async def at_rest() -> bool:  # a silenced joint's position was stale, and damping lets the arm drift
            first = (await arm.read_joint_state()).positions
            await asyncio.sleep(0.05)
            return bool(np.max(np.abs((await arm.read_joint_state()).positions - first)) < 1e-3)

        await wait_until(at_rest)
        assert (await arm.execute(await long_motion(arm, 0.05, 0.3))).completed
    finally:
        spy.close()


@pytest.mark.anyio
async def test_a_fault_while_idle_latches_the_guards_estop_and_shows_in_the_safety_status(arm: CanBackend):
    guard = build_guard(POLICY, arm, None)
    assert arm.emulator is not None
    arm.emulator.raise_fault(5, rs.FeedbackFault.MAGNETIC_ENCODER)
    await wait_until(lambda: _async_true(guard.latch.is_latched))
    status = guard.safety_status()
    assert status.estopped and status.estop_event is not None
    assert "fr3_joint5" in status.estop_event.reason and "MAGNETIC_ENCODER" in status.estop_event.reason
    assert any("fr3_joint5" in fault for fault in status.faults)


@pytest.mark.anyio
async def test_a_fault_before_the_guard_is_built_latches_its_estop_when_it_is(arm: CanBackend):
    """Found by review: a fault between `open()` and `build_guard` was reported to nobody, and the
    first execution's recovery cleared it without any human reset."""
    assert arm.emulator is not None
    arm.emulator.raise_fault(5, rs.FeedbackFault.MAGNETIC_ENCODER)
    await wait_until(lambda: _async_true(arm.fault is not None))
    guard = build_guard(POLICY, arm, None)
    assert guard.latch.is_latched
    assert "fr3_joint5" in str(guard.safety_status().estop_event.reason)


@pytest.mark.anyio
async def test_a_fault_while_the_actuators_are_enabled_refuses_the_start_up(monkeypatch: pytest.MonkeyPatch):
    """A fault frame that arrives after the servo loop starts and before enabling ends (over-current
    on enable) refuses `open()` as a fault found before would, and the actuators are disabled."""
    from armwarden.backends.servo import ServoLoop

    backend = build()
    start = ServoLoop.start

    async def start_then_fault(self: ServoLoop, *args: Any, **kwargs: Any) -> None:
        await start(self, *args, **kwargs)
        assert backend.emulator is not None
        backend.emulator.emit_fault_frame(3, rs.FaultFlag.PHASE_A_OVER_CURRENT)
        await wait_until(lambda: _async_true(backend.fault is not None))

    monkeypatch.setattr(ServoLoop, "start", start_then_fault)
    try:
        with pytest.raises(BackendError, match=r"while enabling the actuators.*PHASE_A_OVER_CURRENT"):
            await backend.open()
        assert not backend.is_open
        emulator = backend.emulator
        assert emulator is not None
        assert not any(emulator.snapshot(joint.can_id).enabled for joint in backend.config.joints)  # disabled again
    finally:
        await backend.close()


async def _position_at_rest(backend: Backend, *, within_rad: float = 1e-4, deadline_s: float = 10.0) -> np.ndarray:
    """The arm's position once two measurements at least 0.1 s apart agree to `within_rad` on every joint.

    Judged by the states' stamps, not by the reader's clock: on a busy host the servo thread can
    go 0.1 s without a new reply, and two reads of the same old state would look like rest."""
    state = await backend.read_joint_state()
    previous, previous_stamp = state.positions.copy(), state.stamp
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        await asyncio.sleep(0.05)
        state = await backend.read_joint_state()
        if state.stamp - previous_stamp < 0.1:
            continue
        current = state.positions.copy()
        if np.max(np.abs(current - previous)) < within_rad:
            return current
        previous, previous_stamp = current, state.stamp
    raise AssertionError(f"the arm did not come to rest within {deadline_s} s")


async def _async_true(value: bool) -> bool:
    return value


# ---------------------------------------------------------------------------- host silence
# What is asserted: the emulated actuators disabled themselves by their own CAN timeout (their
# snapshot), and the backend's health reports the fault. Whether the running execute notices
# before or after its trajectory's end is a race of threads, so only "it did not complete" is.
async def _ended_without_completing(task: asyncio.Task) -> None:
    try:
        result = await task
    except BackendError:
        return
    assert not result.completed


def _disabled_by_their_can_timeout(emulator: ActuatorEmulator, motors: set[int]) -> bool:
    return all(not emulator.snapshot(m).enabled and emulator.snapshot(m).timeouts >= 1 for m in motors)


@pytest.mark.anyio
async def test_a_frozen_servo_thread_mid_motion_lets_the_actuators_can_timeout_stop_them(arm: CanBackend):
    emulator = arm.emulator
    assert emulator is not None
    release = threading.Event()
    original = arm.servo_command
    task = await moving(arm, await long_motion(arm, duration_s=30.0))

    def frozen(setpoint):  # the servo thread hangs here, as if the host had died
        release.wait(30)
        original(setpoint)

    arm.servo_command = frozen  # type: ignore[method-assign]  # the hang is injected on the instance
    await wait_until(lambda: _async_true(_disabled_by_their_can_timeout(emulator, all_motors(arm))))
    assert all(emulator.snapshot(m).torque_nm == 0.0 for m in all_motors(arm))
    arm.servo_command = original  # type: ignore[method-assign]
    release.set()
    await wait_until(lambda: _async_true(arm.fault is not None))  # the host sees them out of run mode
    assert "fr3_joint1 (can id 1): left run mode" in str(arm.health()["fault"])
    await _ended_without_completing(task)


@pytest.mark.anyio
async def test_closing_the_host_bus_mid_motion_lets_the_actuators_can_timeout_stop_them(arm: CanBackend):
    emulator = arm.emulator
    assert emulator is not None and arm.bus is not None
    task = await moving(arm, await long_motion(arm, duration_s=30.0))
    arm.bus.close()  # as when the daemon dies: no more frames from the host
    await wait_until(lambda: _async_true(_disabled_by_their_can_timeout(emulator, all_motors(arm))))
    assert all(emulator.snapshot(m).torque_nm == 0.0 for m in all_motors(arm))
    assert "the servo loop died" in str(arm.health()["fault"])
    await _ended_without_completing(task)


@pytest.mark.anyio
async def test_once_the_servo_loop_dies_the_reader_thread_reads_the_bus_again(arm: CanBackend):
    """The servo loop read the bus on every tick: when it dies, a bus-off or a fault frame
    must still be seen and latched."""
    emulator, bus = arm.emulator, arm.bus
    assert emulator is not None and bus is not None and arm.servo is not None
    original = arm._publish

    def broken() -> None:
        raise RuntimeError("injected servo-thread bug")

    arm._publish = broken  # type: ignore[method-assign]  # the next tick raises: the servo thread dies
    await wait_until(lambda: _async_true(arm.servo is not None and arm.servo.error is not None))
    arm._publish = original  # type: ignore[method-assign]
    emulator.emit_error_frame(0x40)  # bus-off
    await wait_until(lambda: _async_true(HealthFlag.BUS_OFF in bus.flags))
    assert "the servo loop died" in str(arm.health()["fault"])


# ---------------------------------------------------------------------------- the daemon
@pytest.mark.anyio
async def test_serve_with_the_can_sim_example_answers_get_robot_state_over_stdio(tmp_path):
    params = StdioServerParameters(
        command=sys.executable,
        args=["-m", "armwarden.cli", "serve", "--audit-log", str(tmp_path / "audit.jsonl"), "--backend", "can",
              "--backend-config", str(ROBSTRIDE_SIM), "--log-level", "WARNING"],
        env={"PYTHONPATH": str(SRC)}, cwd=str(REPO),
    )
    with anyio.fail_after(60):
        async with Client(params) as client:
            state = await client.call_tool("get_robot_state", {})
    assert not state.is_error
    assert state.structured_content["joint_positions"] == pytest.approx(list(POLICY.robot.home_joint_positions), abs=2e-3)


@pytest.mark.parametrize("priority", [0, 100, 2.5, "high"])
def test_config_refuses_a_realtime_priority_outside_1_to_99(priority: Any):
    with pytest.raises(ConfigurationError, match="realtime_priority"):
        parse_backend_config("can", config_document(realtime_priority=priority))


@pytest.mark.anyio
async def test_start_up_refuses_when_the_servo_thread_cannot_have_its_realtime_priority(monkeypatch: pytest.MonkeyPatch):
    def refuse(pid: int, policy: int, param: Any) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(realtime.os, "sched_setscheduler", refuse)
    backend = build(realtime_priority=50)
    with pytest.raises(BackendError, match="SCHED_FIFO priority 50"):
        await backend.open()
    await backend.close()


# ---------------------------------------------------------------------------- found by review
@pytest.mark.anyio
async def test_a_velocity_the_actuator_cannot_carry_damps_and_faults_the_servo_loop_keeps_running(arm: CanBackend):
    """0.2 rad in 10 ms asks an RS04 for 20 rad/s, beyond its ±15 rad/s field, with every position
    inside the limits: never sent, damped and a fault, as a position past a limit is (it once
    killed the servo thread: nothing was streamed after, not even damping)."""
    spy = Spy(arm)
    try:
        q = (await arm.read_joint_state()).positions.copy()
        goal = q.copy()
        goal[0] += 0.2
        with pytest.raises(BackendError, match=r"fr3_joint1 \(can id 1\): command refused: velocity"):
            await arm.execute(straight_line(arm.joint_names, q, goal, 0.01))
        assert arm.servo is not None and arm.servo.thread is not None and arm.servo.thread.is_alive()
        assert arm.health()["damping"] is True
        mark = len(spy.seen())  # the spy reads the bus on its own thread: frames from before may still come in
        await wait_until(lambda: _async_true(len([s for s in spy.seen()[mark:] if s.command is not None]) >= 42))
        latest = [s for s in spy.seen() if s.command is not None][-14:]  # the last two ticks
        assert all(s.command.kp == 0.0 for s in latest)  # damping, still streamed
        arm.emergency_stop_now()  # a later stop still works
    finally:
        spy.close()


def test_a_policy_finger_speed_the_gripper_actuator_cannot_carry_refuses_the_config():
    """0.08 m of stroke over 8 actuator radians at the policy's 0.5 m/s is 50 rad/s, beyond an
    RS00's ±33 rad/s: refused when the backend is built, not found mid-move."""
    from tests.server.harness import policy_with

    document = config_document()
    document["gripper"]["open_position_rad"] = 8.0
    fast = policy_with(**{"gripper.max_speed_mps": 0.5})
    with pytest.raises(ConfigurationError, match=r"gripper: the policy's finger speed 0.5 m/s .* does not fit the RS00 velocity"):
        create_backend(ROBOT, fast, parse_backend_config("can", document))


@pytest.mark.anyio
async def test_leaving_damping_holds_where_the_arm_sagged_to_never_where_it_was():
    """Found by review: leaving damping after a reset cleared the damping flag before the hold
    moved the setpoint to the measured position, so a tick in between sent the setpoint frozen at
    the e-stop, stiffly, to an arm that sagged while limp. Here the tick is made to fall in between."""
    document = config_document()
    document["simulate"]["dynamics"] = "per_actuator"  # its own 1-DOF loads: one joint sags alone
    document["simulate"]["loads"]["fr3_joint2"]["gravity_torque_nm"] = 5.0  # sags while limp ...
    document["joints"][1]["damping_kd_nms_per_rad"] = 100.0  # ... slowly (≈ 0.05 rad/s)
    backend = create_backend(ROBOT, POLICY, parse_backend_config("can", document))
    await backend.open()
    spy = Spy(backend)
    try:
        servo = backend.servo
        assert servo is not None
        await backend.emergency_stop()
        stale = servo.latest.positions.copy()
        end = time.monotonic() + 20.0  # it sags (how fast depends on the host: wait for the fact)
        while abs((await backend.read_joint_state()).positions[1] - stale[1]) <= 0.03:
            assert time.monotonic() < end, "the limp arm did not sag 0.03 rad within 20 s"
            await asyncio.sleep(0.05)
        # ... and comes to rest on a support where it sagged to (a rigid stop below it), so the
        # execution's start check compares against an arm at rest, however late the host runs it
        joint = backend.config.joints[1]
        emulator = backend.emulator
        assert emulator is not None
        emulator.place_obstacle(joint.can_id, low_rad=emulator.snapshot(joint.can_id).position_rad)
        q = await _position_at_rest(backend)
        away_from_the_support = np.full(len(q), 0.02)
        away_from_the_support[1] = 0.02 * float(np.sign(stale[1] - q[1]))
        freeze = backend._stop_fingers

        lost_the_cpu = threading.Event()

        def freeze_then_lose_the_cpu() -> None:  # two ticks run while `_recover` is between its steps
            freeze()
            # once, and never on the servo thread itself (a fault's stop freezes the gripper there
            # too, and would wait for its own ticks); bounded, so a stalled loop fails the test
            if lost_the_cpu.is_set() or threading.current_thread() is servo.thread:
                return
            lost_the_cpu.set()
            ticks, end = servo.tick_count, time.monotonic() + 10.0
            while servo.tick_count < ticks + 2 and time.monotonic() < end:
                time.sleep(0.0005)

        backend._stop_fingers = freeze_then_lose_the_cpu  # type: ignore[method-assign]
        mark = len(spy.seen())
        await backend.execute(straight_line(backend.joint_names, q, q + away_from_the_support, 0.5))
        stiff = [s for s in spy.seen()[mark:] if s.motor == 2 and s.command is not None and s.command.kp > 0]
        first = (stiff[0].command.position - joint.homing_offset_rad) / joint.direction
        assert abs(first - q[1]) < 0.01, f"the first stiff setpoint {first:.4f} rad is not where the arm is ({q[1]:.4f})"
    finally:
        spy.close()
        await backend.close()
