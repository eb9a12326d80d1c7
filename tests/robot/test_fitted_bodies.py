"""The fitted capsules on the policy's robot: where they sit, the fingers' sweep, which pairs are checked."""

from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin
import pytest

from armwarden.core.errors import PolicyError, RobotModelError
from armwarden.core.geometry import segment_segment_distance
from armwarden.policy import Policy
from armwarden.preflight import load_runtime_model
from armwarden.robot import RobotModel, build_robot, resolve_description
from armwarden.robot.fitted_bodies import fitted_pairs, require_limits_within
from armwarden.robot.fitted_file import FittedGeometry

FINGERS = ("fr3_leftfinger", "fr3_rightfinger")


@pytest.fixture(scope="module")
def fitted(robot: RobotModel) -> FittedGeometry:
    assert robot.fitted is not None, "the bundled policy checks the fitted geometry"
    return robot.fitted


@pytest.fixture(scope="module")
def full_model() -> pin.Model:
    return pin.buildModelFromUrdf(str(resolve_description("builtin:fr3")))


def test_bundled_policy_checks_the_fitted_capsules_including_the_base(robot: RobotModel, fitted: FittedGeometry) -> None:
    assert [c.name for c in robot.capsules] == list(fitted.bodies())
    assert {c.joint_index for c in robot.capsules if c.link == "fr3_link0"} == {0}


def test_capsules_sit_where_pinocchio_puts_their_links(robot: RobotModel, fitted: FittedGeometry) -> None:
    rng = np.random.default_rng(11)
    qs = rng.uniform(robot.lower, robot.upper, size=(10, robot.nq))
    p0, p1 = robot.body_points(robot.joint_frames(qs))
    data = robot.model.createData()
    bodies = fitted.bodies()
    for k, q in enumerate(qs):
        pin.framesForwardKinematics(robot.model, data, q)
        for b, capsule in enumerate(robot.capsules):
            if capsule.link in FINGERS:
                continue  # swept over the opening width: the next tests
            link = data.oMf[robot.model.getFrameId(capsule.link, pin.FrameType.BODY)]
            body = bodies[capsule.name]
            np.testing.assert_allclose(p0[k, b], link.act(np.array(body.p0_m)), atol=1e-12)
            np.testing.assert_allclose(p1[k, b], link.act(np.array(body.p1_m)), atol=1e-12)


