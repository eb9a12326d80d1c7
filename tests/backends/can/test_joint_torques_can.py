"""The CAN backend's measured joint torques (issue 28): each arm actuator's feedback torque
(RobStride type 2, MIT reply) through the calibration's direction, in the published joint state.

Sign and units against a known load: the emulator's actuators carry a gravity load
`gravity_torque_nm`·cos(physical position); an arm at rest reads exactly that load, times the
joint's direction (joint 2 is direction −1 in both examples). Today's emulator has no arm
dynamics (no coupling between joints, no Pinocchio gravity), so the full conformance check
(tests/backends/joint_torque_conformance.py: g(q) at rest, −Jᵀ F under a push) waits for it.

Tolerance: three steps of the reply's torque encoding (16 bits over RobStride's range, 12 bits
over MIT's) and 0.02 N·m for the damping of what motion is left at rest.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest

from armwarden.backends import parse_backend_config
from armwarden.backends.can.backend import CanBackend, create_backend
from armwarden.backends.can.config import Config
from armwarden.backends.can.ranges import Protocol
from tests.backends.can.test_can_backend import MIT_SIM, POLICY, ROBOT, ROBSTRIDE_SIM, build, config_document
from tests.backends.joint_torque_conformance import settled_state
from tests.helpers import run_opened

#: the known loads [N·m] (amplitude of gravity_torque_nm·cos(position)) on joints 1 and 2
LOADS = {"fr3_joint1": 5.0, "fr3_joint2": 4.0}


def loaded(path: Path) -> CanBackend:
    document = config_document(path, joint_torques=True)
    document["simulate"]["dynamics"] = "per_actuator"  # the known 1-DOF loads, not the robot model's arm
    for joint, load in LOADS.items():
        document["simulate"]["loads"][joint]["gravity_torque_nm"] = load
    config = parse_backend_config("can", document)
    assert isinstance(config, Config)
    return create_backend(ROBOT, POLICY, config)


def tolerance_nm(backend: CanBackend, joint: int) -> float:
    ranges = backend.config.joints[joint].ranges
    steps = 0xFFFF if ranges.protocol is Protocol.ROBSTRIDE else 0xFFF
    return 3 * ranges.torque.span / steps + 0.02


@pytest.mark.parametrize("path", [ROBSTRIDE_SIM, MIT_SIM], ids=["robstride", "mit"])
def test_a_joint_held_against_a_known_load_reads_it_with_the_calibration_sign(path: Path) -> None:
    async def scenario(backend: CanBackend) -> None:
        assert backend.capabilities.joint_torques
        emulator = backend.emulator
        assert emulator is not None
        state = await settled_state(backend, still_rad_s=backend.rest_speed_rad_s)
        assert state.efforts is not None
        for j, joint in enumerate(backend.config.joints):
            physical = emulator.snapshot(joint.can_id).position_rad
            load = LOADS.get(joint.name, 0.0) * math.cos(physical)
            assert state.efforts[j] == pytest.approx(joint.direction * load, abs=tolerance_nm(backend, j)), joint.name
        assert backend.config.joints[1].direction == -1 and state.efforts[1] < -1.0  # the sign, not just the size
        assert state.efforts[0] > 1.0

    run_opened(lambda: loaded(path), scenario)


def test_an_actuator_whose_replies_carried_no_torque_reads_nan_and_the_stamp_keeps_its_rule() -> None:
    """NaN is passed on as it is (the monitor fails closed on it), never zero or an older value;
    the state's stamp is still its oldest reply's."""
    backend = build(ROBSTRIDE_SIM, joint_torques=True)
    actuators = backend._actuators
    now = time.monotonic()
    with backend._state_lock:
        for i, a in enumerate(actuators):
            a.raw_position, a.raw_velocity, a.raw_torque, a.reported_at = 0.0, 0.0, 1.5, now - 0.01 * i
        actuators[3].raw_torque = None
    backend._publish()
    state = backend._published
    assert state is not None and state.efforts is not None
    assert math.isnan(state.efforts[3])
    expected = np.array([j.direction * 1.5 for j in backend.config.joints])
    np.testing.assert_array_equal(np.delete(state.efforts, 3), np.delete(expected, 3))
    assert state.stamp == now - 0.01 * (len(actuators) - 1)


def test_before_any_reply_the_state_has_nan_torques_and_stamp_zero() -> None:
    backend = build(ROBSTRIDE_SIM, joint_torques=True)
    backend._publish()
    state = backend._published
    assert state is not None and state.efforts is not None
    assert np.all(np.isnan(state.efforts)) and state.stamp == 0.0


def test_feedback_torques_are_not_the_joints_until_the_config_says_so() -> None:
    """Feedback torques are the arm's only when the config says so (`joint_torques`, which the
    emulated example sets now that its arm has the robot model's dynamics): off, they are not
    offered as the arm's, and contact is not estimated from them."""
    backend = build(ROBSTRIDE_SIM, joint_torques=False)
    assert not backend.capabilities.joint_torques
    backend._publish()
    state = backend._published
    assert state is not None and state.efforts is None
