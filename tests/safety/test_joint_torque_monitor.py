"""The force monitor reading contact from the motors' joint torques: per-joint limits, the baseline
rule, and failing closed on a torque stream that is missing, NaN, frozen or stale — exactly as on a
wrench sensor's stream."""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Sequence

import anyio
import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports]
import pytest

from armwarden.core.errors import BackendError
from armwarden.core.state import JointState
from armwarden.robot.model import RobotModel
from armwarden.safety.contact_observer import ContactObserver, ObserverSettings
from armwarden.safety.contact_source import ContactEstimate, JointTorqueContact, choose_contact_source
from armwarden.safety.force import JOINT_TORQUE_RISE_ALLOWANCE_NM, ForceLimits, ForceMonitor, ForceViolation
from tests.helpers import FakeClock

JOINT_LIMITS = (10.0, 10.0, 8.0, 8.0, 5.0, 5.0, 4.0)
#: the force/torque limits at their largest: these tests are about the joints (one test lowers them)
LIMITS = ForceLimits(max_force_n=150.0, max_torque_nm=30.0, monitor_rate_hz=1000.0, wrench_timeout_s=0.05,
                     max_external_torque_nm=JOINT_LIMITS)
DT_S = 0.005


class TorqueScript:
    """Joint states of an arm held still at `q`: each read advances the fake clock by `DT_S` and
    reports efforts g(q) − (the scripted external torque), stamped now; or a ready-made item
    (a JointState, an exception to raise). After the script the last entry repeats."""

    def __init__(self, robot: RobotModel, q: np.ndarray, clock: FakeClock, script: Sequence[object]) -> None:
        self.robot, self.q, self.clock, self.reads = robot, q, clock, 0
        self.script: list[object] = list(script)
        self.gravity = pin.computeGeneralizedGravity(robot.model, robot.model.createData(), q).copy()

    def state(self, efforts: np.ndarray | None, stamp: float | None = None) -> JointState:
        return JointState(tuple(self.robot.joint_names), self.q, np.zeros(7), self.clock.now if stamp is None else stamp,
                          efforts)

    async def __call__(self) -> JointState:
        item = self.script[min(self.reads, len(self.script) - 1)]
        self.reads += 1
        self.clock.now += DT_S
        if isinstance(item, BaseException):
            raise item
        if isinstance(item, JointState):
            return item
        external = np.asarray(item, dtype=float)
        return self.state(self.gravity - external)  # the motors hold less where something pushes


def latest_only(read_joint_state: Callable[[], Awaitable[JointState]]) -> Callable[[float | None], Awaitable[tuple[JointState, ...]]]:
    """A one-sample reader (a `TorqueScript`) in the shape `JointTorqueContact` reads: each call
    gives one sample, whatever it was asked for."""

    async def read(_since: float | None) -> tuple[JointState, ...]:
        return (await read_joint_state(),)

    return read


def joint_monitor(robot: RobotModel, q: np.ndarray, script: Sequence[object],
                  carried: tuple[float | None, ...] | None = None,
                  limits: ForceLimits = LIMITS) -> tuple[ForceMonitor, TorqueScript]:
    clock = FakeClock(10.0)
    source = TorqueScript(robot, q, clock, script)
    observer = ContactObserver(robot.model, robot.tcp_frame, robot.base_frame,
                               ObserverSettings(50.0, (0.0,) * 7, (0.0,) * 7))
    contact = JointTorqueContact(latest_only(source), observer, robot.joint_names)
    return ForceMonitor(limits, contact.read, clock=clock, carried_joint_ceiling=carried), source


def external(joint: int, torque_nm: float) -> np.ndarray:
    values = np.zeros(7)
    values[joint] = torque_nm
    return values


async def run_until_violation(mon: ForceMonitor) -> ForceViolation:
    with anyio.fail_after(5):  # a safety net for the test itself, never reached when correct
        return await mon.run()


