"""Inverse kinematics: round trips on random reachable poses, and failure as a result."""

from __future__ import annotations

import numpy as np
import pytest

from armwarden.robot import RobotModel
from armwarden.robot.ik import IkOptions, IkSolver
from tests.helpers import READY


def _random_reachable_poses(robot: RobotModel, count: int, seed: int):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        q = rng.uniform(robot.lower, robot.upper)
        yield robot.tcp_pose(q)


def test_full_pose_round_trips_on_200_random_reachable_poses(robot: RobotModel) -> None:
    solver = IkSolver(robot)
    failures = []
    for pose in _random_reachable_poses(robot, 200, seed=11):
        result = solver.solve(pose.position, pose.rotation, [READY])
        reached = robot.tcp_pose(result.q)
        if not (
            result.success
            and np.linalg.norm(reached.position - pose.position) < 1e-4
            and np.allclose(reached.rotation, pose.rotation, atol=2e-3)
            and robot.within_limits(result.q)
        ):
            failures.append((pose.position, result.message))
    assert failures == []


def test_position_only_round_trips_on_200_random_reachable_positions(robot: RobotModel) -> None:
    solver = IkSolver(robot)
    for pose in _random_reachable_poses(robot, 200, seed=12):
        result = solver.solve(pose.position, None, [READY])
        assert result.success, result.message
        assert np.linalg.norm(robot.tcp_pose(result.q).position - pose.position) < 1e-4


def test_unreachable_target_is_reported_with_its_residual_not_raised(robot: RobotModel) -> None:
    result = IkSolver(robot).solve(np.array([2.0, 0.0, 0.5]), None, [READY])
    assert not result.success
    assert result.position_error_m > 0.5
    assert "best residual" in result.message


def test_nearby_target_is_solved_from_the_current_state_with_small_motion(robot: RobotModel) -> None:
    start = robot.tcp_pose(READY)
    result = IkSolver(robot).solve(start.position + [0.02, 0.0, -0.02], start.rotation, [READY])
    assert result.success
    assert np.max(np.abs(result.q - READY)) < 0.2


def test_solutions_respect_the_joint_limits(robot: RobotModel) -> None:
    solver = IkSolver(robot)
    for pose in _random_reachable_poses(robot, 30, seed=13):
        result = solver.solve(pose.position, pose.rotation, [READY])
        assert np.all(result.q >= robot.lower) and np.all(result.q <= robot.upper)


def test_a_seed_that_stops_improving_is_given_up_long_before_the_iteration_cap(robot: RobotModel) -> None:
    solver = IkSolver(robot)
    result = solver.solve_from(np.array([2.0, 0.0, 0.5]), None, READY)  # 2 m out: the arm stretches, then stalls
    assert not result.success and result.message == "stalled"
    assert result.iterations < solver.options.max_iterations / 2


def test_giving_up_stalled_seeds_changes_no_solution_on_random_poses(robot: RobotModel) -> None:
    patient = IkSolver(robot, IkOptions(stall_iterations=0))  # every seed runs to the iteration cap
    default = IkSolver(robot)
    for pose in _random_reachable_poses(robot, 100, seed=13):
        a = patient.solve(pose.position, pose.rotation, [READY])
        b = default.solve(pose.position, pose.rotation, [READY])
        assert a.success == b.success
        np.testing.assert_array_equal(a.q, b.q)


def test_damping_must_be_positive_for_the_cholesky_step() -> None:
    for damping in (0.0, -1e-3, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="damping"):
            IkOptions(damping=damping)
