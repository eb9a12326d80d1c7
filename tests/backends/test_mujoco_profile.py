"""The MuJoCo cell's cameras are the robot profile's mounts; a user's URDF, which has no profile,
must list its cameras in the backend config (refused otherwise, never the FR3's wrist body). The
arm's drives (armature) are the profile's `actuators`; without them, the generic rule, logged."""

from __future__ import annotations

import pytest

import armwarden.backends.mujoco  # noqa: F401 - chooses the offscreen GL platform before mujoco loads

mujoco = pytest.importorskip("mujoco")

from armwarden.backends.mujoco.backend import create_backend  # noqa: E402 - after the importorskip above
from armwarden.backends.mujoco.camera_mounts import CameraSpec, profile_cameras  # noqa: E402
from armwarden.backends.mujoco.config import CameraConfig, Config  # noqa: E402
from armwarden.backends.mujoco.gains import ArmGains, armature_from_profile, generic_armature  # noqa: E402
from armwarden.backends.mujoco.model import build_model  # noqa: E402
from armwarden.backends.mujoco.scene import scene_for_policy  # noqa: E402
from armwarden.core.errors import RobotModelError  # noqa: E402
from armwarden.policy import Policy, bundled_policy, load_policy  # noqa: E402
from armwarden.robot import build_robot  # noqa: E402
from armwarden.robot.model import resolve_description  # noqa: E402
from armwarden.robots import load_profile  # noqa: E402

FR3 = load_profile("fr3")


def _user_urdf_policy() -> Policy:
    """The bundled FR3 policy, its robot given as a file path: a user's URDF, no profile."""
    policy = load_policy(bundled_policy("fr3"))
    robot = policy.robot.model_copy(update={"description": str(FR3.file(FR3.description))})
    return policy.model_copy(update={"robot": robot})


def test_fr3_cameras_are_the_profiles_mounts():
    assert profile_cameras("builtin:fr3") == (
        CameraSpec("scene", position_m=(1.9, 0.0, 1.2), target_m=(0.3, 0.0, 0.3), fovy_deg=50.0),
        CameraSpec("wrist", position_m=(0.07, 0.0, 0.085), target_m=(0.0, 0.0, 0.22), body="fr3_hand",
                   up=(1.0, 0.0, 0.0), fovy_deg=70.0),
    )


def test_a_user_urdf_without_configured_cameras_gets_a_scene_camera_in_front_of_its_workspace():
    policy = _user_urdf_policy()
    backend = create_backend(build_robot(policy), policy, Config())
    assert backend.capabilities.cameras == ("scene",)
    (camera,) = scene_for_policy(policy).cameras
    assert camera.body is None and camera.position_m[0] > policy.workspace.box.max[0]
    assert policy.workspace.box.min[2] < camera.target_m[2] < camera.position_m[2]


def test_a_user_urdf_gets_the_cameras_its_config_lists():
    policy = _user_urdf_policy()
    top = CameraConfig(name="top", position_m=(0.3, 0.0, 2.0), target_m=(0.3, 0.0, 0.0), up=(1.0, 0.0, 0.0))
    backend = create_backend(build_robot(policy), policy, Config(cameras=(top,)))
    assert backend.capabilities.cameras == ("top",)


def test_the_compiled_fr3_armature_is_the_profiles_not_the_generic_rules(caplog):
    policy = load_policy(bundled_policy("fr3"))
    with caplog.at_level("WARNING", logger="armwarden.backends.mujoco"):
        backend = create_backend(build_robot(policy), policy, Config(cameras=()))
    assert FR3.actuators is not None
    armature = backend.sim.model.dof_armature[backend.sim.arm_dofs]
    assert armature.tolist() == [FR3.actuators[joint].armature_kg_m2 for joint in policy.robot.joint_names]
    assert not [record for record in caplog.records if "generic armature rule" in record.getMessage()]


def test_a_profiles_armature_is_what_the_model_compiles_and_sizes_its_gains_with():
    policy = load_policy(bundled_policy("fr3"))
    robot = build_robot(policy)
    heavier = {joint: {"armature_kg_m2": 0.3 + 0.01 * index} for index, joint in enumerate(policy.robot.joint_names)}
    profile = FR3.model_validate(FR3.model_dump() | {"actuators": heavier})
    armature = armature_from_profile(profile, policy.robot.joint_names)
    assert armature is not None and armature == tuple(0.3 + 0.01 * index for index in range(7))
    scene = scene_for_policy(policy, cameras=())
    cell = build_model(resolve_description(policy.robot.description), robot, scene, armature=armature)
    assert cell.model.dof_armature[cell.arm_dofs].tolist() == list(armature)
    assert cell.gains.armature == armature
    generic = build_model(resolve_description(policy.robot.description), robot, scene)
    # more rotor inertia on every joint: stiffer servos for the same bandwidth
    assert all(heavy > light for heavy, light in zip(cell.gains.kp, generic.gains.kp, strict=True))


def test_a_robot_without_actuators_in_a_profile_gets_the_generic_rule_and_says_so(caplog):
    policy = _user_urdf_policy()
    with caplog.at_level("WARNING", logger="armwarden.backends.mujoco"):
        backend = create_backend(build_robot(policy), policy, Config(cameras=()))
    model = backend.sim.model
    efforts = [float(model.jnt_actfrcrange[model.joint(joint).id][1]) for joint in policy.robot.joint_names]
    armature = model.dof_armature[backend.sim.arm_dofs]
    assert armature.tolist() == list(generic_armature(efforts))
    messages = [record.getMessage() for record in caplog.records if "generic armature rule" in record.getMessage()]
    assert len(messages) == 1, messages


def test_profile_actuators_for_other_joints_than_the_policys_are_refused():
    joints = ("fr3_joint1", "fr3_joint2", "fr3_joint3", "fr3_joint4", "fr3_joint5", "fr3_joint6", "extra_joint")
    with pytest.raises(RobotModelError, match=r"no actuator for the arm joints extra_joint in the robot profile"):
        armature_from_profile(FR3, joints)


def test_a_robot_without_a_profile_has_no_profile_armature():
    assert armature_from_profile(None, ("fr3_joint1",)) is None


def test_an_armature_besides_whole_gains_is_refused():
    policy = load_policy(bundled_policy("fr3"))
    robot = build_robot(policy)
    gains = ArmGains(kp=(100.0,) * 7, kv=(10.0,) * 7, armature=(0.1,) * 7)
    with pytest.raises(RobotModelError, match=r"give the arm's armature or its whole gains, not both"):
        build_model(resolve_description(policy.robot.description), robot, scene_for_policy(policy, cameras=()),
                    armature=(0.2,) * 7, gains=gains)
