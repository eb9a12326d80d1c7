"""Any arm a policy describes builds in the MuJoCo backend with no per-arm code. (Serving generated
arms end to end, URDF and MJCF, with and without fingers, is tests/onboarding/test_init_mujoco.py.)"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

import armwarden.backends.mujoco  # noqa: F401 - chooses the offscreen GL platform before mujoco loads

pytest.importorskip("mujoco")

from armwarden.backends.mujoco.model import build_model
from armwarden.backends.mujoco.scene import scene_for_policy
from armwarden.onboarding import InitOptions, run_init
from armwarden.policy import load_policy
from armwarden.robot import build_robot
from armwarden.robot.model import resolve_description
from tests.onboarding.conftest import QUICK_FIT
from tests.robot.generated_arm import write_random_arm


def test_an_arm_with_fitted_geometry_builds_without_its_mesh_files(tmp_path: Path) -> None:
    """The fitted capsules replace every shape, so the manufacturer's meshes need not be on disk."""
    arm = write_random_arm(tmp_path / "arm", seed=5, n_joints=4, gripper=True)
    options = InitOptions(description=arm.urdf, output=tmp_path / "policy" / "arm.yaml", fit=QUICK_FIT)
    run_init(options)
    shutil.rmtree(tmp_path / "arm" / "meshes")
    policy = load_policy(options.output)
    cell = build_model(resolve_description(policy.robot.description), build_robot(policy), scene_for_policy(policy))
    assert cell.model.nmesh == 0
    assert cell.arm_joints == tuple(arm.joint_names)
    assert len(cell.finger_joints) == 2