@pytest.mark.anyio
async def test_an_external_torque_over_a_joints_limit_stops_the_motion(robot: RobotModel, ready: np.ndarray) -> None:
    mon, _ = joint_monitor(robot, ready, [external(1, 0.0)] * 3 + [external(1, 40.0)])
    assert not isinstance(await mon.baseline(), ForceViolation)
    violation = await run_until_violation(mon)
    assert violation.kind == "joint_torque_limit"
    assert "joint 2" in violation.detail and "limit of 10 N·m" in violation.detail
    assert violation.external_torques_nm is not None and violation.external_torques_nm[1] > 10.0
    assert violation.to_dict()["external_torques_nm"][1] == pytest.approx(violation.external_torques_nm[1])


@pytest.mark.anyio
async def test_torques_under_every_limit_do_not_stop(robot: RobotModel, ready: np.ndarray) -> None:
    under = np.array(JOINT_LIMITS) * 0.8 * np.array([1, -1, 1, -1, 1, -1, 1])
    mon, _ = joint_monitor(robot, ready, [under])
    await mon.baseline()
    for _ in range(50):
        assert await mon.check_once() is None
    assert mon.max_observed_external_torques_nm is not None
    np.testing.assert_allclose(mon.max_observed_external_torques_nm, np.abs(under), atol=1e-6)


@pytest.mark.anyio
async def test_a_joint_state_without_measured_torques_fails_closed(robot: RobotModel, ready: np.ndarray) -> None:
    clock = FakeClock(10.0)
    source = TorqueScript(robot, ready, clock, [])
    source.script = [source.state(None)]
    mon = ForceMonitor(LIMITS, JointTorqueContact(latest_only(source), mon_observer(robot), robot.joint_names).read, clock=clock)
    found = await mon.baseline()
    assert isinstance(found, ForceViolation) and found.kind == "wrench_missing"
    assert "no measured joint torques" in found.detail


def mon_observer(robot: RobotModel) -> ContactObserver:
    return ContactObserver(robot.model, robot.tcp_frame, robot.base_frame, ObserverSettings(50.0, (0.0,) * 7, (0.0,) * 7))


@pytest.mark.anyio
async def test_a_nan_torque_mid_motion_fails_closed_as_an_invalid_reading(robot: RobotModel,
                                                                          ready: np.ndarray) -> None:
    mon, source = joint_monitor(robot, ready, [external(0, 0.0)] * 3)
    await mon.baseline()
    assert await mon.check_once() is None
    efforts = source.gravity.copy()
    efforts[3] = np.nan
    source.script = [source.state(efforts, stamp=source.clock.now + DT_S)]
    source.reads = 0
    violation = await mon.check_once()
    assert violation is not None and violation.kind == "wrench_invalid"


@pytest.mark.anyio
async def test_a_torque_stream_whose_stamp_stops_advancing_fails_closed_as_frozen(robot: RobotModel,
                                                                                  ready: np.ndarray) -> None:
    clock = FakeClock(10.0)
    source = TorqueScript(robot, ready, clock, [])
    frozen = source.state(source.gravity, stamp=10.0)
    source.script = [frozen]
    mon = ForceMonitor(LIMITS, JointTorqueContact(latest_only(source), mon_observer(robot), robot.joint_names).read, clock=clock)
    await mon.baseline()
    violation = await run_until_violation(mon)
    assert violation.kind in ("wrench_frozen", "wrench_stale")
    assert clock.now - 10.0 > LIMITS.wrench_timeout_s


@pytest.mark.anyio
async def test_an_old_joint_state_fails_closed_as_stale(robot: RobotModel, ready: np.ndarray) -> None:
    clock = FakeClock(10.0)
    source = TorqueScript(robot, ready, clock, [])
    source.script = [source.state(source.gravity, stamp=9.0)]  # a second old when first read
    mon = ForceMonitor(LIMITS, JointTorqueContact(latest_only(source), mon_observer(robot), robot.joint_names).read, clock=clock)
    found = await mon.baseline()
    assert isinstance(found, ForceViolation) and found.kind == "wrench_stale"


