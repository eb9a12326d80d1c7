"""The ROS 2 backend's `--backend-config`: strict, with YAML paths in every error. Runs without
ROS installed: the config module does not import rclpy, and creating the backend without rclpy
is `BackendUnavailable` with the install hint."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import yaml

from armwarden.backends import create_backend, load_backend_config, parse_backend_config
from armwarden.backends.ros2 import INSTALL_HINT
from armwarden.backends.ros2.config import Config, check_against_policy, resolve_robot_names
from armwarden.core.errors import BackendUnavailable, ConfigurationError
from armwarden.policy import Policy
from armwarden.robot import RobotModel
from armwarden.robots import load_profile

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "ros2_fr3.yaml"


def errors_of(document: dict) -> str:
    with pytest.raises(ConfigurationError) as caught:
        parse_backend_config("ros2", document)
    return str(caught.value)


def test_the_example_config_is_valid_and_names_the_cells_endpoints() -> None:
    config = load_backend_config("ros2", EXAMPLE)
    assert isinstance(config, Config)
    assert config.trajectory.action == "/fr3_arm_controller/follow_joint_trajectory"
    assert config.gripper is not None and config.controller_manager is not None and "scene" in config.cameras


def test_the_drivers_names_left_null_come_from_the_fr3_profile() -> None:
    ros = load_profile("fr3").ros
    assert ros is not None
    config = resolve_robot_names(Config.model_validate({"gripper": {}}), "builtin:fr3")
    assert config.trajectory.action == ros.trajectory_action == "/fr3_arm_controller/follow_joint_trajectory"
    assert config.gripper is not None
    assert config.gripper.action == ros.gripper_action == "/franka_gripper/gripper_action"
    assert config.gripper.joint_states_topic == ros.gripper_joint_states == "/franka_gripper/joint_states"
    assert config.gripper.finger_joints == ros.finger_joints == ("fr3_finger_joint1", "fr3_finger_joint2")


def test_names_the_config_gives_win_over_the_profiles() -> None:
    document = {"trajectory": {"topic": "/arm/joint_trajectory"},
                "gripper": {"action": "/hand/gripper_cmd", "finger_joints": ["left"]}}
    config = resolve_robot_names(Config.model_validate(document), "builtin:fr3")
    assert (config.trajectory.action, config.trajectory.topic) == (None, "/arm/joint_trajectory")
    assert config.gripper is not None
    assert (config.gripper.action, config.gripper.joint_states_topic, config.gripper.finger_joints) == (
        "/hand/gripper_cmd", "/franka_gripper/joint_states", ("left",))


def test_a_user_urdf_must_name_its_drivers_endpoints() -> None:
    with pytest.raises(ConfigurationError) as caught:
        resolve_robot_names(Config.model_validate({"gripper": {"finger_joints": ["left"]}}), "/cell/arm.urdf")
    message = str(caught.value)
    for key in ("trajectory.action", "gripper.action", "gripper.joint_states_topic"):
        assert f"{key}: required: the robot '/cell/arm.urdf' has no profile that names it" in message
    assert "gripper.finger_joints" not in message


def test_a_user_urdf_config_that_names_everything_is_kept() -> None:
    document = {"trajectory": {"action": "/arm/follow_joint_trajectory"},
                "gripper": {"action": "/hand/gripper_cmd", "joint_states_topic": "/hand/joint_states",
                            "finger_joints": ["left", "right"]}}
    config = Config.model_validate(document)
    assert resolve_robot_names(config, "/cell/arm.urdf") == config


def test_an_unknown_key_is_named_with_its_path() -> None:
    message = errors_of({"joint_states": {"topic": "/joint_states", "max_age": 0.5}})
    assert "joint_states.max_age: unknown key" in message


def test_nan_is_refused_with_its_path() -> None:
    message = errors_of({"wrench": {"topic": "/wrench", "max_age_s": float("nan")}})
    assert "wrench.max_age_s: " in message


def test_a_camera_kind_must_be_image_or_compressed() -> None:
    message = errors_of({"cameras": {"scene": {"topic": "/image", "kind": "video"}}})
    assert "cameras.scene.kind: " in message


def test_the_trajectory_goes_through_exactly_one_of_action_and_topic() -> None:
    message = errors_of({"trajectory": {"action": "/a/follow_joint_trajectory", "topic": "/a/joint_trajectory"}})
    assert "trajectory: " in message and "exactly one of action" in message


def test_two_policy_joints_mapped_to_one_ros_name_are_refused() -> None:
    message = errors_of({"joints": {"fr3_joint1": "j", "fr3_joint2": "j"}})
    assert "same JointState name: j" in message


def test_joints_naming_a_joint_the_policy_lacks_are_refused_with_the_path(fr3_policy: Policy) -> None:
    config = parse_backend_config("ros2", {"joints": {"fr3_joint9": "joint9"}})
    assert isinstance(config, Config)
    with pytest.raises(ConfigurationError, match=r"joints\.fr3_joint9: not a joint of the policy"):
        check_against_policy(config, tuple(fr3_policy.robot.joint_names))


def test_joint_names_map_to_ros_names_with_identity_by_default(fr3_policy: Policy) -> None:
    config = parse_backend_config("ros2", {"joints": {"fr3_joint1": "panda_joint1"}})
    assert isinstance(config, Config)
    names = check_against_policy(config, tuple(fr3_policy.robot.joint_names))
    assert names[0] == "panda_joint1" and names[1:] == tuple(fr3_policy.robot.joint_names[1:])


def test_a_joint_mapped_to_another_policy_joints_own_name_is_refused(fr3_policy: Policy) -> None:
    """Found by review: fr3_joint1 → fr3_joint2 passed (the mapped names were only compared with
    each other), and joint 1 then read joint 2's position."""
    config = parse_backend_config("ros2", {"joints": {"fr3_joint1": "fr3_joint2"}})
    assert isinstance(config, Config)
    with pytest.raises(ConfigurationError, match=r"two policy joints would read the same JointState name "
                                                 r"\(fr3_joint2: fr3_joint1, fr3_joint2\)"):
        check_against_policy(config, tuple(fr3_policy.robot.joint_names))


def test_without_rclpy_creating_the_backend_names_the_install_command(
        monkeypatch, fr3_policy: Policy, robot: RobotModel) -> None:
    monkeypatch.setitem(sys.modules, "armwarden.backends.ros2.backend", None)  # as if rclpy were missing
    with pytest.raises(BackendUnavailable, match="the ros2 backend is not available") as caught:
        create_backend("ros2", robot, fr3_policy, yaml.safe_load(EXAMPLE.read_text(encoding="utf-8")))
    assert INSTALL_HINT in str(caught.value)
