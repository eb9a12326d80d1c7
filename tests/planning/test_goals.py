"""Goal selection for pose targets: several IK solutions, blocked ones dropped, the rest ranked."""

from __future__ import annotations

import time

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from armwarden.planning.goals import CLOSE_TO_A_ZONE, GoalSelector
from armwarden.preflight import RuntimeModel
from armwarden.safety.limits import Box
from armwarden.safety.violations import Code, Violation
from tests.helpers import DOWN, READY
from tests.planning.scenarios import hemmed_block, with_zones

#: around the elbow (joint 4) of the ready pose; the arm's redundancy can swing the elbow elsewhere
ELBOW_ZONE = Box.of("elbow_zone", [-0.225, -0.06, 0.555], [-0.105, 0.06, 0.675])


def selector(model: RuntimeModel) -> GoalSelector:
    return GoalSelector(model.planner.ik, model.envelope, model.planner.settings.home_rad)


def ready_target(model: RuntimeModel) -> tuple[np.ndarray, np.ndarray]:
    pose = model.robot.tcp_pose(READY)
    return pose.position, pose.rotation


def test_a_solution_with_its_elbow_in_a_zone_is_dropped_for_one_with_the_elbow_elsewhere(runtime: RuntimeModel) -> None:
    model = with_zones(runtime, ELBOW_ZONE)
    position, rotation = ready_target(model)
    selection = selector(model).select(READY, position, rotation, seed=3, deadline=time.monotonic() + 5, first=READY)
    assert selection.goals, selection.describe_blocked()
    assert "KEEP_OUT" in selection.describe_blocked()
    for goal in selection.goals:
        assert not [v for v in model.envelope.check_path(goal) if v.is_hard]
        assert np.linalg.norm(model.robot.tcp_pose(goal).position - position) < 1e-3
        assert np.max(np.abs(goal - READY)) > 0.05  # not the blocked ready pose


def test_goals_are_ranked_by_weighted_joint_travel(runtime: RuntimeModel) -> None:
    chooser = selector(runtime)
    target = np.array([0.45, 0.1, 0.3])
    selection = chooser.select(READY, target, None, seed=11, deadline=time.monotonic() + 5)
    travel = [chooser.weighted_travel(READY, goal) for goal in selection.goals]
    assert len(travel) >= 2 and travel == sorted(travel)


def test_the_same_seed_gives_the_same_goals(runtime: RuntimeModel) -> None:
    chooser = selector(runtime)
    target = np.array([0.40, -0.1, 0.25])
    first = chooser.select(READY, target, DOWN, seed=5, deadline=time.monotonic() + 5)
    again = chooser.select(READY, target, DOWN, seed=5, deadline=time.monotonic() + 5)
    assert len(first.goals) == len(again.goals) > 0
    for a, b in zip(first.goals, again.goals, strict=True):
        np.testing.assert_array_equal(a, b)


def test_a_goal_beyond_the_joint_travel_cap_is_not_offered(runtime: RuntimeModel) -> None:
    chooser = selector(runtime)
    cap = runtime.envelope.limits.max_joint_step_rad
    selection = chooser.select(READY, np.array([-0.1, 0.35, 0.3]), None, seed=2, deadline=time.monotonic() + 5)
    assert all(np.max(np.abs(goal - READY)) <= cap for goal in selection.goals)


def test_goals_with_a_clear_approach_come_first_and_their_approach_line_passes_the_envelope(runtime: RuntimeModel) -> None:
    model = with_zones(runtime, Box.of("bin_box", [0.40, -0.20, 0.0], [0.70, 0.20, 0.25]))
    chooser = selector(model)
    selection = chooser.select(READY, np.array([0.55, 0.0, 0.29]), DOWN, seed=8, deadline=time.monotonic() + 5)
    assert selection.approaches and selection.approaches[0] is not None
    flags = [approach is None for approach in selection.approaches]
    assert flags == sorted(flags)  # with an approach (False) before without (True)
    for goal, approach in zip(selection.goals, selection.approaches, strict=True):
        if approach is not None:
            assert not [v for v in model.envelope.check_path(np.vstack([approach, goal])) if v.is_hard]
            gap = np.linalg.norm(model.robot.tcp_pose(approach).position - model.robot.tcp_pose(goal).position)
            assert abs(gap - chooser.options.retreat_m) < 1e-3  # a few centimetres back, as asked


def hand_blocked_unless_turned_to(model: RuntimeModel, angle: float, monkeypatch) -> None:
    """The envelope refuses every configuration whose last joint is not at `angle` (as a zone
    beside the fingers would at the other angles)."""
    blocked = (Violation(Code.KEEP_OUT, "fr3_hand enters keep-out zone 'beside'", 0.0, "fr3_hand"),)
    monkeypatch.setattr(model.envelope, "check_path", lambda qs, **_: () if abs(np.atleast_2d(qs)[-1][-1] - angle) < 1e-12
                        else blocked)


