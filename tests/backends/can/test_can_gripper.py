"""The CAN gripper (examples/can_sim.yaml's RobStride finger actuator) through the bus: moves to a
width, grasps an object with at most the asked force, refuses a force above its torque limit,
freezes on a stop and is damped with the arm on an e-stop."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable

import anyio
import pytest
from hypothesis import given
from hypothesis import strategies as st

from armwarden.backends import parse_backend_config
from armwarden.backends.can.actuators import Actuator, OutFrame
from armwarden.backends.can.backend import CanBackend
from armwarden.backends.can.command import MotorCommand
from armwarden.backends.can.config import GripperConfig
from armwarden.backends.can.gripper import CanFingers, FingerGuards, ImpedanceFingerMotion, capped_setpoint
from armwarden.backends.ramp import Ramp
from armwarden.core.errors import BackendError
from tests.backends.can.test_can_backend import MIT_SIM, Spy, _async_true, build, config_document
from tests.backends.contract import wait_until

pytestmark = pytest.mark.anyio
GRIPPER_ID = 8
#: the torque a 40 N grasp asks of the fingers' actuator (examples/can_sim.yaml: 0.04 m/rad)
GRASP_TORQUE_NM = 40.0 * 0.04


def gripper_of(backend: CanBackend):
    assert backend.config.gripper is not None and backend.emulator is not None
    return backend.config.gripper, backend.emulator


async def width(backend: CanBackend) -> float:
    state = await backend.gripper_state()
    assert state is not None
    return state.width_m


def test_the_gripper_is_a_capability_only_when_configured():
    assert build().capabilities.gripper is True
    assert build(MIT_SIM).capabilities.gripper is False


def test_the_cells_gripper_part_is_the_can_fingers_and_absent_without_a_gripper():
    assert isinstance(build().cell.gripper, CanFingers)
    assert build(MIT_SIM).cell.gripper is None


def test_a_gripper_sharing_a_joints_can_id_is_refused():
    document = config_document()
    document["gripper"]["can_id"] = 3
    with pytest.raises(Exception, match="duplicate can_id: 3"):
        parse_backend_config("can", document)


async def test_a_move_reaches_the_width_through_the_bus(arm: CanBackend):
    g, emulator = gripper_of(arm)
    result = await arm.gripper_move(0.03, 0.1)
    assert result.success and result.width_m == pytest.approx(0.03, abs=g.position_tolerance_rad * abs(g.width_per_rad_m))
    assert g.width_of(emulator.snapshot(GRIPPER_ID).position_rad) == pytest.approx(0.03, abs=1e-3)


async def test_a_grasp_holds_the_object_squeezing_with_no_more_than_the_force(arm: CanBackend):
    g, emulator = gripper_of(arm)
    emulator.place_obstacle(GRIPPER_ID, low_rad=g.position_of(0.02))  # an object 2 cm wide
    result = await arm.gripper_grasp(0.02, 40.0, 0.1, 0.005, 0.005)
    assert result.success and result.is_grasped
    state = await arm.gripper_state()
    assert state is not None and state.is_grasped
    squeeze = abs(emulator.snapshot(GRIPPER_ID).torque_nm)
    lsb_torque = g.kp_nm_per_rad * g.ranges.position.span / 0xFFFF  # the cap acts on measured (quantised) positions
    assert 0.0 < squeeze <= 40.0 * abs(g.width_per_rad_m) + 4 * lsb_torque


@given(wanted=st.floats(-3, 3), measured=st.floats(-3, 3), velocity=st.floats(-5, 5),
       measured_velocity=st.floats(-5, 5), cap=st.floats(0.01, 4))
def test_the_command_never_pushes_harder_than_the_cap_counting_its_damping(
        wanted: float, measured: float, velocity: float, measured_velocity: float, cap: float) -> None:
    kp, kd = 20.0, 1.0
    damping = kd * (velocity - measured_velocity)
    position = capped_setpoint(wanted, measured, cap, kp, damping)
    assert abs(kp * (position - measured) + damping) <= cap * (1 + 1e-9)


_GRIPPER = build().config.gripper


def frame_pushes(motion_of: Callable[[GripperConfig], ImpedanceFingerMotion], measured_rad: float,
                 measured_velocity: float = 0.0) -> tuple[MotorCommand, float]:
    """One frame of fingers measured at `measured_rad` (gripper position) moving at
    `measured_velocity` under the motion `motion_of` gives: the command, and the torque its whole
    law kp·(setpoint − measured) + kd·(velocity − measured velocity) pushes with."""
    g = _GRIPPER
    assert g is not None
    raw_position = g.direction * measured_rad + g.homing_offset_rad
    actuator = Actuator(-1, g, g.ranges, None, raw_position=raw_position,
                        raw_velocity=g.direction * measured_velocity, reported_at=time.monotonic())
    commands: list[MotorCommand] = []

    def command_frame(target: Actuator, command: MotorCommand) -> OutFrame:
        commands.append(command)
        return OutFrame(target, 0, b"", True)

    fingers = CanFingers(actuator, g, threading.Lock(), command_frame,
                         FingerGuards(lambda: None, lambda: None, lambda: False, lambda: 0.02))
    fingers.motion = motion_of(g)
    fingers.frame()
    (command,) = commands
    return command, (command.kp * (command.position - raw_position)
                     + command.kd * (command.velocity - actuator.raw_velocity))


def test_fingers_blocked_while_their_ramp_still_runs_are_commanded_no_more_than_the_force():
    """The ramp's velocity is fed forward through kd: fingers standing on the object would get it
    on top of the spring's capped push (3.6 N·m squeezed where 1.6 were asked, found by CI)."""
    def closing(g: GripperConfig) -> ImpedanceFingerMotion:  # 0.1 m/s from the object to shut, half-way there
        speed, blocked_at = 0.1 / abs(g.width_per_rad_m), g.position_of(0.02)
        began = time.monotonic() - abs(blocked_at - g.position_of(0.0)) / speed / 2
        return ImpedanceFingerMotion(Ramp(blocked_at, g.position_of(0.0), speed, began), GRASP_TORQUE_NM, grasp=True)

    assert _GRIPPER is not None
    command, pushed = frame_pushes(closing, _GRIPPER.position_of(0.02))
    assert command.velocity != 0.0  # the ramp still runs
    assert 0.0 < abs(pushed) <= GRASP_TORQUE_NM * (1 + 1e-9)


