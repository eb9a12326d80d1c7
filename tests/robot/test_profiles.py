"""Every robot ArmWarden ships is one folder with a profile; `builtin:<name>` and the bundled
policies resolve through it, and nothing outside the folder can be named."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from armwarden.core.errors import PolicyError, RobotModelError
from armwarden.policy import bundled_policy, load_policy
from armwarden.robot.model import RobotModel, resolve_collision_geometry, resolve_description
from armwarden.robots import BUILTIN_PREFIX, RobotProfile, builtin_robots, bundled_policies, load_profile


def test_the_fr3_is_shipped_with_its_description_fitted_geometry_and_two_policies() -> None:
    assert "fr3" in builtin_robots()
    profile = load_profile("fr3")
    assert profile.file(profile.description).is_file()
    assert profile.collision_geometry is not None and profile.file(profile.collision_geometry).is_file()
    assert list(profile.policies) == ["fr3", "readonly"]


@pytest.mark.parametrize("robot", builtin_robots())
def test_each_bundled_policy_of_a_robot_loads_and_its_description_builds_a_model(robot: str) -> None:
    for name in load_profile(robot).policies:
        policy = load_policy(bundled_policy(name))
        assert policy.robot.description == BUILTIN_PREFIX + robot
        urdf = resolve_description(policy.robot.description)
        assert urdf == load_profile(robot).file(load_profile(robot).description)
        model = RobotModel(urdf, policy.robot.joint_names, policy.robot.base_frame, policy.robot.tcp_frame)
        assert model.joint_names == tuple(policy.robot.joint_names)


def test_every_bundled_policy_name_is_unique_across_robots() -> None:
    names = [name for robot in builtin_robots() for name in load_profile(robot).policies]
    assert sorted(names) == sorted(bundled_policies())


def test_auto_collision_geometry_is_the_profiles_fitted_file() -> None:
    fitted = resolve_collision_geometry("auto", "builtin:fr3")
    assert fitted is not None and fitted.robot == "fr3"
    assert resolve_collision_geometry("urdf", "builtin:fr3") is None


def test_an_unknown_builtin_robot_is_refused_naming_the_shipped_ones() -> None:
    with pytest.raises(RobotModelError, match=r"unknown built-in robot description 'builtin:ur5'.*builtin:fr3"):
        resolve_description("builtin:ur5")
    with pytest.raises(RobotModelError, match="unknown built-in collision geometry"):
        resolve_collision_geometry("builtin:ur5", "builtin:fr3")


def test_an_unknown_bundled_policy_is_refused_naming_the_bundled_ones() -> None:
    with pytest.raises(PolicyError, match="no such bundled policy; bundled: fr3, readonly"):
        bundled_policy("ur5")


@pytest.mark.parametrize("file", ["../fr3/policy.yaml", "/etc/passwd", "sub/description.urdf", ""])
def test_a_profile_cannot_name_a_file_outside_its_folder(file: str) -> None:
    document = load_profile("fr3").model_dump() | {"description": file}
    with pytest.raises(ValidationError):
        RobotProfile.model_validate(document)


def test_a_profile_with_an_unknown_key_is_refused() -> None:
    with pytest.raises(ValidationError, match="extra"):
        RobotProfile.model_validate(load_profile("fr3").model_dump() | {"home": [0.0] * 7})
