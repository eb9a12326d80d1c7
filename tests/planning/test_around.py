"""Planning around a blocked straight line (`plan_and_check` with the `DetourPlanner`), on the bundled FR3.

The envelope decides: every accepted detour is re-checked here by the independent dense oracle.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from armwarden.guard.planning import plan_and_check
from armwarden.planning.goals import CLOSE_TO_A_ZONE
from armwarden.planning.planners import PoseTarget
from armwarden.preflight import RuntimeModel
from armwarden.safety.limits import Box
from armwarden.safety.violations import Code
from tests.helpers import DOWN, READY
from tests.planning.scenarios import PILLAR, PILLAR_GOAL, PILLAR_START, base_turn, hemmed_block, oracle_for, with_zones

UNOBSTRUCTED_POSES = [
    PoseTarget(np.array([0.45, 0.1, 0.3]), DOWN),
    PoseTarget(np.array([0.40, 0.05, 0.35])),
    PoseTarget(np.array([0.30, -0.2, 0.45]), DOWN),
]


def hard_codes(outcome, report) -> set[Code]:
    return {v.code for v in (*outcome.violations, *(report.violations if report else ())) if v.is_hard}


# ------------------------------------------------------------------ unobstructed: today's plan, unchanged
@pytest.mark.parametrize("target", UNOBSTRUCTED_POSES)
def test_an_unobstructed_pose_target_gives_the_straight_line_plan_unchanged(runtime: RuntimeModel, target) -> None:
    outcome, report = plan_and_check(runtime, "pose", READY, {"target": target})
    straight = runtime.planner.plan_to_pose(READY, target)
    assert report is not None and not report.hard
    assert outcome.trajectory.digest == straight.trajectory.digest
    assert outcome.notes == straight.notes


def test_an_unobstructed_joint_target_gives_the_straight_line_plan_unchanged(runtime: RuntimeModel) -> None:
    goal = READY + np.array([0.2, -0.1, 0.0, 0.2, 0.0, 0.1, -0.3])
    outcome, _ = plan_and_check(runtime, "joints", READY, {"joint_positions": goal})
    assert outcome.trajectory.digest == runtime.planner.plan_to_joints(READY, goal).trajectory.digest


def test_an_unobstructed_plan_never_consults_the_detour_planner(runtime: RuntimeModel, monkeypatch) -> None:
    def fail(*args, **kwargs):
        raise AssertionError("the detour planner ran for an unobstructed target")

    monkeypatch.setattr(runtime.detours, "plan", fail)
    _, report = plan_and_check(runtime, "pose", READY, {"target": UNOBSTRUCTED_POSES[0]})
    assert report is not None and not report.hard


# ------------------------------------------------------------------ blocked: a detour the envelope accepts
def test_a_base_turn_blocked_by_a_pillar_goes_around_it(runtime: RuntimeModel) -> None:
    model = with_zones(runtime, PILLAR)
    straight, straight_report = plan_and_check(with_zones(runtime, PILLAR, detours=False), "joints", PILLAR_START,
                                               {"joint_positions": PILLAR_GOAL})
    assert Code.KEEP_OUT in hard_codes(straight, straight_report)

    outcome, report = plan_and_check(model, "joints", PILLAR_START, {"joint_positions": PILLAR_GOAL})
    assert report is not None and not report.hard, report.hard
    np.testing.assert_array_equal(outcome.trajectory.start, PILLAR_START)
    np.testing.assert_array_equal(outcome.trajectory.goal, PILLAR_GOAL)
    assert any(note.startswith("detour planned") and "× the straight line's" in note for note in outcome.notes)
    assert oracle_for(model).violations(outcome.trajectory) == []


def test_the_same_request_gives_the_same_detour(runtime: RuntimeModel) -> None:
    first, _ = plan_and_check(with_zones(runtime, PILLAR), "joints", PILLAR_START, {"joint_positions": PILLAR_GOAL})
    again, _ = plan_and_check(with_zones(runtime, PILLAR), "joints", PILLAR_START, {"joint_positions": PILLAR_GOAL})
    np.testing.assert_array_equal(first.trajectory.positions, again.trajectory.positions)
    np.testing.assert_array_equal(first.trajectory.times, again.trajectory.times)


def test_a_pose_target_whose_nearest_solution_is_blocked_gets_another_solution_or_a_detour(runtime: RuntimeModel) -> None:
    # the straight joint line from the turned base sweeps the hand through the pillar
    target = PoseTarget(runtime.robot.tcp_pose(PILLAR_GOAL).position, DOWN)
    model = with_zones(runtime, PILLAR)
    outcome, report = plan_and_check(model, "pose", PILLAR_START, {"target": target})
    assert report is not None and not report.hard, hard_codes(outcome, report)
    reached = runtime.robot.tcp_pose(outcome.trajectory.goal)
    assert np.linalg.norm(reached.position - target.position) < 1e-3
    assert oracle_for(model).violations(outcome.trajectory) == []


# ------------------------------------------------------------------ no detour: a clear rejection, in budget
def test_no_detour_within_the_budget_is_a_rejection_naming_the_blocker_and_the_budget(runtime: RuntimeModel) -> None:
    budget = 0.25
    model = with_zones(runtime, hemmed_block(runtime), budget_s=budget)
    began = time.monotonic()  # out of the hemmed ready pose: every way out sweeps the hand into the block
    outcome, report = plan_and_check(model, "joints", READY, {"joint_positions": base_turn(0.6)})
    elapsed = time.monotonic() - began
    assert report is not None and Code.KEEP_OUT in {v.code for v in report.hard}
    (no_detour,) = [v for v in outcome.violations if v.code is Code.NO_DETOUR]
    assert no_detour.is_hard
    assert "'block'" in no_detour.detail and "planning budget of 0.25 s" in no_detour.detail
    assert elapsed <= 1.2 * budget, f"planning took {elapsed:.3f} s for a {budget} s budget"


def test_a_stop_request_ends_the_search_at_once(runtime: RuntimeModel) -> None:
    model = with_zones(runtime, hemmed_block(runtime), budget_s=2.0)
    straight = model.planner.plan_to_joints(READY, base_turn(0.6))
    report = model.envelope.check(straight.trajectory)
    began = time.monotonic()
    outcome = model.detours.plan("joints", READY, straight, report, should_stop=lambda: True)
    assert time.monotonic() - began < 0.5
    assert any(v.code is Code.NO_DETOUR and "e-stop" in v.detail for v in outcome.violations)


def test_a_goal_close_to_a_zone_is_still_searched_for_and_its_refusal_says_what_may_help(runtime: RuntimeModel) -> None:
    """The ready pose 1 mm above a block: plans into it from afar fail the final check at their
    last sample; the refusal says so, after the search ran (the goal is ranked, not dropped)."""
    model = with_zones(runtime, hemmed_block(runtime), budget_s=0.3)
    outcome, report = plan_and_check(model, "joints", base_turn(0.6), {"joint_positions": READY})
    assert report is not None and Code.KEEP_OUT in {v.code for v in report.hard}
    (no_detour,) = [v for v in outcome.violations if v.code is Code.NO_DETOUR]
    assert "within a few millimetres of a zone" in no_detour.detail
    assert "motion.sweep_resolution_m" in no_detour.detail and "may help" in no_detour.detail


#: a wrist-only motion (joint 5) back to the ready pose
WRIST_START = READY + np.array([0.0, 0.0, 0.0, 0.0, 1.4, 0.0, 0.0])


def elbow_side_and_wrist_obstacle(runtime: RuntimeModel) -> tuple[Box, Box]:
    """A zone 1 mm beside the ready pose's padded elbow (fr3_link4, beside its nearest body,
    found by bisection on the envelope's own check), and a 1 cm obstacle where the TCP passes
    halfway along the wrist motion from `WRIST_START`."""

    def beside(y0: float) -> Box:
        return Box.of("elbow_side", [-0.19, y0, 0.59], [-0.14, y0 + 0.05, 0.64])

    inside, clear = 0.0, 0.3  # y of the zone's near face: in the elbow, and well clear of it
    while clear - inside > 1e-6:
        middle = (inside + clear) / 2
        blocked = any(v.is_hard for v in with_zones(runtime, beside(middle)).envelope.check_path(READY))
        inside, clear = (middle, clear) if blocked else (inside, middle)
    elbow = beside(clear + 0.001)
    centre = runtime.robot.tcp_pose(READY + (WRIST_START - READY) / 2).position
    return elbow, Box.of("obstacle", centre - 0.005, centre + 0.005)


def test_a_goal_whose_near_body_does_not_move_on_the_way_in_is_reached_by_a_detour(runtime: RuntimeModel) -> None:
    """A goal ranked close to a zone is not dropped: the elbow 1 mm from its zone gets no sweep
    allowance from a wrist motion, so a detour of the wrist around the obstacle ends there and
    passes the final check and the dense oracle."""
    model = with_zones(runtime, *elbow_side_and_wrist_obstacle(runtime), budget_s=2.0)
    assert model.detours is not None
    assert model.detours.goals.arrival(READY) == CLOSE_TO_A_ZONE
    outcome, report = plan_and_check(model, "joints", WRIST_START, {"joint_positions": READY})
    assert report is not None and not report.hard, [v.detail for v in outcome.violations]
    assert any("detour planned" in note for note in outcome.notes)
    assert oracle_for(model).violations(outcome.trajectory) == []


def test_a_goal_past_a_joint_limit_is_refused_without_a_search(runtime: RuntimeModel, monkeypatch) -> None:
    monkeypatch.setattr(runtime.detours, "plan", lambda *a, **k: pytest.fail("searched for an unreachable goal"))
    goal = READY.copy()
    goal[3] = 0.5  # joint 4 above its upper limit
    outcome, report = plan_and_check(runtime, "joints", READY, {"joint_positions": goal})
    assert report is not None and Code.JOINT_LIMIT in {v.code for v in report.hard}
    assert not any(v.code is Code.NO_DETOUR for v in outcome.violations)


def test_a_cartesian_path_stays_a_straight_line_even_when_blocked(runtime: RuntimeModel) -> None:
    start_tcp = runtime.robot.tcp_pose(READY).position
    wall = Box.of("wall", start_tcp + [0.05, -0.2, -0.3], start_tcp + [0.07, 0.2, 0.3])
    model = with_zones(runtime, wall)
    waypoints = [PoseTarget(start_tcp + np.array([0.12, 0.0, 0.0]), DOWN)]
    outcome, report = plan_and_check(model, "cartesian", READY, {"waypoints": waypoints})
    assert report is not None and Code.KEEP_OUT in {v.code for v in report.hard}
    assert not any(v.code is Code.NO_DETOUR for v in outcome.violations)


# ------------------------------------------------------------------ the per-plan caps, before and while searching
BIN_BOX = Box.of("bin_box", [0.40, -0.20, 0.0], [0.70, 0.20, 0.25])


def test_a_target_farther_than_the_tcp_cap_is_refused_without_a_search(runtime: RuntimeModel, monkeypatch) -> None:
    model = with_zones(runtime, BIN_BOX)
    assert model.detours is not None
    monkeypatch.setattr(model.detours.search, "find", lambda *a, **k: pytest.fail("searched for a target out of reach"))
    monkeypatch.setattr(model.detours.goals, "select", lambda *a, **k: pytest.fail("sought goals for a target out of reach"))
    target = PoseTarget(np.array([0.75, 0.06, 0.08]), None)  # in front of the box, 0.60 m from the ready TCP
    outcome, report = plan_and_check(model, "pose", READY, {"target": target})
    assert report is not None and report.hard
    (no_detour,) = [v for v in outcome.violations if v.code is Code.NO_DETOUR]
    assert "motion.max_cartesian_step_m" in no_detour.detail and "no path is shorter" in no_detour.detail


def test_a_pose_target_behind_an_obstacle_for_the_joint_line_gets_the_straight_tcp_line(runtime: RuntimeModel) -> None:
    """Beside the box, below the ready pose: the straight joint line swings the hand through the
    box's corner, the straight TCP line passes it."""
    model = with_zones(runtime, BIN_BOX)
    target = PoseTarget(np.array([0.347, 0.1, 0.172]), None)
    _, straight_report = plan_and_check(with_zones(runtime, BIN_BOX, detours=False), "pose", READY, {"target": target})
    assert straight_report is not None and Code.KEEP_OUT in {v.code for v in straight_report.hard}
    outcome, report = plan_and_check(model, "pose", READY, {"target": target})
    assert report is not None and not report.hard, outcome.violations
    assert any("straight TCP line" in note for note in outcome.notes)
    distance = np.linalg.norm(target.position - runtime.robot.tcp_pose(READY).position)
    assert report.tcp_path_length_m <= distance * 1.01
    assert outcome.trajectory is not None and oracle_for(model).violations(outcome.trajectory) == []
