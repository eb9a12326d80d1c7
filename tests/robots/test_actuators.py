"""A robot profile's `actuators` section: each arm joint's reflected rotor inertia (armature), as the
MuJoCo backend simulates its drives. Strict: only the arm's joints, every one of them, positive
finite values, no unknown keys."""

from __future__ import annotations

import math
from typing import Any

import pytest
from pydantic import ValidationError

from armwarden.robots import RobotProfile, load_profile

FR3 = load_profile("fr3")
ARM = tuple(FR3.ready_joint_positions or ())


def _with_actuators(actuators: Any) -> dict[str, Any]:
    return FR3.model_dump() | {"actuators": actuators}


def _fr3_actuators() -> dict[str, dict[str, float]]:
    return {joint: {"armature_kg_m2": 0.1} for joint in ARM}


def test_the_fr3_profile_carries_each_arm_joints_armature_by_drive_size() -> None:
    assert FR3.actuators is not None
    assert tuple(FR3.actuators) == ARM
    # the large drives (87 N·m, joints 1-4) 0.1 kg·m², the small ones (12 N·m, joints 5-7) 0.05
    assert [entry.armature_kg_m2 for entry in FR3.actuators.values()] == [0.1] * 4 + [0.05] * 3


def test_a_profile_without_actuators_is_valid() -> None:
    assert RobotProfile.model_validate(_with_actuators(None)).actuators is None


def test_an_actuator_for_a_joint_that_is_not_the_arms_is_refused() -> None:
    actuators = _fr3_actuators() | {"fr3_finger_joint1": {"armature_kg_m2": 0.01}}
    with pytest.raises(ValidationError, match=r"actuators name joints that are not the arm's: fr3_finger_joint1"):
        RobotProfile.model_validate(_with_actuators(actuators))


def test_an_arm_joint_without_an_actuator_is_refused() -> None:
    actuators = _fr3_actuators()
    del actuators["fr3_joint7"]
    with pytest.raises(ValidationError, match=r"actuators lack arm joints: fr3_joint7"):
        RobotProfile.model_validate(_with_actuators(actuators))


@pytest.mark.parametrize("armature", [0.0, -0.1, math.nan, math.inf])
def test_an_armature_that_is_not_positive_and_finite_is_refused(armature: float) -> None:
    actuators = _fr3_actuators() | {"fr3_joint1": {"armature_kg_m2": armature}}
    with pytest.raises(ValidationError, match=r"actuators\.fr3_joint1\.armature_kg_m2"):
        RobotProfile.model_validate(_with_actuators(actuators))


def test_an_unknown_key_in_an_actuator_is_refused() -> None:
    actuators = _fr3_actuators() | {"fr3_joint1": {"armature_kg_m2": 0.1, "gear_ratio": 100.0}}
    with pytest.raises(ValidationError, match=r"actuators\.fr3_joint1\.gear_ratio"):
        RobotProfile.model_validate(_with_actuators(actuators))


def test_an_actuator_without_its_armature_is_refused() -> None:
    actuators = _fr3_actuators() | {"fr3_joint1": {}}
    with pytest.raises(ValidationError, match=r"actuators\.fr3_joint1\.armature_kg_m2"):
        RobotProfile.model_validate(_with_actuators(actuators))
