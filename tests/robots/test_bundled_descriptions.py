"""Every bundled arm's description (each `robots/<arm>/` folder with a description.urdf, found by
listing): Pinocchio and MuJoCo both load it and agree on the TCP, its joints and limits are usable,
its ready pose is inside them, and its SOURCES.md names a licence."""

# pyright: reportAttributeAccessIssue=false
from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from importlib import resources
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import pytest
import yaml

ROBOTS = Path(str(resources.files("armwarden") / "robots"))
ARMS = sorted(path.parent.name for path in ROBOTS.glob("*/description.urdf"))
TOLERANCE_M = 1e-9
SAMPLES = 200
LICENCES = re.compile(r"\b(BSD-3-Clause|BSD-2-Clause|Apache-2\.0|MIT|GPL-3\.0|LGPL-3\.0)\b")


def _profile(arm: str) -> dict:
    """profile.yaml, or the draft an arm waiting for its bundled policy has."""
    for name in ("profile.yaml", "profile.draft.yaml"):
        path = ROBOTS / arm / name
        if path.exists():
            return yaml.safe_load(path.read_text(encoding="utf-8"))
    raise AssertionError(f"robots/{arm} has neither profile.yaml nor profile.draft.yaml")


def _pinocchio(arm: str) -> pin.Model:
    return pin.buildModelFromUrdf(str(ROBOTS / arm / "description.urdf"))


def _mujoco(arm: str) -> mujoco.MjModel:
    """MuJoCo's model of the same file, every link a body; collision meshes (package:// files that
    are never shipped) removed."""
    spec = mujoco.MjSpec.from_file(str(ROBOTS / arm / "description.urdf"))
    spec.compiler.fusestatic = False
    spec.compiler.balanceinertia = True  # as the MuJoCo backend (the FR3 hand's inertia); no effect on kinematics
    for geom in list(spec.geoms):
        if geom.type == mujoco.mjtGeom.mjGEOM_MESH:
            spec.delete(geom)
    for mesh in list(spec.meshes):
        spec.delete(mesh)
    return spec.compile()


def test_arms_are_found() -> None:
    assert {"ur5e", "gen3", "xarm7", "so101", "piper"} <= set(ARMS)


@pytest.mark.parametrize("arm", ARMS)
def test_description_is_well_formed_xml(arm: str) -> None:
    """Strict parsers (ElementTree, ROS tools) read it too, not only the lenient ones of Pinocchio and MuJoCo."""
    assert ET.parse(ROBOTS / arm / "description.urdf").getroot().tag == "robot"


@pytest.mark.parametrize("arm", ARMS)
def test_pinocchio_and_mujoco_agree_on_the_tcp(arm: str) -> None:
    model = _pinocchio(arm)
    data = model.createData()
    tcp = _profile(arm)["tcp_frame"]
    frame = model.getFrameId(tcp)
    assert frame < model.nframes, f"{arm}: no frame {tcp}"
    source = _mujoco(arm)
    mj_data = mujoco.MjData(source)
    body = mujoco.mj_name2id(source, mujoco.mjtObj.mjOBJ_BODY, tcp)
    assert body >= 0, f"{arm}: MuJoCo has no body {tcp}"
    addresses = [source.jnt_qposadr[mujoco.mj_name2id(source, mujoco.mjtObj.mjOBJ_JOINT, name)]
                 for name in model.names[1:]]
    rng = np.random.default_rng(27)
    worst = 0.0
    for _ in range(SAMPLES):
        q = rng.uniform(model.lowerPositionLimit, model.upperPositionLimit)
        mj_data.qpos[:] = source.qpos0
        for joint, address in enumerate(addresses, start=1):
            mj_data.qpos[address] = q[model.joints[joint].idx_q]
        mujoco.mj_kinematics(source, mj_data)
        pin.framesForwardKinematics(model, data, q)
        worst = max(worst, float(np.linalg.norm(data.oMf[frame].translation - mj_data.xpos[body])),
                    float(np.abs(data.oMf[frame].rotation - mj_data.xmat[body].reshape(3, 3)).max()))
    assert worst < TOLERANCE_M


@pytest.mark.parametrize("arm", ARMS)
def test_joints_are_an_arm_and_at_most_a_gripper(arm: str) -> None:
    model = _pinocchio(arm)
    arm_joints = list(_profile(arm)["ready_joint_positions"])
    joints = list(model.names[1:])
    assert 4 <= len(arm_joints) <= 7
    assert joints[:len(arm_joints)] == arm_joints
    assert len(joints) - len(arm_joints) <= 2
    assert all(model.joints[index].nq == 1 for index in range(1, model.njoints))


@pytest.mark.parametrize("arm", ARMS)
def test_limits_are_finite_and_positive(arm: str) -> None:
    model = _pinocchio(arm)
    assert np.all(np.isfinite(model.lowerPositionLimit)) and np.all(np.isfinite(model.upperPositionLimit))
    assert np.all(model.lowerPositionLimit < model.upperPositionLimit)
    assert np.all(model.velocityLimit > 0) and np.all(np.isfinite(model.velocityLimit))
    assert np.all(model.effortLimit > 0) and np.all(np.isfinite(model.effortLimit))


@pytest.mark.parametrize("arm", ARMS)
def test_ready_pose_is_within_the_limits(arm: str) -> None:
    model = _pinocchio(arm)
    for name, position in _profile(arm)["ready_joint_positions"].items():
        index = model.joints[model.getJointId(name)].idx_q
        assert model.lowerPositionLimit[index] <= position <= model.upperPositionLimit[index], name


@pytest.mark.parametrize("arm", ARMS)
def test_sources_name_a_licence(arm: str) -> None:
    assert LICENCES.search((ROBOTS / arm / "SOURCES.md").read_text(encoding="utf-8"))