def test_a_blocked_solution_for_a_position_target_turns_the_hand_about_its_own_axis(runtime: RuntimeModel, monkeypatch) -> None:
    q = READY.copy()
    q[-1] += 0.6  # a solution with the hand turned 0.6 rad from where it starts
    hand_blocked_unless_turned_to(runtime, READY[-1], monkeypatch)

    turned = selector(runtime)._turned_clear(q, READY, runtime.envelope.limits.max_joint_step_rad)

    assert turned is not None
    np.testing.assert_array_equal(turned[0][:-1], q[:-1])
    assert turned[0][-1] == READY[-1]  # back where the start has it: no travel for the wrist
    np.testing.assert_allclose(runtime.robot.tcp_pose(turned[0]).position, runtime.robot.tcp_pose(q).position, atol=1e-12)


def test_a_solution_blocked_at_every_turn_of_the_hand_stays_blocked(runtime: RuntimeModel, monkeypatch) -> None:
    hand_blocked_unless_turned_to(runtime, 99.0, monkeypatch)  # no angle the joint can reach

    assert selector(runtime)._turned_clear(READY + 0.1, READY, runtime.envelope.limits.max_joint_step_rad) is None


def test_arrival_ranks_a_goal_by_how_close_its_bodies_are_to_a_zone(runtime: RuntimeModel) -> None:
    """The ready pose a few millimetres above a block, with a 1 cm sweep resolution: clear with
    5 mm of growth (what a plan's last sample gets at most), 2.5 mm, or neither."""
    assert runtime.envelope.limits.sweep_resolution_m == 0.01
    ranks = {}
    for gap_mm in (1.0, 4.0, 6.0):
        model = with_zones(runtime, hemmed_block(runtime, gap_mm / 1e3))
        assert not [v for v in model.envelope.check_path(READY) if v.is_hard]  # clear in itself
        ranks[gap_mm] = selector(model).arrival(READY)
    assert ranks == {1.0: CLOSE_TO_A_ZONE, 4.0: 1, 6.0: 0}


def test_a_goal_close_to_a_zone_is_kept_and_ranked_after_the_others(runtime: RuntimeModel) -> None:
    model = with_zones(runtime, hemmed_block(runtime))
    position, rotation = ready_target(model)  # every solution's hand hovers 1 mm above the block
    selection = selector(model).select(READY + 0.3, position, rotation, seed=5, deadline=time.monotonic() + 2)
    assert selection.goals and set(selection.arrivals) == {CLOSE_TO_A_ZONE}
    assert len(selection.arrivals) == len(selection.goals)


def test_goals_clear_of_the_zones_by_the_whole_allowance_rank_before_closer_ones(runtime: RuntimeModel,
                                                                                 monkeypatch) -> None:
    chooser = selector(runtime)
    position, rotation = ready_target(runtime)
    plain = chooser.select(READY, position, rotation, seed=2, deadline=time.monotonic() + 2)
    assert len(plain.goals) >= 2
    late = plain.goals[0]  # the best goal, made to look close to a zone
    monkeypatch.setattr(chooser, "arrival", lambda q: CLOSE_TO_A_ZONE if np.array_equal(q, late) else 0)
    ranked = chooser.select(READY, position, rotation, seed=2, deadline=time.monotonic() + 2)
    assert not np.array_equal(ranked.goals[0], late)
    with_approach = [rank for rank, approach in zip(ranked.arrivals, ranked.approaches, strict=True) if approach is not None]
    assert with_approach == sorted(with_approach)  # then by rank; and it is kept only behind the others
    assert all(rank == 0 for goal, rank in zip(ranked.goals, ranked.arrivals, strict=True) if not np.array_equal(goal, late))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(waypoints=st.lists(arrays(np.float64, 7, elements=st.floats(-0.8, 0.8)), min_size=1, max_size=4),
       speed=st.floats(0.05, 1.0))
def test_no_body_gets_more_than_half_the_resolution_as_allowance_at_a_plans_last_sample(
        runtime: RuntimeModel, waypoints, speed) -> None:
    """What rank 0 rests on: whatever the path into a goal and its timing, each body's sweep
    allowance at the last fine sample is at most half of `motion.sweep_resolution_m`."""
    envelope = runtime.envelope
    positions = np.clip(np.vstack([READY + w for w in waypoints] + [READY]), runtime.robot.lower, runtime.robot.upper)
    times = np.concatenate([[0.0], np.cumsum(np.full(len(positions) - 1, 1.0 / speed))])
    _, _, inflation = envelope.sample_path(times, positions)
    assert float(np.max(inflation[-1])) <= 0.5 * envelope.limits.sweep_resolution_m + 1e-12
