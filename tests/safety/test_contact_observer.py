"""The momentum observer against an arm simulated by Pinocchio's forward dynamics: it recovers a
known external torque, sees nothing when nothing touches, and does not mistake a declared payload
or allowed friction for a contact."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports]
import pytest

from armwarden.core.errors import ConfigurationError
from armwarden.robot.model import RobotModel
from armwarden.safety.contact_observer import ContactObserver, ObserverSettings

GAIN = 50.0
SIM_STEP_S = 0.0005


@dataclass
class SimulatedArm:
    """An arm moved by Pinocchio's `aba` under a computed-torque tracking law (PD scaled by the mass
    matrix, gravity fed forward); records what its motors apply (the torque a real motor reports)."""

    model: pin.Model
    q: np.ndarray
    v: np.ndarray
    t: float = 0.0
    external: Callable[[float, np.ndarray], np.ndarray] | None = None
    friction: Callable[[np.ndarray], np.ndarray] | None = None
    tau: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.data = self.model.createData()
        self.start = self.q.copy()
        self.tau = pin.computeGeneralizedGravity(self.model, self.data, self.q).copy()  # at rest, on target

    def target(self, t: float) -> np.ndarray:
        return self.start + 0.3 * np.sin(1.5 * t) * np.linspace(1.0, 0.4, self.model.nv)

    def step(self) -> None:
        gravity = pin.computeGeneralizedGravity(self.model, self.data, self.q)
        mass = pin.crba(self.model, self.data, self.q)
        mass = np.triu(mass) + np.triu(mass, 1).T
        tau = gravity + mass @ (400.0 * (self.target(self.t) - self.q) - 40.0 * self.v)
        applied = tau.copy()
        if self.external is not None:
            applied += self.external(self.t, self.q)
        if self.friction is not None:
            applied -= self.friction(self.v)
        acceleration = pin.aba(self.model, self.data, self.q, self.v, applied)
        self.v = self.v + SIM_STEP_S * acceleration
        self.q = self.q + SIM_STEP_S * self.v
        self.t += SIM_STEP_S
        self.tau = tau

    def run(self, observer: ContactObserver, duration_s: float, sample_every: Callable[[int], int] = lambda _: 10,
            ) -> list[tuple[float, np.ndarray]]:
        """Simulate for `duration_s`, feeding the observer every few steps; the residuals it gave."""
        residuals, sample = [], 0
        countdown = 0
        while self.t < duration_s:
            if countdown <= 0:
                assert self.tau is not None
                residuals.append((self.t, observer.update(self.q, self.v, self.tau, self.t)))
                countdown = sample_every(sample)
                sample += 1
            countdown -= 1
            self.step()
        return residuals


def settings(nv: int, **overrides: object) -> ObserverSettings:
    values: dict = {"gain_per_s": GAIN, "coulomb_nm": (0.0,) * nv, "viscous_nms": (0.0,) * nv}
    values.update(overrides)
    return ObserverSettings(**values)


@pytest.fixture
def observer(robot: RobotModel) -> ContactObserver:
    return ContactObserver(robot.model, robot.tcp_frame, robot.base_frame, settings(robot.model.nv))


@pytest.fixture
def arm(robot: RobotModel, ready: np.ndarray) -> SimulatedArm:
    return SimulatedArm(robot.model, ready.copy(), np.zeros(robot.model.nv))


def test_a_moving_arm_that_touches_nothing_shows_almost_no_external_torque(arm: SimulatedArm,
                                                                            observer: ContactObserver) -> None:
    residuals = arm.run(observer, 1.0)
    assert max(np.abs(r).max() for _, r in residuals) < 0.1  # N·m: only the integration schemes differ


def test_a_step_of_external_torque_is_recovered_joint_by_joint(arm: SimulatedArm, observer: ContactObserver) -> None:
    push = np.array([4.0, -6.0, 2.0, 5.0, -1.0, 1.5, 0.8])
    arm.external = lambda t, _q: push if t >= 0.2 else np.zeros(7)
    residuals = arm.run(observer, 0.2 + 6 / GAIN)
    np.testing.assert_allclose(residuals[-1][1], push, atol=0.1)


def test_the_residual_rises_like_a_first_order_filter_of_bandwidth_k(arm: SimulatedArm,
                                                                      observer: ContactObserver) -> None:
    push = np.array([0.0, 10.0, 0, 0, 0, 0, 0])
    arm.external = lambda t, _q: push if t >= 0.2 else np.zeros(7)
    residuals = arm.run(observer, 0.2 + 1 / GAIN, sample_every=lambda _: 2)
    assert residuals[-1][1][1] == pytest.approx(10.0 * (1 - np.exp(-1)), abs=0.3)


def test_irregular_sample_intervals_do_not_bias_the_estimate(arm: SimulatedArm, observer: ContactObserver) -> None:
    push = np.array([3.0, 3.0, -3.0, 3.0, 1.0, -1.0, 0.5])
    arm.external = lambda t, _q: push if t >= 0.1 else np.zeros(7)
    spacing = np.random.default_rng(3).integers(1, 60, size=10_000)  # 0.5 ms to 30 ms apart
    residuals = arm.run(observer, 0.1 + 8 / GAIN, sample_every=lambda k: int(spacing[k]))
    np.testing.assert_allclose(residuals[-1][1], push, atol=0.15)


def test_a_contact_present_before_the_first_sample_shows_at_once(arm: SimulatedArm, observer: ContactObserver) -> None:
    push = np.array([0.0, 8.0, 0.0, -4.0, 0.0, 0.0, 0.0])
    arm.external = lambda _t, _q: push
    arm.target = lambda _t: arm.start  # type: ignore[method-assign]  # holding still, pressed on
    for _ in range(4000):
        arm.step()
    assert arm.tau is not None
    first = observer.update(arm.q, arm.v, arm.tau, arm.t)
    np.testing.assert_allclose(first, push, atol=0.05)


def test_a_declared_payload_is_not_a_contact(robot: RobotModel, ready: np.ndarray) -> None:
    heavy = pin.Model(robot.model)
    frame = heavy.frames[heavy.getFrameId(robot.tcp_frame)]
    heavy.inertias[frame.parentJoint] = heavy.inertias[frame.parentJoint] + pin.Inertia(
        1.0, frame.placement.act(np.array([0.0, 0.0, 0.05])), np.zeros((3, 3)))
    arm = SimulatedArm(heavy, ready.copy(), np.zeros(7))
    declared = ContactObserver(robot.model, robot.tcp_frame, robot.base_frame,
                               settings(7, payload_kg=1.0, payload_com_m=(0.0, 0.0, 0.05)))
    residuals = arm.run(declared, 0.6)
    assert max(np.abs(r).max() for _, r in residuals) < 0.1


def test_an_undeclared_payload_reads_as_its_weight(robot: RobotModel, ready: np.ndarray) -> None:
    heavy = pin.Model(robot.model)
    frame = heavy.frames[heavy.getFrameId(robot.tcp_frame)]
    heavy.inertias[frame.parentJoint] = heavy.inertias[frame.parentJoint] + pin.Inertia(
        1.0, frame.placement.act(np.zeros(3)), np.zeros((3, 3)))
    arm = SimulatedArm(heavy, ready.copy(), np.zeros(7))
    observer = ContactObserver(robot.model, robot.tcp_frame, robot.base_frame, settings(7))
    arm.target = lambda _t: arm.start  # type: ignore[method-assign]
    residual = arm.run(observer, 0.5)[-1][1]
    wrench = observer.tcp_wrench(arm.q, residual)
    np.testing.assert_allclose(wrench.force_n, [0.0, 0.0, -9.81], atol=0.1)


def test_friction_the_policy_allows_for_is_not_a_contact(robot: RobotModel, ready: np.ndarray) -> None:
    # (the light wrist joints get less: explicit Euler on a stiff friction law would chatter)
    coulomb, viscous = np.array([0.8, 0.8, 0.8, 0.8, 0.2, 0.2, 0.1]), np.full(7, 0.3)
    arm = SimulatedArm(robot.model, ready.copy(), np.zeros(7))
    arm.friction = lambda v: coulomb * np.tanh(v / 0.02) + viscous * v
    unaware = ContactObserver(robot.model, robot.tcp_frame, robot.base_frame, settings(7))
    aware = ContactObserver(robot.model, robot.tcp_frame, robot.base_frame,
                            settings(7, coulomb_nm=tuple(coulomb), viscous_nms=tuple(viscous)))
    residuals_unaware, residuals_aware = [], []
    while arm.t < 1.0:
        assert arm.tau is not None
        residuals_unaware.append(unaware.update(arm.q, arm.v, arm.tau, arm.t))
        residuals_aware.append(aware.update(arm.q, arm.v, arm.tau, arm.t))
        for _ in range(10):
            arm.step()
    assert max(np.abs(r).max() for r in residuals_unaware) > 0.7
    assert max(np.abs(r).max() for r in residuals_aware) < 0.1


def test_a_force_at_the_tcp_is_recovered_as_a_wrench(robot: RobotModel, ready: np.ndarray,
                                                     observer: ContactObserver) -> None:
    data = robot.model.createData()
    tcp = robot.model.getFrameId(robot.tcp_frame)
    jacobian = pin.computeFrameJacobian(robot.model, data, ready, tcp, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    wrench = np.array([5.0, -12.0, 8.0, 0.4, 0.0, -0.3])
    estimate = observer.tcp_wrench(ready, jacobian.T @ wrench)
    np.testing.assert_allclose(estimate.force_n, wrench[:3], atol=1e-3)
    np.testing.assert_allclose(estimate.torque_nm, wrench[3:], atol=1e-4)
    assert 1.0 <= estimate.condition < 100.0


def test_the_same_sample_twice_changes_nothing(arm: SimulatedArm, observer: ContactObserver) -> None:
    last_stamp = arm.run(observer, 0.1)[-1][0]
    assert arm.tau is not None
    before = observer.residual
    again = observer.update(arm.q + 0.1, arm.v, arm.tau + 5.0, last_stamp)
    np.testing.assert_array_equal(again, before)


def test_friction_for_the_wrong_number_of_joints_is_refused(robot: RobotModel) -> None:
    with pytest.raises(ConfigurationError, match="one per joint"):
        ContactObserver(robot.model, robot.tcp_frame, robot.base_frame,
                        ObserverSettings(GAIN, (0.0,) * 6, (0.0,) * 6))


def test_the_rotor_inertia_the_policy_declares_is_not_a_contact(robot: RobotModel, ready: np.ndarray) -> None:
    rotors = np.array([0.1, 0.1, 0.1, 0.1, 0.05, 0.05, 0.05])
    with_rotors = pin.Model(robot.model)
    with_rotors.armature = rotors
    unaware = ContactObserver(robot.model, robot.tcp_frame, robot.base_frame, settings(7))
    aware = ContactObserver(robot.model, robot.tcp_frame, robot.base_frame, settings(7, rotor_inertia_kgm2=tuple(rotors)))
    arm = SimulatedArm(with_rotors, ready.copy(), np.zeros(7))
    residuals_unaware, residuals_aware = [], []
    while arm.t < 1.0:
        assert arm.tau is not None
        residuals_unaware.append(unaware.update(arm.q, arm.v, arm.tau, arm.t))
        residuals_aware.append(aware.update(arm.q, arm.v, arm.tau, arm.t))
        for _ in range(10):
            arm.step()
    assert max(np.abs(r).max() for r in residuals_unaware) > 0.1  # accelerating the rotors is not free
    assert max(np.abs(r).max() for r in residuals_aware) < 0.05
