"""The joint, pose and Cartesian planners on the bundled FR3."""

from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin
import pytest

from armwarden.guard.planning import plan_and_check
from armwarden.planning.planners import Planner, PoseTarget
from armwarden.preflight import RuntimeModel
from armwarden.robot import RobotModel
from armwarden.safety.violations import Code
from tests.helpers import DOWN, READY


def test_joint_plan_starts_at_the_state_and_ends_exactly_at_the_goal(planner: Planner) -> None:
    goal = READY + np.array([0.2, -0.1, 0.0, 0.2, 0.0, 0.1, -0.3])
    outcome = planner.plan_to_joints(READY, goal)
    assert outcome.violations == ()
    np.testing.assert_array_equal(outcome.trajectory.positions[0], READY)
    np.testing.assert_allclose(outcome.trajectory.goal, goal, atol=1e-12)


def test_default_scaling_comes_from_the_policy(planner: Planner, fr3_policy) -> None:
    outcome = planner.plan_to_joints(READY, READY + 0.1)
    assert outcome.velocity_scaling == fr3_policy.motion.default_velocity_scaling
    assert outcome.acceleration_scaling == fr3_policy.motion.default_acceleration_scaling


def test_scaling_above_the_cap_is_clamped_and_the_plan_says_so(planner: Planner, fr3_policy) -> None:
    outcome = planner.plan_to_joints(READY, READY + 0.1, velocity_scaling=0.9, acceleration_scaling=0.9)
    assert outcome.velocity_scaling == fr3_policy.motion.max_velocity_scaling
    assert any("velocity_scaling 0.9" in note and "clamped" in note for note in outcome.notes)
    assert any("acceleration_scaling 0.9" in note for note in outcome.notes)


@pytest.mark.parametrize("bad", [0.0, -0.5, float("nan"), float("inf"), 1e-300, 0.0099])
def test_non_positive_non_finite_or_tiny_scaling_is_malformed(planner: Planner, bad: float) -> None:
    outcome = planner.plan_to_joints(READY, READY + 0.1, velocity_scaling=bad)
    assert outcome.trajectory is None
    assert [v.code for v in outcome.violations] == [Code.MALFORMED]


@pytest.mark.parametrize("goal", [READY[:5], np.append(READY, 0.0), READY + np.array([np.nan, 0, 0, 0, 0, 0, 0])])
def test_malformed_joint_goal_is_refused(planner: Planner, goal) -> None:
    outcome = planner.plan_to_joints(READY, goal)
    assert outcome.trajectory is None and outcome.violations[0].code is Code.MALFORMED


def test_pose_plan_reaches_the_target_pose(planner: Planner, robot: RobotModel) -> None:
    target = PoseTarget(np.array([0.45, 0.1, 0.3]), DOWN)
    outcome = planner.plan_to_pose(READY, target)
    reached = robot.tcp_pose(outcome.trajectory.goal)
    assert np.linalg.norm(reached.position - target.position) < 1e-4
    assert np.allclose(reached.rotation, DOWN, atol=2e-3)


def test_position_only_pose_plan_leaves_orientation_free(planner: Planner, robot: RobotModel) -> None:
    outcome = planner.plan_to_pose(READY, PoseTarget(np.array([0.35, -0.1, 0.45])))
    assert np.linalg.norm(robot.tcp_pose(outcome.trajectory.goal).position - [0.35, -0.1, 0.45]) < 1e-4


def test_unreachable_pose_is_an_ik_failure_not_an_exception(planner: Planner) -> None:
    outcome = planner.plan_to_pose(READY, PoseTarget(np.array([1.5, 0.0, 0.4]), DOWN))
    assert outcome.trajectory is None
    assert outcome.violations[0].code is Code.IK_FAILED
    assert "residual" in outcome.violations[0].detail


def test_cartesian_path_keeps_the_tcp_on_the_straight_line(planner: Planner, robot: RobotModel) -> None:
    start = robot.tcp_pose(READY).position
    goal = start + np.array([0.1, 0.15, -0.1])
    outcome = planner.plan_cartesian_path(READY, [PoseTarget(goal)])
    trajectory = outcome.trajectory
    direction = (goal - start) / np.linalg.norm(goal - start)
    for t in np.linspace(0.0, trajectory.duration_s, 200):
        p = robot.tcp_pose(trajectory.sample(t)).position
        off_line = np.linalg.norm((p - start) - np.dot(p - start, direction) * direction)
        assert off_line < 1e-3
    np.testing.assert_allclose(robot.tcp_pose(trajectory.goal).position, goal, atol=1e-4)