@pytest.mark.anyio
async def test_resting_above_a_joint_limit_allows_moving_away_but_not_pressing_harder(
        robot: RobotModel, ready: np.ndarray) -> None:
    resting = external(1, 12.0)  # over joint 2's 10 N·m, under twice it
    mon, source = joint_monitor(robot, ready, [resting])
    await mon.baseline()
    assert not mon.baseline_excessive
    thresholds = mon.joint_torque_thresholds_nm
    assert thresholds is not None and thresholds[1] == pytest.approx(12.0 + JOINT_TORQUE_RISE_ALLOWANCE_NM, abs=1e-6)
    assert thresholds[0] == JOINT_LIMITS[0]
    source.script = [external(1, 12.0 + 2 * JOINT_TORQUE_RISE_ALLOWANCE_NM)]
    source.reads = 0
    violation = await run_until_violation(mon)
    assert violation.kind == "joint_torque_limit" and "baseline above the 10 N·m limit" in violation.detail
    ceiling = mon.joint_contact_ceiling
    assert ceiling is not None and ceiling[1] == pytest.approx(thresholds[1]) and ceiling[0] is None


@pytest.mark.anyio
async def test_a_carried_joint_ceiling_keeps_small_motions_from_ratcheting_up(robot: RobotModel,
                                                                              ready: np.ndarray) -> None:
    carried = (None, 12.5, None, None, None, None, None)
    mon, _ = joint_monitor(robot, ready, [external(1, 12.4)], carried=carried)
    await mon.baseline()
    thresholds = mon.joint_torque_thresholds_nm
    assert thresholds is not None and thresholds[1] == pytest.approx(12.5)


@pytest.mark.anyio
async def test_a_baseline_over_twice_a_joint_limit_is_not_moved_from(robot: RobotModel, ready: np.ndarray) -> None:
    mon, _ = joint_monitor(robot, ready, [external(4, 10.5)])  # joint 5: limit 5 N·m
    await mon.baseline()
    assert mon.baseline_excessive