@pytest.mark.parametrize("width_share", [0.0, 0.25, 0.5, 0.75, 1.0])
def test_swept_finger_capsules_hold_each_finger_body_at_every_opening(
    robot: RobotModel, fitted: FittedGeometry, full_model: pin.Model, width_share: float
) -> None:
    """Each swept capsule holds its fitted body at any finger position: sample the body's surface
    (segment points ± radius in every direction) with the finger joints at that share of their range."""
    q = pin.neutral(full_model)
    for name in ("fr3_finger_joint1", "fr3_finger_joint2"):
        joint = full_model.joints[full_model.getJointId(name)]
        q[joint.idx_q] = full_model.lowerPositionLimit[joint.idx_q] + width_share * (
            full_model.upperPositionLimit[joint.idx_q] - full_model.lowerPositionLimit[joint.idx_q]
        )
    data = full_model.createData()
    pin.framesForwardKinematics(full_model, data, q)
    flange_joint = data.oMi[full_model.getJointId("fr3_joint7")]
    bodies = fitted.bodies()
    directions = np.random.default_rng(5).normal(size=(200, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    for capsule in (c for c in robot.capsules if c.link in FINGERS):
        body = bodies[capsule.name]
        link_in_joint = flange_joint.actInv(data.oMf[full_model.getFrameId(capsule.link, pin.FrameType.BODY)])
        a, b = link_in_joint.act(np.array(body.p0_m)), link_in_joint.act(np.array(body.p1_m))
        along = np.linspace(0.0, 1.0, 7)[:, None]
        surface = (a + along * (b - a))[:, None, :] + body.radius_m * directions[None]
        points = surface.reshape(-1, 3)
        s0, s1 = np.array(capsule.p0_m), np.array(capsule.p1_m)
        distance = segment_segment_distance(
            points, points, np.broadcast_to(s0, points.shape), np.broadcast_to(s1, points.shape)
        )
        assert np.all(distance <= capsule.radius_m + 1e-12), capsule.name


def test_only_pairs_the_analysis_keeps_are_checked(robot: RobotModel, fitted: FittedGeometry) -> None:
    names = [c.name for c in robot.capsules]
    checked = {frozenset((names[a], names[b])) for a, b in robot.self_collision_pairs}
    kept = {frozenset(p) for p in fitted.included_pairs}
    same_joint = {p for p in kept if len({robot.capsules[names.index(n)].joint_index for n in p}) == 1}
    assert checked == kept - same_joint
    assert same_joint  # the fingertips facing each other: the gripper's business, not a plan's
    assert all({n.split("/")[0] for n in p} <= {"fr3_hand", *FINGERS} for p in same_joint)


def test_the_base_is_checked_against_the_forearm_and_the_hand(robot: RobotModel) -> None:
    links = {frozenset((robot.capsules[a].link, robot.capsules[b].link)) for a, b in robot.self_collision_pairs}
    assert frozenset(("fr3_link0", "fr3_link5")) in links
    assert frozenset(("fr3_link0", "fr3_hand")) in links


def test_a_pair_the_file_neither_keeps_nor_excludes_is_checked(robot: RobotModel, fitted: FittedGeometry) -> None:
    dropped = fitted.excluded_pairs[0]
    forgetful = dataclasses.replace(fitted, excluded_pairs=fitted.excluded_pairs[1:])
    names = [c.name for c in robot.capsules]
    pairs = {frozenset((names[a], names[b])) for a, b in fitted_pairs(robot.capsules, forgetful)}
    assert frozenset(dropped.bodies) in pairs


def test_a_file_without_pair_analysis_is_refused(robot: RobotModel, fitted: FittedGeometry) -> None:
    with pytest.raises(RobotModelError, match="no self-collision pair analysis"):
        fitted_pairs(robot.capsules, dataclasses.replace(fitted, joint_limits={}))


def test_limits_wider_than_the_analysis_are_refused(fitted: FittedGeometry) -> None:
    lo, hi = fitted.joint_limits["fr3_joint4"]
    with pytest.raises(RobotModelError, match="fr3_joint4"):
        require_limits_within(fitted, {"fr3_joint4": (lo - 0.1, hi)})


def test_a_policy_naming_an_unknown_builtin_geometry_is_refused_at_the_field(fr3_policy: Policy) -> None:
    policy = fr3_policy.model_copy(
        update={"robot": fr3_policy.robot.model_copy(update={"collision_geometry": "builtin:ur5"})}
    )
    with pytest.raises(PolicyError) as caught:
        load_runtime_model(policy)
    assert [path for path, _ in caught.value.errors] == ["robot.collision_geometry"]


def test_urdf_geometry_checks_the_base_too(fr3_policy: Policy) -> None:
    policy = fr3_policy.model_copy(
        update={"robot": fr3_policy.robot.model_copy(update={"collision_geometry": "urdf"})}
    )
    robot = build_robot(policy)
    assert {c.link for c in robot.capsules if c.joint_index == 0} == {"fr3_link0"}
    assert robot.fitted is None


def test_padding_for_an_unknown_link_is_refused_naming_the_field(fr3_policy: Policy) -> None:
    workspace = fr3_policy.workspace.model_copy(update={"padding_by_link_m": {"fr3_link9": 0.0}})
    with pytest.raises(PolicyError) as caught:
        load_runtime_model(fr3_policy.model_copy(update={"workspace": workspace}))
    assert [path for path, _ in caught.value.errors] == ["workspace.padding_by_link_m"]