def test_cartesian_path_keeps_the_start_orientation_when_none_is_given(planner: Planner, robot: RobotModel) -> None:
    start = robot.tcp_pose(READY)
    outcome = planner.plan_cartesian_path(READY, [PoseTarget(start.position + [0.05, 0.0, -0.05])])
    np.testing.assert_allclose(robot.tcp_pose(outcome.trajectory.goal).rotation, start.rotation, atol=2e-3)


def test_cartesian_path_interpolates_orientation_to_the_waypoint(planner: Planner, robot: RobotModel) -> None:
    start = robot.tcp_pose(READY)
    turned = start.rotation @ pin.utils.rpyToMatrix(0.0, 0.0, 0.4)
    outcome = planner.plan_cartesian_path(READY, [PoseTarget(start.position + [0.0, 0.05, 0.0], turned)])
    np.testing.assert_allclose(robot.tcp_pose(outcome.trajectory.goal).rotation, turned, atol=2e-3)


def test_cartesian_path_through_several_waypoints_visits_each(planner: Planner, robot: RobotModel) -> None:
    start = robot.tcp_pose(READY).position
    waypoints = [start + [0.05, 0.05, 0.0], start + [0.05, -0.05, 0.0], start + [0.0, 0.0, -0.05]]
    trajectory = planner.plan_cartesian_path(READY, [PoseTarget(w) for w in waypoints]).trajectory
    tcp = np.array([robot.tcp_pose(q).position for q in trajectory.positions])
    for w in waypoints:
        assert np.min(np.linalg.norm(tcp - w, axis=1)) < 1e-4


def test_cartesian_line_through_the_base_axis_fails_cleanly(planner: Planner) -> None:
    outcome = planner.plan_cartesian_path(READY, [PoseTarget(np.array([-0.3, 0.0, 0.49]))])
    assert outcome.trajectory is None
    assert outcome.violations[0].code is Code.IK_FAILED and "waypoint 0" in outcome.violations[0].detail


def test_a_joint_jump_between_cartesian_steps_is_refused(planner: Planner, robot: RobotModel) -> None:
    strict = Planner(robot, dataclasses.replace(planner.settings, max_ik_jump_rad=1e-4), planner.ik)
    outcome = strict.plan_cartesian_path(READY, [PoseTarget(robot.tcp_pose(READY).position + [0.05, 0.0, 0.0])])
    assert outcome.trajectory is None and "joint jump" in outcome.violations[0].detail


def test_empty_cartesian_path_is_malformed(planner: Planner) -> None:
    outcome = planner.plan_cartesian_path(READY, [])
    assert outcome.violations[0].code is Code.MALFORMED


def test_a_cartesian_step_the_ik_misses_from_the_previous_solution_is_retried_from_other_seeds(
        planner: Planner, robot: RobotModel) -> None:
    # folded arm, TCP drawn back over the base: from the previous step's solution alone the
    # solver stalls at one step; the extrapolated previous step and a half step reach it
    start = np.array([-0.4328, -1.5354, 0.4141, -2.9921, 0.1865, 1.8162, 1.8952])
    outcome = planner.plan_cartesian_path(start, [PoseTarget(np.array([0.0047, -0.0385, 0.4925]))])
    assert outcome.violations == (), outcome.violations
    steps = np.max(np.abs(np.diff(outcome.trajectory.positions, axis=0)), axis=1)
    assert np.all(steps <= planner.settings.max_ik_jump_rad)
    assert np.linalg.norm(robot.tcp_pose(outcome.trajectory.goal).position - [0.0047, -0.0385, 0.4925]) < 1e-3


#: a line the arm can follow with joint 6 on its lower limit the whole way (the hand held close
#: to the forearm), which IK stepping used to refuse ("did not converge": clipping a step that
#: leans on a limit leaves most of the error in place)
ALONG_A_LIMIT = (np.array([-0.098, -0.591, -0.083, -2.377, -0.146, 0.63, 0.965]), np.array([0.16, -0.056, 0.537]))


def test_a_clear_cartesian_line_along_a_joint_limit_is_followed(runtime: RuntimeModel) -> None:
    start, goal = ALONG_A_LIMIT
    outcome, report = plan_and_check(runtime, "cartesian", start, {"waypoints": [PoseTarget(goal)]})
    assert outcome.trajectory is not None, outcome.violations
    assert report is not None and not report.hard, outcome.violations
    robot = runtime.robot
    assert np.min(outcome.trajectory.positions[:, 5]) <= robot.lower[5] + 1e-3  # it does lean on joint 6's limit
    begin = robot.tcp_pose(start).position
    direction = (goal - begin) / np.linalg.norm(goal - begin)
    for q in outcome.trajectory.positions:
        p = robot.tcp_pose(q).position - begin
        assert np.linalg.norm(p - np.dot(p, direction) * direction) < 1e-3
    np.testing.assert_allclose(robot.tcp_pose(outcome.trajectory.goal).position, goal, atol=1e-4)