@pytest.mark.anyio
async def test_a_force_at_the_tcp_is_held_against_the_force_limit(robot: RobotModel, ready: np.ndarray) -> None:
    data = robot.model.createData()
    tcp = robot.model.getFrameId(robot.tcp_frame)
    jacobian = pin.computeFrameJacobian(robot.model, data, ready, tcp, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    push = jacobian.T @ np.array([0.0, 0.0, -15.0, 0.0, 0.0, 0.0])  # 15 N down at the TCP
    assert np.all(np.abs(push) < np.array(JOINT_LIMITS))  # under every joint's limit: only the wrench catches it
    limits = ForceLimits(max_force_n=12.0, max_torque_nm=10.0, monitor_rate_hz=1000.0, wrench_timeout_s=0.05,
                         max_external_torque_nm=JOINT_LIMITS)
    mon, _ = joint_monitor(robot, ready, [np.zeros(7)] * 2 + [push], limits=limits)
    await mon.baseline()
    violation = await run_until_violation(mon)
    assert violation.kind == "force_limit" and 12.0 < (violation.force_n or 0.0) <= 15.0


def test_auto_prefers_the_sensor_and_falls_back_to_joint_torques() -> None:
    assert choose_contact_source("auto", True, True, True) == "sensor"
    assert choose_contact_source("auto", False, True, True) == "joint_torques"
    assert choose_contact_source("auto", False, True, False) is None  # torques, but no limits for them
    assert choose_contact_source("auto", False, False, True) is None


def test_an_explicit_source_is_used_only_where_the_backend_has_it() -> None:
    assert choose_contact_source("sensor", False, True, True) is None
    assert choose_contact_source("joint_torques", True, True, True) == "joint_torques"
    assert choose_contact_source("joint_torques", True, False, True) is None


@pytest.mark.anyio
async def test_a_nan_sample_is_never_fed_to_the_observer(robot: RobotModel, ready: np.ndarray) -> None:
    """After a NaN sample the next good one reads clean: the observer's state was not poisoned."""
    clock = FakeClock(10.0)
    source = TorqueScript(robot, ready, clock, [])
    nan = source.gravity.copy()
    nan[2] = np.nan
    source.script = [source.state(source.gravity, stamp=10.005), source.state(nan, stamp=10.010),
                     source.state(source.gravity, stamp=10.015)]
    contact = JointTorqueContact(latest_only(source), mon_observer(robot), robot.joint_names)
    first, unusable, after = await contact.read(), await contact.read(), await contact.read()
    assert isinstance(first, ContactEstimate) and isinstance(unusable, ContactEstimate)
    assert isinstance(after, ContactEstimate)
    assert not np.all(np.isfinite(unusable.force))
    assert np.all(np.isfinite(after.force)) and np.allclose(after.external_torques_nm, 0.0, atol=1e-6)


def moving_state(source: TorqueScript, stamp: float, speed: float) -> JointState:
    """The arm at `q` moving at `speed` rad/s on every joint, its motors holding gravity only (a
    momentum jump no torque explains, as a stalled poll sees an acceleration it slept through)."""
    return JointState(tuple(source.robot.joint_names), source.q, np.full(7, speed), stamp, source.gravity)


@pytest.mark.anyio
async def test_an_interval_too_long_to_integrate_is_skipped_not_read_as_contact(robot: RobotModel,
                                                                                ready: np.ndarray) -> None:
    source = TorqueScript(robot, ready, FakeClock(10.0), [])
    source.script = [source.state(source.gravity, stamp=10.0), moving_state(source, 10.0 + 0.05, 0.5)]
    contact = JointTorqueContact(latest_only(source), mon_observer(robot), robot.joint_names)
    await contact.read()
    after_stall = await contact.read()
    assert isinstance(after_stall, ContactEstimate)
    assert np.allclose(after_stall.external_torques_nm, 0.0, atol=1e-6) and contact.unobserved_s == pytest.approx(0.05)


@pytest.mark.anyio
async def test_the_same_jump_inside_a_short_interval_is_read_as_contact(robot: RobotModel, ready: np.ndarray) -> None:
    """(The rule above skips only what cannot be integrated: a jump 5 ms apart is a contact.)"""
    source = TorqueScript(robot, ready, FakeClock(10.0), [])
    source.script = [source.state(source.gravity, stamp=10.0), moving_state(source, 10.005, 0.5)]
    contact = JointTorqueContact(latest_only(source), mon_observer(robot), robot.joint_names)
    await contact.read()
    reading = await contact.read()
    assert isinstance(reading, ContactEstimate) and np.max(np.abs(reading.external_torques_nm)) > 10.0


@pytest.mark.anyio
async def test_a_moving_arm_the_observer_cannot_integrate_for_long_fails_closed(robot: RobotModel,
                                                                               ready: np.ndarray) -> None:
    source = TorqueScript(robot, ready, FakeClock(10.0), [])
    source.script = [moving_state(source, 10.0 + 0.04 * k, 0.5) for k in range(5)]
    contact = JointTorqueContact(latest_only(source), mon_observer(robot), robot.joint_names, max_unobserved_s=0.1)
    readings = [await contact.read() for _ in range(5)]
    assert all(np.all(np.isfinite(r.force)) for r in readings[:3] if r is not None)
    last = readings[-1]
    assert last is not None and not np.all(np.isfinite(last.force))  # unusable: the monitor stops the arm


@pytest.mark.anyio
async def test_long_intervals_at_rest_are_not_unobserved_time(robot: RobotModel, ready: np.ndarray) -> None:
    source = TorqueScript(robot, ready, FakeClock(10.0), [])
    source.script = [source.state(source.gravity, stamp=10.0 + 0.5 * k) for k in range(6)]
    contact = JointTorqueContact(latest_only(source), mon_observer(robot), robot.joint_names, max_unobserved_s=0.1)
    readings = [await contact.read() for _ in range(6)]
    assert all(r is not None and np.all(np.isfinite(r.force)) for r in readings)


def pushed_states(source: TorqueScript, count: int, start: float = 10.0) -> list[JointState]:
    """`count` samples 1 ms apart of the held arm with 3 N·m pushing on joint 2 from the second on."""
    return [source.state(source.gravity - (external(1, 3.0) if k else 0.0), stamp=start + 0.001 * k)
            for k in range(count)]


class Batches:
    """A `read_joint_states_since` over scripted batches; remembers what each read asked for."""

    def __init__(self, batches: Sequence[Sequence[JointState]]) -> None:
        self.batches, self.asked = list(batches), []

    async def __call__(self, since: float | None) -> tuple[JointState, ...]:
        self.asked.append(since)
        return tuple(self.batches.pop(0))


@pytest.mark.anyio
async def test_a_read_integrates_every_sample_since_the_last_as_one_read_per_sample_would(
        robot: RobotModel, ready: np.ndarray) -> None:
    source = TorqueScript(robot, ready, FakeClock(10.0), [])
    states = pushed_states(source, 11)
    one_each = JointTorqueContact(Batches([[s] for s in states]), mon_observer(robot), robot.joint_names)
    readings_alone = [await one_each.read() for _ in states]
    alone = readings_alone[-1]
    batches = Batches([states[:1], states[1:6], states[6:]])
    in_batches = JointTorqueContact(batches, mon_observer(robot), robot.joint_names)
    readings = [await in_batches.read() for _ in range(3)]
    assert isinstance(alone, ContactEstimate) and isinstance(readings[-1], ContactEstimate)
    np.testing.assert_allclose(readings[-1].external_torques_nm, alone.external_torques_nm, atol=1e-12)
    assert readings[-1].stamp == states[-1].stamp and in_batches.samples_integrated == len(states)
    assert batches.asked == [None, states[0].stamp, states[5].stamp]  # each read asks for what it has not seen


@pytest.mark.anyio
async def test_a_nan_sample_inside_a_read_fails_that_read_closed(robot: RobotModel, ready: np.ndarray) -> None:
    source = TorqueScript(robot, ready, FakeClock(10.0), [])
    states = pushed_states(source, 6)
    nan = source.gravity.copy()
    nan[4] = np.nan
    states[3] = source.state(nan, stamp=states[3].stamp)
    contact = JointTorqueContact(Batches([states[:1], states[1:]]), mon_observer(robot), robot.joint_names)
    await contact.read()
    reading = await contact.read()
    assert isinstance(reading, ContactEstimate) and not np.all(np.isfinite(reading.external_torques_nm))


@pytest.mark.anyio
async def test_a_read_that_returns_nothing_is_a_backend_error(robot: RobotModel, ready: np.ndarray) -> None:
    contact = JointTorqueContact(Batches([[]]), mon_observer(robot), robot.joint_names)
    with pytest.raises(BackendError, match="no joint state"):
        await contact.read()


@pytest.mark.anyio
async def test_an_interval_too_long_on_the_arms_time_is_skipped_at_any_speedup(robot: RobotModel,
                                                                                ready: np.ndarray) -> None:
    """A simulator at speedup 10 moves the arm 50 ms between stamps 5 ms apart: the jump the test
    above skips at speedup 1 is skipped here too (it read 10.6 N·m when the cap was on the stamps)."""
    source = TorqueScript(robot, ready, FakeClock(10.0), [])
    source.script = [source.state(source.gravity, stamp=10.0), moving_state(source, 10.0 + 0.005, 0.5)]
    contact = JointTorqueContact(latest_only(source), mon_observer(robot), robot.joint_names, time_scale=10.0)
    await contact.read()
    after_stall = await contact.read()
    assert isinstance(after_stall, ContactEstimate)
    assert np.allclose(after_stall.external_torques_nm, 0.0, atol=1e-6) and contact.unobserved_s == pytest.approx(0.05)


@pytest.mark.anyio
async def test_a_moving_arm_unobserved_for_long_on_its_own_time_fails_closed_at_speedup(robot: RobotModel,
                                                                                       ready: np.ndarray) -> None:
    """At speedup 2.5, stamps 16 ms apart are 40 ms of motion each: the same as the test above."""
    source = TorqueScript(robot, ready, FakeClock(10.0), [])
    source.script = [moving_state(source, 10.0 + 0.016 * k, 0.5) for k in range(5)]
    contact = JointTorqueContact(latest_only(source), mon_observer(robot), robot.joint_names, time_scale=2.5,
                                 max_unobserved_s=0.1)
    readings = [await contact.read() for _ in range(5)]
    last = readings[-1]
    assert last is not None and not np.all(np.isfinite(last.force))
