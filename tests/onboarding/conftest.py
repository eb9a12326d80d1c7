"""Generated arms run through `armwarden init` once per module: fitting is the slow step, and every
test here reads the same outputs."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from armwarden.onboarding import InitOptions, InitResult, run_init
from armwarden.onboarding.fitted import FitSettings
from tests.robot.generated_arm import GeneratedArm, write_random_arm

#: one capsule per link part and a small pair-proof budget: what a test can afford
QUICK_FIT = FitSettings(max_bodies=1, pair_boxes=2000)


@dataclass(frozen=True)
class InitRun:
    arm: GeneratedArm
    options: InitOptions
    result: InitResult


def init_arm(directory: Path, seed: int, n_joints: int, *, gripper: bool = False) -> InitRun:
    arm = write_random_arm(directory / "arm", seed, n_joints, gripper=gripper)
    options = InitOptions(description=arm.urdf, output=directory / "policy" / "arm.yaml", fit=QUICK_FIT)
    return InitRun(arm, options, run_init(options))


@pytest.fixture(scope="module")
def six_joint_arm(tmp_path_factory: pytest.TempPathFactory) -> InitRun:
    return init_arm(tmp_path_factory.mktemp("six"), seed=6, n_joints=6)


@pytest.fixture(scope="module")
def arm_with_fingers(tmp_path_factory: pytest.TempPathFactory) -> InitRun:
    return init_arm(tmp_path_factory.mktemp("fingers"), seed=11, n_joints=5, gripper=True)
