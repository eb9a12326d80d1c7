"""The bundled FR3 description loaded with Pinocchio: golden vectors, frames, capsules, limits."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from armwarden.core.errors import RobotModelError
from armwarden.robot import RobotModel, build_robot, resolve_description
from tests.helpers import READY

JOINTS = [f"fr3_joint{i}" for i in range(1, 8)]


@pytest.fixture(scope="module")
def urdf_robot() -> RobotModel:
    """The bundled FR3 with the URDF's own collision primitives (`collision_geometry: urdf`)."""
    return RobotModel.from_description("builtin:fr3", JOINTS, "fr3_link0", "fr3_hand_tcp", collision_geometry="urdf")


def test_ready_pose_flange_and_tcp_match_the_published_golden_vectors(robot: RobotModel) -> None:
    flange = robot.frame_pose(READY, "fr3_link8").position
    tcp = robot.tcp_pose(READY)
    np.testing.assert_allclose(flange, [0.3069, 0.0, 0.5903], atol=1e-4)
    np.testing.assert_allclose(tcp.position, [0.3069, 0.0, 0.4869], atol=1e-4)
    np.testing.assert_allclose(tcp.rotation, np.diag([1.0, -1.0, -1.0]), atol=1e-6)


def test_zero_configuration_matches_the_published_golden_vectors(robot: RobotModel) -> None:
    np.testing.assert_allclose(robot.frame_pose(np.zeros(7), "fr3_link8").position, [0.088, 0.0, 0.926], atol=1e-4)
    np.testing.assert_allclose(robot.tcp_pose(np.zeros(7)).position, [0.088, 0.0, 0.8226], atol=1e-4)


def test_zero_configuration_is_outside_the_fr3_limits_on_joints_4_and_6(robot: RobotModel) -> None:
    assert not robot.within_limits(np.zeros(7))
    outside = [name for name, lo, hi in zip(robot.joint_names, robot.lower, robot.upper, strict=True) if not lo <= 0.0 <= hi]
    assert outside == ["fr3_joint4", "fr3_joint6"]


def test_every_link_with_collision_geometry_carries_capsules(robot: RobotModel) -> None:
    links = {c.link for c in robot.capsules}
    assert links == {f"fr3_link{i}" for i in range(8)} | {"fr3_hand", "fr3_leftfinger", "fr3_rightfinger"}
    assert all(c.radius_m > 0.0 for c in robot.capsules)


def test_batched_body_points_agree_with_pinocchio_geometry_placements(urdf_robot: RobotModel) -> None:
    robot = urdf_robot
    rng = np.random.default_rng(3)
    qs = rng.uniform(robot.lower, robot.upper, size=(20, 7))
    p0, p1 = robot.body_points(robot.joint_frames(qs))
    geometry_data = pin.GeometryData(robot.geometry)
    for k, q in enumerate(qs):
        pin.updateGeometryPlacements(robot.model, robot.data, robot.geometry, geometry_data, q)
        for b, capsule in enumerate(robot.capsules):
            obj_index = robot.geometry.getGeometryId(capsule.name)
            placement = geometry_data.oMg[obj_index]
            half = placement.rotation[:, 2] * robot.geometry.geometryObjects[obj_index].geometry.halfLength
            ends = {tuple(np.round(placement.translation - half, 9)), tuple(np.round(placement.translation + half, 9))}
            got = {tuple(np.round(p0[k, b], 9)), tuple(np.round(p1[k, b], 9))}
            assert got == ends
        np.testing.assert_allclose(p0[k, -1], robot.tcp_pose(q).position, atol=1e-12)


def test_batched_tcp_points_are_the_tcp_poses(robot: RobotModel) -> None:
    rng = np.random.default_rng(3)
    qs = rng.uniform(robot.lower, robot.upper, size=(20, robot.nq))

    points = robot.tcp_points(qs)

    assert points.shape == (20, 3)
    assert np.allclose(points, [robot.tcp_pose(q).position for q in qs], atol=1e-12)


def test_reach_bounds_the_real_point_motion_for_small_joint_steps(robot: RobotModel) -> None:
    rng = np.random.default_rng(5)
    for _ in range(200):
        q = rng.uniform(robot.lower, robot.upper)
        dq = rng.normal(scale=0.01, size=7)
        a0, a1 = robot.body_points(robot.joint_frames(np.array([q, q + dq])))
        moved = np.maximum(np.linalg.norm(a0[1] - a0[0], axis=-1), np.linalg.norm(a1[1] - a1[0], axis=-1))
        bound = np.abs(dq) @ robot.reach
        assert np.all(moved <= bound + 1e-12)


