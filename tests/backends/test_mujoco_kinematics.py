"""Pinocchio and MuJoCo must agree on where the TCP is: the MuJoCo cell is compiled from the same
description the planner and the envelope use, so any drift in the import (frames, fixed joints,
MJCF placements) would make the simulation move a different arm from the one the checks judged.
Every bundled arm with a policy, and generated arms as URDF and as their MJCF twin, are held to
1e-9 m over random configurations within the limits."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import pytest

import armwarden.backends.mujoco  # chooses the offscreen GL platform before mujoco loads

mujoco = pytest.importorskip("mujoco")

import armwarden.robots  # noqa: E402
from armwarden.backends.mujoco.model import build_model  # noqa: E402
from armwarden.backends.mujoco.scene import scene_for_policy  # noqa: E402
from armwarden.onboarding import InitOptions, run_init  # noqa: E402
from armwarden.policy import Policy, load_policy  # noqa: E402
from armwarden.robot import build_robot  # noqa: E402
from armwarden.robot.model import resolve_description  # noqa: E402
from tests.onboarding.conftest import QUICK_FIT  # noqa: E402
from tests.robot.generated_arm import write_mjcf_twin, write_random_arm  # noqa: E402

CONFIGURATIONS = 200
TOLERANCE_M = 1e-9
TOLERANCE_RAD = 1e-9
ROBOTS_DIR = Path(armwarden.robots.__file__).parent
BUNDLED = sorted(path.parent.name for path in ROBOTS_DIR.glob("*/policy.yaml"))


def tcp_pose_in(model: Any, data: Any, frame: str) -> Callable[[], tuple[np.ndarray, np.ndarray]]:
    """Reads the TCP's world position after mj_kinematics: a body (URDF links stay bodies), else a site (MJCF)."""
    try:
        body = model.body(frame).id
    except KeyError:
        site = model.site(frame).id
        return lambda: (data.site_xpos[site].copy(), data.site_xmat[site].reshape(3, 3).copy())
    return lambda: (data.xpos[body].copy(), data.xmat[body].reshape(3, 3).copy())


def assert_tcp_agrees(policy: Policy) -> None:
    """Pinocchio's TCP in the base frame, moved into MuJoCo's world (the description's root frame),
    equals the TCP body's (or site's) pose from mj_kinematics of the compiled cell."""
    robot = build_robot(policy)
    cell = build_model(resolve_description(policy.robot.description), robot, scene_for_policy(policy))
    model = cell.model
    data = mujoco.MjData(model)
    tcp = tcp_pose_in(model, data, robot.tcp_frame)
    pdata = robot.model.createData()
    pin.framesForwardKinematics(robot.model, pdata, pin.neutral(robot.model))
    base = pdata.oMf[robot.frame_id(robot.base_frame)]
    rng = np.random.default_rng(27)
    worst = worst_angle = 0.0
    for _ in range(CONFIGURATIONS):
        q = rng.uniform(robot.lower, robot.upper)
        data.qpos[cell.arm_qpos] = q
        mujoco.mj_kinematics(model, data)
        pose = robot.tcp_pose(q)
        position, rotation = tcp()
        worst = max(worst, float(np.linalg.norm(position - base.act(np.asarray(pose.position, dtype=float)))))
        worst_angle = max(worst_angle, float(np.linalg.norm(pin.log3(rotation.T @ base.rotation @ pose.rotation))))
    assert worst <= TOLERANCE_M, f"TCP positions differ by up to {worst:.3g} m"
    assert worst_angle <= TOLERANCE_RAD, f"TCP orientations differ by up to {worst_angle:.3g} rad"


@pytest.mark.parametrize("name", BUNDLED)
def test_a_bundled_arm_tcp_agrees_with_mujoco_kinematics(name: str) -> None:
    assert_tcp_agrees(load_policy(ROBOTS_DIR / name / "policy.yaml"))


def test_a_generated_urdf_arm_tcp_agrees_with_mujoco_kinematics(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path / "arm", seed=27, n_joints=6)
    options = InitOptions(description=arm.urdf, output=tmp_path / "policy" / "arm.yaml", fit=QUICK_FIT)
    run_init(options)
    assert_tcp_agrees(load_policy(options.output))


def test_a_generated_mjcf_arm_tcp_agrees_with_mujoco_kinematics(tmp_path: Path) -> None:
    """The MJCF twin in the URDF arm's policy: the same joints, frames and fitted links, another format."""
    arm = write_random_arm(tmp_path / "urdf", seed=43, n_joints=5)
    options = InitOptions(description=arm.urdf, output=tmp_path / "policy" / "arm.yaml", fit=QUICK_FIT)
    run_init(options)
    policy = load_policy(options.output)
    twin = str(write_mjcf_twin(arm, tmp_path / "mjcf"))
    # the twin writes limits to 5 decimals; a policy may be stricter than its description, never looser
    limits = {name: limit.model_copy(update={"min": limit.min + 1e-4, "max": limit.max - 1e-4})
              for name, limit in policy.robot.joint_limits.items()}
    robot = policy.robot.model_copy(update={"description": twin, "joint_limits": limits})
    assert_tcp_agrees(policy.model_copy(update={"robot": robot}))