async def test_a_grasp_that_closes_past_the_band_fails_naming_the_width(arm: CanBackend):
    gripper_of(arm)[1].place_obstacle(GRIPPER_ID, low_rad=gripper_of(arm)[0].position_of(0.03))
    result = await arm.gripper_grasp(0.01, 20.0, 0.1, 0.002, 0.002)
    assert not result.success and not result.is_grasped and "outside" in result.detail


async def test_a_force_above_the_torque_limit_is_refused_and_nothing_moves(arm: CanBackend):
    emulator = gripper_of(arm)[1]
    before = emulator.snapshot(GRIPPER_ID).position_rad
    with pytest.raises(BackendError, match="torque limit"):
        await arm.gripper_grasp(0.02, 1000.0, 0.1, 0.005, 0.005)
    assert emulator.snapshot(GRIPPER_ID).position_rad == pytest.approx(before, abs=1e-3)


async def test_a_stop_freezes_the_fingers_where_they_are(arm: CanBackend):
    g, emulator = gripper_of(arm)
    task = asyncio.create_task(arm.gripper_move(0.0, 0.02))
    await wait_until(lambda: _async_true(g.width_of(emulator.snapshot(GRIPPER_ID).position_rad) < 0.07))
    await arm.stop()
    result = await task
    assert not result.success and result.detail == "stopped"
    frozen_at = await width(arm)
    await asyncio.sleep(0.2)
    assert frozen_at > 0.01
    assert await width(arm) == pytest.approx(frozen_at, abs=1e-3)


async def test_an_estop_damps_the_gripper_with_the_arm(arm: CanBackend):
    spy = Spy(arm)
    try:
        arm.emergency_stop_now()
        await wait_until(lambda: _async_true(any(s.damping and s.motor == GRIPPER_ID for s in spy.seen())))
        with pytest.raises(BackendError, match="damped"):
            await arm.gripper_move(0.02, 0.1)
    finally:
        spy.close()


async def test_the_gripper_state_carries_the_time_its_reading_arrived_not_the_time_it_was_read(arm: CanBackend):
    _, emulator = gripper_of(arm)
    fresh = await arm.gripper_state()
    assert fresh is not None and time.monotonic() - fresh.stamp < 0.5
    emulator.silence(GRIPPER_ID)  # its replies stop: the last reading ages
    last, since = (await arm.gripper_state()).stamp, time.monotonic()
    while time.monotonic() - since < 0.3:  # replies still on their way (a loaded host delays them): settle first
        await anyio.sleep(0.05)
        if (latest := (await arm.gripper_state()).stamp) != last:
            last, since = latest, time.monotonic()
    await anyio.sleep(0.2)
    aged = await arm.gripper_state()
    assert aged is not None and aged.stamp == last and time.monotonic() - aged.stamp >= 0.2


def test_fingers_blocked_where_their_ramp_starts_are_commanded_no_more_than_the_force():
    """An object as wide as the open fingers: the cap wants a setpoint past the open end to cancel
    kd·v, the travel clamp keeps it at the end, and the command pushed with kd·v (2.5 N·m where a
    grasp asked for 1.6) while the ramp ran; the velocity fed forward is capped instead."""
    def closing(g: GripperConfig) -> ImpedanceFingerMotion:
        ramp = Ramp(g.position_of(g.max_width_m), g.position_of(0.0), 0.1 / abs(g.width_per_rad_m), time.monotonic() - 0.05)
        return ImpedanceFingerMotion(ramp, GRASP_TORQUE_NM, grasp=True)

    assert _GRIPPER is not None
    command, pushed = frame_pushes(closing, _GRIPPER.position_of(_GRIPPER.max_width_m))
    assert command.velocity != 0.0  # still pushing toward closed
    assert 0.0 < abs(pushed) <= GRASP_TORQUE_NM * (1 + 1e-9)


@given(measured=st.floats(-0.5, 2.5), measured_velocity=st.floats(-5, 5), start=st.floats(0, 2),
       target=st.floats(0, 2), elapsed=st.floats(0, 2), force_n=st.floats(1, 100))
def test_whatever_the_fingers_do_a_frame_pushes_no_harder_than_its_cap(
        measured: float, measured_velocity: float, start: float, target: float, elapsed: float, force_n: float) -> None:
    """The whole law kp·(setpoint − measured) + kd·(velocity − measured velocity), after the
    travel clamp, for fingers anywhere (even past an end of their travel) at any speed."""
    assert _GRIPPER is not None
    cap = min(force_n * abs(_GRIPPER.width_per_rad_m), _GRIPPER.torque_limit_nm)

    def motion(g: GripperConfig) -> ImpedanceFingerMotion:
        return ImpedanceFingerMotion(Ramp(start, target, 0.1 / abs(g.width_per_rad_m), time.monotonic() - elapsed),
                                     cap, grasp=True)

    _, pushed = frame_pushes(motion, measured, measured_velocity)
    assert abs(pushed) <= cap * (1 + 1e-6) + 1e-9