def test_tcp_jacobian_matches_finite_differences(robot: RobotModel) -> None:
    q = READY + 0.1
    jac = robot.tcp_jacobian(q)
    eps = 1e-6
    for i in range(7):
        dq = np.zeros(7)
        dq[i] = eps
        numeric = (robot.tcp_pose(q + dq).position - robot.tcp_pose(q - dq).position) / (2 * eps)
        np.testing.assert_allclose(jac[:3, i], numeric, atol=1e-6)


def test_unknown_frame_error_lists_the_valid_frames(robot: RobotModel) -> None:
    with pytest.raises(RobotModelError, match=r"valid frames: .*fr3_hand_tcp"):
        robot.frame_pose(READY, "no_such_frame")


def test_unknown_builtin_description_is_refused() -> None:
    with pytest.raises(RobotModelError, match="builtin:fr3"):
        resolve_description("builtin:ur5")


def test_missing_urdf_file_is_refused(tmp_path) -> None:
    with pytest.raises(RobotModelError, match="not a readable file"):
        resolve_description(str(tmp_path / "missing.urdf"))


def test_unknown_joint_name_is_refused() -> None:
    with pytest.raises(RobotModelError, match="unknown joint"):
        RobotModel.from_description("builtin:fr3", JOINTS[:6] + ["elbow"], "fr3_link0", "fr3_hand_tcp")


def test_user_urdf_with_box_and_sphere_geometry_gets_containing_capsules(tmp_path) -> None:
    urdf = tmp_path / "two_link.urdf"
    urdf.write_text(
        """<robot name="two_link">
  <link name="base"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <link name="l1"><collision><origin xyz="0.2 0 0"/><geometry><box size="0.4 0.1 0.06"/></geometry></collision></link>
  <joint name="j2" type="revolute"><origin xyz="0.4 0 0"/><parent link="l1"/><child link="l2"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <link name="l2"><collision><origin xyz="0.1 0 0"/><geometry><sphere radius="0.05"/></geometry></collision></link>
  <joint name="tip" type="fixed"><origin xyz="0.2 0 0"/><parent link="l2"/><child link="tool"/></joint>
  <link name="tool"/>
</robot>"""
    )
    model = RobotModel(urdf, ["j1", "j2"], "base", "tool")
    box, sphere = model.capsules
    assert box.radius_m == pytest.approx(np.hypot(0.05, 0.03))
    assert sorted(p[0] for p in (box.p0_m, box.p1_m)) == pytest.approx([0.0, 0.4])
    assert sphere.p0_m == sphere.p1_m and sphere.radius_m == pytest.approx(0.05)
    np.testing.assert_allclose(model.tcp_pose(np.zeros(2)).position, [0.6, 0.0, 0.0], atol=1e-12)


def test_policy_limits_looser_than_the_description_are_refused(fr3_policy) -> None:
    limits = dict(fr3_policy.robot.joint_limits)
    limits["fr3_joint1"] = limits["fr3_joint1"].model_copy(update={"max": 3.0})
    loose_robot = fr3_policy.robot.model_copy(update={"joint_limits": limits})
    with pytest.raises(RobotModelError, match="exceed the description"):
        build_robot(fr3_policy.model_copy(update={"robot": loose_robot}))


def test_batched_tcp_points_are_in_a_base_frame_that_is_not_the_world(tmp_path) -> None:
    urdf = tmp_path / "mounted.urdf"
    urdf.write_text(
        """<robot name="mounted">
  <link name="world"/>
  <joint name="mount" type="fixed"><origin xyz="0.5 0.2 0.8" rpy="0 0 1.5707963"/><parent link="world"/><child link="base"/></joint>
  <link name="base"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <link name="l1"><collision><origin xyz="0.2 0 0"/><geometry><box size="0.4 0.1 0.06"/></geometry></collision></link>
  <joint name="tip" type="fixed"><origin xyz="0.4 0 0.1"/><parent link="l1"/><child link="tool"/></joint>
  <link name="tool"/>
</robot>"""
    )
    model = RobotModel(urdf, ["j1"], "base", "tool")
    qs = np.array([[-0.7], [0.0], [0.4]])

    points = model.tcp_points(qs)

    assert np.allclose(points, [model.tcp_pose(q).position for q in qs], atol=1e-12)
    assert np.allclose(points[1], [0.4, 0.0, 0.1], atol=1e-9)  # in the base frame, not the world's
