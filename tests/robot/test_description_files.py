"""Loading any arm's description: URDF and MJCF, meshes found through package:// URIs and search
paths (or named when missing), xacro refused with the instruction, the arm chain inferred or
checked, and RobotModel loading through it."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import pytest

from armwarden.core.errors import RobotModelError
from armwarden.robot.description_chain import infer_chain
from armwarden.robot.description_files import load_description
from armwarden.robot.fitted_file import FittedBody, FittedGeometry, LinkFit
from armwarden.robot.model import RobotModel
from tests.robot.generated_arm import GeneratedArm, write_mjcf_twin, write_random_arm


def tcp_placements(model: pin.Model, tcp: str, qs: np.ndarray) -> np.ndarray:
    data, frame = model.createData(), model.getFrameId(tcp)
    out = []
    for q in qs:
        pin.framesForwardKinematics(model, data, q)
        out.append(data.oMf[frame].homogeneous.copy())
    return np.array(out)


@pytest.mark.parametrize("n_joints", [4, 5, 6, 7])
def test_the_arm_chain_of_a_generated_arm_is_inferred(tmp_path: Path, n_joints: int) -> None:
    arm = write_random_arm(tmp_path, seed=n_joints, n_joints=n_joints)
    description = load_description(arm.urdf)
    chain = infer_chain(description.model, mimic_joints=description.mimic_joints)
    assert (chain.base_frame, chain.tcp_frame, chain.joint_names) == (arm.base_frame, arm.tcp_frame, arm.joint_names)


def test_fingers_are_gripper_joints_and_a_mimic_finger_is_not_driven(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=8, n_joints=6, gripper=True)
    description = load_description(arm.urdf)
    chain = infer_chain(description.model, mimic_joints=description.mimic_joints)
    assert chain.joint_names == arm.joint_names and chain.gripper_joints == arm.gripper_joints


def test_an_mjcf_twin_loads_with_the_same_arm_and_kinematics(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path / "urdf", seed=9, n_joints=6)
    twin = load_description(write_mjcf_twin(arm, tmp_path / "mjcf"))
    urdf = load_description(arm.urdf)
    assert twin.kind == "mjcf"
    assert infer_chain(twin.model).joint_names == arm.joint_names
    qs = np.random.default_rng(1).uniform(-1.0, 1.0, size=(50, len(arm.joint_names)))
    difference = tcp_placements(twin.model, "tool0", qs) - tcp_placements(urdf.model, "tool0", qs)
    assert np.abs(difference).max() < 1e-9


def test_package_meshes_are_found_through_the_mesh_path(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=2, n_joints=5, package_uris=True)
    collision = load_description(arm.urdf, (arm.mesh_dir,)).collision
    assert collision is not None and collision.ngeoms == 6


def test_package_meshes_beside_the_description_need_no_mesh_path(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=2, n_joints=5, package_uris=True)
    shutil.move(arm.mesh_dir / "generated_arm", arm.urdf.parent / "generated_arm")
    collision = load_description(arm.urdf).collision
    assert collision is not None and collision.ngeoms == 6


def test_relative_meshes_are_found_beside_the_description_or_on_the_mesh_path(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path / "arm", seed=2, n_joints=5)
    assert load_description(arm.urdf).collision is not None
    moved = tmp_path / "elsewhere" / "arm.urdf"
    moved.parent.mkdir()
    shutil.move(arm.urdf, moved)
    with pytest.raises(RobotModelError, match="not found"):
        load_description(moved)
    collision = load_description(moved, (arm.mesh_dir,)).collision
    assert collision is not None and collision.ngeoms == 6


def test_a_missing_mesh_is_named_with_its_link_and_every_place_tried(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=2, n_joints=5, package_uris=True)
    with pytest.raises(RobotModelError, match=r"link 'link3': package://generated_arm/meshes/link3.stl \(tried") as caught:
        load_description(arm.urdf)
    assert "--mesh-path" in str(caught.value) and str(arm.urdf.parent) in str(caught.value)


def test_without_collision_the_meshes_are_not_needed(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=2, n_joints=5, package_uris=True)
    description = load_description(arm.urdf, with_collision=False)
    assert description.collision is None and description.model.nq == 5


def test_a_xacro_file_is_refused_with_the_command_that_expands_it(tmp_path: Path) -> None:
    path = tmp_path / "arm.urdf.xacro"
    path.write_text('<robot xmlns:xacro="http://www.ros.org/wiki/xacro" name="a"/>', encoding="utf-8")
    with pytest.raises(RobotModelError, match=r"xacro arm.urdf.xacro > arm.urdf"):
        load_description(path)


def test_a_xacro_macro_in_a_urdf_named_file_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "arm.urdf"
    path.write_text('<robot xmlns:xacro="http://www.ros.org/wiki/xacro" name="a"><xacro:property name="l" value="1"/>'
                    '<link name="base"/></robot>', encoding="utf-8")
    with pytest.raises(RobotModelError, match=r"xacro arm.urdf > arm.expanded.urdf"):
        load_description(path)


def test_an_expanded_urdf_that_keeps_the_xacro_namespace_loads(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=3, n_joints=4)
    text = arm.urdf.read_text(encoding="utf-8").replace("<robot ", '<robot xmlns:xacro="http://www.ros.org/wiki/xacro" ')
    arm.urdf.write_text(text, encoding="utf-8")
    assert load_description(arm.urdf).model.nq == 4


def test_a_file_that_is_neither_urdf_nor_mjcf_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "arm.sdf"
    path.write_text("<sdf version='1.7'/>", encoding="utf-8")
    with pytest.raises(RobotModelError, match="neither a URDF"):
        load_description(path)


def _with_second_tool(arm: GeneratedArm) -> Path:
    text = arm.urdf.read_text(encoding="utf-8").replace("</robot>", (
        '<joint name="tcp_joint" type="fixed"><parent link="link5"/><child link="tcp"/>'
        '<origin xyz="0 0.05 0" rpy="0 0 0"/></joint><link name="tcp"/></robot>'))
    arm.urdf.write_text(text, encoding="utf-8")
    return arm.urdf


def test_two_tool_frames_at_the_end_of_the_arm_are_named_and_one_can_be_chosen(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=3, n_joints=5)
    model = load_description(_with_second_tool(arm)).model
    with pytest.raises(RobotModelError, match=r"ambiguous: tcp, tool0 .*--tcp-frame"):
        infer_chain(model)
    assert infer_chain(model, tcp_frame="tcp").tcp_frame == "tcp"


def test_of_several_frames_at_the_end_the_one_named_as_a_tool_point_is_the_tcp(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=3, n_joints=5)
    text = arm.urdf.read_text(encoding="utf-8").replace("</robot>", (
        '<joint name="knuckle_joint" type="fixed"><parent link="link5"/><child link="left_knuckle"/>'
        '<origin xyz="0 0.05 0" rpy="0 0 0"/></joint><link name="left_knuckle"/></robot>'))
    arm.urdf.write_text(text, encoding="utf-8")
    assert infer_chain(load_description(arm.urdf).model).tcp_frame == "tool0"


def test_two_equal_branches_are_named_as_candidates(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=3, n_joints=4)
    text = arm.urdf.read_text(encoding="utf-8")
    branch = "".join(
        f'<joint name="b{i}" type="revolute"><parent link="{parent}"/><child link="b{i}_link"/>'
        f'<origin xyz="0 0.1 0" rpy="0 0 0"/><axis xyz="0 1 0"/><limit lower="-1" upper="1" velocity="1" effort="1"/>'
        f'</joint><link name="b{i}_link"/>' for i, parent in ((1, "base_link"), (2, "b1_link"), (3, "b2_link"), (4, "b3_link")))
    arm.urdf.write_text(text.replace("</robot>", branch + "</robot>"), encoding="utf-8")
    with pytest.raises(RobotModelError, match=r"2 revolute chains of 4 joints, ending at b4, joint4.*--joints"):
        infer_chain(load_description(arm.urdf).model)


def test_unknown_joint_and_frame_names_are_listed_with_the_valid_ones(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=3, n_joints=4)
    model = load_description(arm.urdf).model
    with pytest.raises(RobotModelError, match=r"unknown joint\(s\) joint9; the description's joints: joint1, joint2"):
        infer_chain(model, joints=["joint1", "joint2", "joint3", "joint9"])
    with pytest.raises(RobotModelError, match=r"TCP frame 'flange' is unknown; .*tool0"):
        infer_chain(model, tcp_frame="flange")


def test_a_tcp_frame_before_the_arms_last_joint_is_refused(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=3, n_joints=4)
    with pytest.raises(RobotModelError, match=r"'link2' is not rigidly attached after .* joint4; frames that are: .*tool0"):
        infer_chain(load_description(arm.urdf).model, tcp_frame="link2")


def test_a_base_frame_that_moves_is_refused(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=3, n_joints=4)
    with pytest.raises(RobotModelError, match="moves with a joint"):
        infer_chain(load_description(arm.urdf).model, base_frame="link2")


def test_joints_out_of_kinematic_order_are_refused(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=3, n_joints=5)
    model = load_description(arm.urdf).model
    with pytest.raises(RobotModelError, match="not one chain in kinematic order"):
        infer_chain(model, joints=["joint2", "joint1", "joint3", "joint4"])


def test_an_arm_of_three_joints_is_refused_naming_the_count(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=3, n_joints=5)
    model = load_description(arm.urdf).model
    with pytest.raises(RobotModelError, match="has 3 joints"):
        infer_chain(model, joints=["joint1", "joint2", "joint3"])


def _one_capsule_per_link(model: pin.Model) -> FittedGeometry:
    """Stand-in fitted geometry: a capsule along each moving link (its fit is not under test)."""
    links = {}
    for frame in model.frames:
        if frame.type == pin.FrameType.BODY and frame.name.startswith("link"):
            body = FittedBody(f"{frame.name}_0", (0.0, 0.0, 0.0), (0.0, 0.0, 0.05), 0.04)
            links[frame.name] = LinkFit(frame.name, "test", (body,), 0, 0, 0.0, (0.0,))
    limits = {name: (float(model.lowerPositionLimit[model.idx_qs[j]]), float(model.upperPositionLimit[model.idx_qs[j]]))
              for j, name in enumerate(model.names) if j > 0}
    return FittedGeometry("generated", {}, 0.0, links, joint_limits=limits)


def test_a_robot_with_fitted_geometry_loads_a_urdf_whose_meshes_are_gone(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=12, n_joints=4)
    fitted = _one_capsule_per_link(load_description(arm.urdf).model)
    shutil.rmtree(arm.urdf.parent / "meshes")
    robot = RobotModel(arm.urdf, arm.joint_names, arm.base_frame, arm.tcp_frame, fitted=fitted)
    assert robot.fitted is fitted and robot.model.nq == 4


def test_a_robot_loads_from_an_mjcf_description(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path / "urdf", seed=13, n_joints=5)
    twin = write_mjcf_twin(arm, tmp_path / "mjcf")
    robot = RobotModel(twin, arm.joint_names, arm.base_frame, arm.tcp_frame)
    assert robot.model.nq == 5 and robot.capsules


@pytest.mark.parametrize("kind", ["floating", "planar"])
def test_a_urdf_joint_that_is_not_revolute_or_prismatic_is_refused(tmp_path: Path, kind: str) -> None:
    arm = write_random_arm(tmp_path, seed=3, n_joints=4)
    text = arm.urdf.read_text(encoding="utf-8").replace('name="joint2" type="revolute"', f'name="joint2" type="{kind}"')
    arm.urdf.write_text(text, encoding="utf-8")
    with pytest.raises(RobotModelError, match=rf"does not support: joint2 \({kind}\)"):
        load_description(arm.urdf)


def test_an_mjcf_ball_joint_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "arm.xml"
    path.write_text("<mujoco><worldbody><body name='base'><body name='l1'><joint name='shoulder' type='ball'/>"
                    "<geom size='0.1'/></body></body></worldbody></mujoco>", encoding="utf-8")
    with pytest.raises(RobotModelError, match=r"shoulder \(spherical\)"):
        load_description(path)


def test_a_parse_error_carries_the_parsers_text(tmp_path: Path) -> None:
    path = tmp_path / "arm.urdf"
    path.write_text("<robot name='a'><link name='l'></robot>", encoding="utf-8")
    with pytest.raises(RobotModelError, match=r"not well-formed XML: mismatched tag: line 1"):
        load_description(path)


def test_chosen_joints_that_leave_out_a_joint_below_them_are_refused(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=3, n_joints=5)
    model = load_description(arm.urdf).model
    with pytest.raises(RobotModelError, match=r"joint\(s\) joint1 move the arm's base"):
        infer_chain(model, joints=["joint2", "joint3", "joint4", "joint5"])


def test_a_prismatic_finger_chosen_as_an_arm_joint_is_refused(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=3, n_joints=4, gripper=True)
    model = load_description(arm.urdf).model
    with pytest.raises(RobotModelError, match="finger_joint1 is not revolute"):
        infer_chain(model, joints=[*arm.joint_names, "finger_joint1"])


def test_an_mjcf_twin_with_a_gripper_has_the_same_arm_and_gripper_joints(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path / "urdf", seed=14, n_joints=5, gripper=True)
    twin = load_description(write_mjcf_twin(arm, tmp_path / "mjcf"))
    chain = infer_chain(twin.model, mimic_joints=twin.mimic_joints)
    assert (chain.joint_names, chain.gripper_joints, chain.tcp_frame) == (arm.joint_names, arm.gripper_joints, "tool0")


def test_a_missing_mjcf_mesh_is_named_with_its_body_and_the_place_tried(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path / "urdf", seed=15, n_joints=4)
    twin = write_mjcf_twin(arm, tmp_path / "mjcf")
    (tmp_path / "mjcf" / "meshes" / "link3.stl").unlink()
    with pytest.raises(RobotModelError, match=r"mesh 'link3' of 'link3': meshes/link3.stl \(tried .*mjcf/meshes/link3.stl\)"):
        load_description(twin)
    assert load_description(twin, with_collision=False).model.nq == 4
