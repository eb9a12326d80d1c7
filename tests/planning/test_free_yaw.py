"""Free yaw: a pose target whose turn about the tool axis the planner may choose (opt-in)."""

from __future__ import annotations

import time

import numpy as np

from armwarden.guard.planning import decode_request, encode_request, plan_and_check
from armwarden.planning.around import request_seed
from armwarden.planning.goals import GoalSelector
from armwarden.planning.planners import PoseTarget, yaw_about_z, yaw_towards
from armwarden.preflight import RuntimeModel
from armwarden.safety.violations import Code
from tests.helpers import DOWN, READY
from tests.planning.scenarios import oracle_for

#: hand down above the table, fingers turned half a turn from where the ready pose has them: joint 7
#: would travel about 2.8 rad, past the policy's 1.5 rad per plan, on every arm branch IK finds
TURNED_POSITION = np.array([0.45, 0.1, 0.3])
HALF_TURNED_DOWN = DOWN @ yaw_about_z(np.pi)


def tool_axis(model: RuntimeModel, q: np.ndarray) -> np.ndarray:
    return model.robot.tcp_pose(q).rotation[:, 2]


def test_yaw_towards_keeps_the_tool_axis_and_takes_the_nearest_turn() -> None:
    rng = np.random.default_rng(1)
    for _ in range(20):
        target = DOWN @ yaw_about_z(rng.uniform(-np.pi, np.pi))
        current = DOWN @ yaw_about_z(rng.uniform(-np.pi, np.pi))
        current = current @ np.linalg.qr(np.eye(3) + 0.2 * rng.normal(size=(3, 3)))[0]  # tilted as well
        current *= np.sign(np.linalg.det(current))
        chosen = yaw_towards(target, current)
        np.testing.assert_allclose(chosen[:, 2], target[:, 2], atol=1e-12)
        np.testing.assert_allclose(chosen.T @ chosen, np.eye(3), atol=1e-12)
        closest = max(np.trace((target @ yaw_about_z(a)).T @ current) for a in np.linspace(-np.pi, np.pi, 3601))
        assert np.trace(chosen.T @ current) >= closest - 1e-6


def test_a_fixed_yaw_past_the_travel_cap_is_refused(runtime: RuntimeModel) -> None:
    outcome, report = plan_and_check(runtime, "pose", READY, {"target": PoseTarget(TURNED_POSITION, HALF_TURNED_DOWN)})
    assert report is not None and Code.STEP_TOO_LARGE in {v.code for v in report.hard}
    assert any(v.code is Code.NO_DETOUR for v in outcome.violations)


def test_free_yaw_reaches_the_same_target_with_the_tool_still_pointing_down(runtime: RuntimeModel) -> None:
    target = PoseTarget(TURNED_POSITION, HALF_TURNED_DOWN, free_yaw=True)
    outcome, report = plan_and_check(runtime, "pose", READY, {"target": target})
    assert report is not None and not report.hard, outcome.violations
    assert outcome.trajectory is not None
    reached = runtime.robot.tcp_pose(outcome.trajectory.goal)
    assert np.linalg.norm(reached.position - TURNED_POSITION) < 1e-3
    np.testing.assert_allclose(reached.rotation[:, 2], [0.0, 0.0, -1.0], atol=2e-3)
    assert oracle_for(runtime).violations(outcome.trajectory) == []


def test_goal_selection_with_free_yaw_finds_goals_the_fixed_yaw_cannot(runtime: RuntimeModel) -> None:
    chooser = GoalSelector(runtime.planner.ik, runtime.envelope, runtime.planner.settings.home_rad)
    fixed = chooser.select(READY, TURNED_POSITION, HALF_TURNED_DOWN, seed=3, deadline=time.monotonic() + 5)
    free = chooser.select(READY, TURNED_POSITION, HALF_TURNED_DOWN, seed=3, deadline=time.monotonic() + 5, free_yaw=True)
    assert not fixed.goals and "STEP_TOO_LARGE" in fixed.describe_blocked()
    assert free.goals
    for goal in free.goals:
        assert np.linalg.norm(runtime.robot.tcp_pose(goal).position - TURNED_POSITION) < 1e-3
        np.testing.assert_allclose(tool_axis(runtime, goal), [0.0, 0.0, -1.0], atol=2e-3)


def test_free_yaw_is_off_unless_asked_and_a_replay_keeps_it() -> None:
    assert PoseTarget(TURNED_POSITION, DOWN).free_yaw is False
    for free in (False, True):
        request = {"target": PoseTarget(TURNED_POSITION, DOWN, free_yaw=free)}
        assert decode_request("pose", encode_request("pose", request))["target"].free_yaw is free


def test_free_yaw_gives_a_request_its_own_seed() -> None:
    fixed = request_seed("pose", READY, PoseTarget(TURNED_POSITION, DOWN))
    assert fixed != request_seed("pose", READY, PoseTarget(TURNED_POSITION, DOWN, free_yaw=True))
    assert fixed == request_seed("pose", READY, PoseTarget(TURNED_POSITION, DOWN))
