"""The fake backend takes its robot's defaults from the robot profile (`builtin:<name>`), and a
user's URDF, which has no profile, gets a generic set or a clear refusal, never the FR3's names."""

from __future__ import annotations

import numpy as np
import pytest

from armwarden.backends.fake import Config, create_backend
from armwarden.backends.fake.backend import FakeBackend
from armwarden.policy import Policy, bundled_policy, load_policy
from armwarden.robot.model import RobotModel
from armwarden.robots import load_profile
from tests.helpers import run_opened

FR3 = load_profile("fr3")


def _user_urdf_policy() -> Policy:
    """The bundled FR3 policy, its robot given as a file path: a user's URDF, no profile."""
    policy = load_policy(bundled_policy("fr3"))
    robot = policy.robot.model_copy(update={"description": str(FR3.file(FR3.description))})
    return policy.model_copy(update={"robot": robot})


def _model(policy: Policy) -> RobotModel:
    robot = policy.robot
    return RobotModel.from_description(robot.description, list(robot.joint_names), robot.base_frame, robot.tcp_frame)


def test_fr3_profile_lists_the_values_the_backends_used_to_hard_code():
    assert FR3.ready_joint_positions is not None and FR3.controllers is not None and FR3.ros is not None
    assert list(FR3.ready_joint_positions) == [f"fr3_joint{i}" for i in range(1, 8)]
    assert list(FR3.ready_joint_positions.values()) == [0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4]
    assert (FR3.base_frame, FR3.tcp_frame) == ("fr3_link0", "fr3_hand_tcp")
    assert FR3.controllers.trajectory == "fr3_arm_controller"
    assert FR3.ros.trajectory_action == "/fr3_arm_controller/follow_joint_trajectory"
    assert FR3.ros.finger_joints == ("fr3_finger_joint1", "fr3_finger_joint2")


def test_a_bare_fake_starts_at_the_profiles_ready_pose_with_its_controllers_and_graph():
    async def scenario(backend: FakeBackend):
        return await backend.read_joint_state(), await backend.list_controllers(), await backend.graph()

    state, controllers, graph = run_opened(FakeBackend, scenario)
    assert FR3.ready_joint_positions is not None and FR3.controllers is not None and FR3.ros is not None
    assert state.names == tuple(FR3.ready_joint_positions)
    assert np.array_equal(state.positions, list(FR3.ready_joint_positions.values()))
    assert [(c.name, c.type, c.state) for c in controllers] == [(e.name, e.type, e.state) for e in FR3.controllers.loaded]
    assert set(FR3.ros.actions) | {FR3.ros.trajectory_action} == set(graph["actions"])
    assert FR3.ros.wrench_topic in graph["topics"] and FR3.ros.gripper_joint_states in graph["topics"]
    assert set(FR3.ros.nodes) <= set(graph["nodes"]) and set(FR3.ros.services) <= set(graph["services"])


def test_a_fake_without_a_profile_refuses_to_guess_its_joints():
    with pytest.raises(ValueError, match=r"joint_names must be given: the robot .* has no profile"):
        FakeBackend(description=str(FR3.file(FR3.description)))


def test_a_fake_without_a_profile_refuses_to_guess_its_home():
    with pytest.raises(ValueError, match="home must be given"):
        FakeBackend(description=str(FR3.file(FR3.description)), joint_names=tuple(FR3.ready_joint_positions or ()),
                    base_frame="fr3_link0", tcp_frame="fr3_hand_tcp")


def test_a_user_urdf_policy_gets_the_generic_controllers_and_no_driver_names():
    policy = _user_urdf_policy()

    async def scenario(backend: FakeBackend):
        return await backend.list_controllers(), await backend.graph()

    controllers, graph = run_opened(lambda: create_backend(_model(policy), policy, Config()), scenario)
    assert [(c.name, c.state) for c in controllers] == [("arm_controller", "active")]
    assert graph["actions"] == ["/arm_controller/follow_joint_trajectory"]
    names = [name for names in graph.values() for name in names]
    assert not [name for name in names if "fr3" in name or "franka" in name]
