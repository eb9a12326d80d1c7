"""Loading any arm's description: URDF and MJCF, meshes found through package:// URIs and search
paths (or named when missing), xacro refused with the instruction, the arm chain inferred or
checked, and each link's collision surface placed where Pinocchio places it."""

from __future__ import annotations

from pathlib import Path

import coal  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import pytest

from armwarden.core.errors import RobotModelError
from armwarden.robot.description_chain import infer_chain
from armwarden.robot.description_files import load_description
from armwarden.robot.fitting_mesh import winding_numbers
from armwarden.robot.link_meshes import link_meshes, shape_mesh
from tests.robot.generated_arm import GeneratedArm, write_mjcf_twin, write_random_arm


def tcp_positions(model: pin.Model, tcp: str, qs: np.ndarray) -> np.ndarray:
    data, frame = model.createData(), model.getFrameId(tcp)
    out = []
    for q in qs:
        pin.framesForwardKinematics(model, data, q)
        out.append(data.oMf[frame].translation.copy())
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
    # MuJoCo writes 6 significant digits
    assert np.allclose(tcp_positions(twin.model, "tool0", qs), tcp_positions(urdf.model, "tool0", qs), atol=1e-5)
    assert set(link_meshes(twin)) == set(link_meshes(urdf))


def test_package_meshes_are_found_through_the_mesh_path(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=2, n_joints=5, package_uris=True)
    assert load_description(arm.urdf, (arm.mesh_dir,)).collision is not None


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


def test_a_file_that_is_neither_urdf_nor_mjcf_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "arm.sdf"
    path.write_text("<sdf version='1.7'/>", encoding="utf-8")
    with pytest.raises(RobotModelError, match="neither a URDF"):
        load_description(path)


def _with_second_tool(arm: GeneratedArm) -> Path:
    text = arm.urdf.read_text(encoding="utf-8").replace("</robot>", (
        '<joint name="camera_joint" type="fixed"><parent link="link5"/><child link="camera"/>'
        '<origin xyz="0 0.05 0" rpy="0 0 0"/></joint><link name="camera"/></robot>'))
    arm.urdf.write_text(text, encoding="utf-8")
    return arm.urdf


def test_two_frames_at_the_end_of_the_arm_are_named_and_one_can_be_chosen(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=3, n_joints=5)
    model = load_description(_with_second_tool(arm)).model
    with pytest.raises(RobotModelError, match=r"ambiguous: camera, tool0 .*--tcp-frame"):
        infer_chain(model)
    assert infer_chain(model, tcp_frame="camera").tcp_frame == "camera"


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


def test_each_link_surface_sits_where_pinocchio_places_the_geometry(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=4, n_joints=6, gripper=True)
    description = load_description(arm.urdf)
    model, geometry = description.model, description.collision
    assert geometry is not None
    meshes = link_meshes(description)
    data, geometry_data = model.createData(), pin.GeometryData(geometry)
    q = pin.randomConfiguration(model)
    pin.framesForwardKinematics(model, data, q)
    pin.updateGeometryPlacements(model, data, geometry, geometry_data)
    for index, obj in enumerate(geometry.geometryObjects):
        link = model.frames[obj.parentFrame].name
        shape = shape_mesh(link, obj.geometry, "")
        expected = shape.vertices @ geometry_data.oMg[index].rotation.T + geometry_data.oMg[index].translation
        placed = meshes[link].vertices @ data.oMf[obj.parentFrame].rotation.T + data.oMf[obj.parentFrame].translation
        distances = np.min(np.linalg.norm(expected[:, None, :] - placed[None, :, :], axis=2), axis=1)
        assert distances.max() < 1e-12, link


@pytest.mark.parametrize(("shape", "surface"), [
    (coal.Sphere(0.05), lambda u: 0.05 * u),
    (coal.Capsule(0.04, 0.1), lambda u: 0.04 * u + np.where(u[:, 2:3] > 0, [0.0, 0.0, 0.05], [0.0, 0.0, -0.05])),
    (coal.Ellipsoid(0.02, 0.05, 0.08), lambda u: u * [0.02, 0.05, 0.08]),
    (coal.Cylinder(0.03, 0.2), lambda u: np.column_stack([0.03 * u[:, :2] / np.linalg.norm(u[:, :2], axis=1, keepdims=True),
                                                          0.1 * u[:, 2]])),
], ids=["sphere", "capsule", "ellipsoid", "cylinder"])
def test_a_round_primitive_becomes_a_polytope_that_encloses_it(shape: object, surface) -> None:
    units = np.random.default_rng(5).normal(size=(4000, 3))
    units /= np.linalg.norm(units, axis=1, keepdims=True)
    mesh = shape_mesh("link", shape, "primitive")
    inside = winding_numbers(surface(units), mesh.vertices, mesh.triangles)
    assert np.all(inside > 0.5)  # every point of the true surface is inside (the polytope is closed and outward)
