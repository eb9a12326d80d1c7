"""The MuJoCo cell's cameras are the robot profile's mounts; a user's URDF, which has no profile,
must list its cameras in the backend config (refused otherwise, never the FR3's wrist body)."""

from __future__ import annotations

import pytest

import armwarden.backends.mujoco  # noqa: F401 - chooses the offscreen GL platform before mujoco loads

mujoco = pytest.importorskip("mujoco")

from armwarden.backends.mujoco.backend import create_backend  # noqa: E402 - after the importorskip above
from armwarden.backends.mujoco.camera_mounts import CameraSpec, profile_cameras  # noqa: E402
from armwarden.backends.mujoco.config import CameraConfig, Config  # noqa: E402
from armwarden.core.errors import RobotModelError  # noqa: E402
from armwarden.policy import Policy, bundled_policy, load_policy  # noqa: E402
from armwarden.robot import build_robot  # noqa: E402
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


def test_a_user_urdf_without_configured_cameras_is_refused():
    policy = _user_urdf_policy()
    with pytest.raises(RobotModelError, match=r"has no profile naming its camera mounts: list them"):
        create_backend(build_robot(policy), policy, Config())


def test_a_user_urdf_gets_the_cameras_its_config_lists():
    policy = _user_urdf_policy()
    top = CameraConfig(name="top", position_m=(0.3, 0.0, 2.0), target_m=(0.3, 0.0, 0.0), up=(1.0, 0.0, 0.0))
    backend = create_backend(build_robot(policy), policy, Config(cameras=(top,)))
    assert backend.capabilities.cameras == ("top",)
