"""The compiled geometry checks against the numpy ones they replace, and the semantics both share.

`Envelope(robot, limits)` checks geometry with the numba kernels of `safety.kernel`;
`Envelope(robot, limits, compiled=False)` with the numpy passes, kept as the oracle. Here both
must return the same violations (codes, bodies, times) and the same per-sample flags on random
paths, keep-out boxes and workspace boxes, and on the cases that matter most: a thin zone crossed
between samples, a self-collision pair, a pair with a body fixed to the world.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from armwarden.core.trajectory import JointTrajectory
from armwarden.safety.envelope import Envelope
from armwarden.safety.limits import Box
from armwarden.safety.sampling import Samples, samples_at
from armwarden.safety.violations import Code
from tests.helpers import READY


def _numpy(envelope: Envelope, **changes) -> Envelope:
    return Envelope(envelope.robot, dataclasses.replace(envelope.limits, **changes), compiled=False)


def _compiled(envelope: Envelope, **changes) -> Envelope:
    return Envelope(envelope.robot, dataclasses.replace(envelope.limits, **changes), compiled=True)


BOTH = pytest.mark.parametrize("make", [_numpy, _compiled], ids=["numpy", "compiled"])


# ---------------------------------------------------------------------------- semantics both share
@BOTH
def test_a_link_of_several_bodies_is_reported_at_its_earliest_finding(envelope: Envelope, make) -> None:
    """Fitted links are named once for all their capsules: the link's finding in a pass is its
    earliest sample's, whichever of its capsules it comes from."""
    checked = make(envelope)
    bodies = [b for b, c in enumerate(checked.robot.capsules) if c.link == "fr3_link5"]
    assert len(bodies) >= 2
    first, later = bodies[0], bodies[-1]
    inflation = np.zeros((2, len(checked.robot.capsules) + 1))
    inflation[0, later] = 10.0  # sample 0: only the link's last capsule leaves the workspace
    inflation[1, first] = 10.0  # sample 1: its first one
    samples = Samples(np.array([0.0, 1.0]), np.vstack([READY, READY]), inflation,
                      np.zeros((2, len(checked.self_collision_pairs))))
    found, flagged, _ = checked._geometry_pass(samples)
    (violation,) = [v for v in found.values() if v.code is Code.WORKSPACE and v.body == "fr3_link5"]
    assert violation.time_s == 0.0
    assert flagged.tolist() == [True, True]


@BOTH
def test_a_sample_is_not_a_finding_by_itself_for_the_line_to_another_flagged_sample(envelope: Envelope, make) -> None:
    """A flagged sample without its allowance is checked as the configuration it is: the straight
    line from the TCP of the flagged sample before it (which may be far along the path) is not
    where the TCP went, and must not make it a finding. Here the TCP swings on an arc around
    the base and a thin zone sits on the chord between the arc's ends, off the arc."""
    start, goal = READY.copy(), READY.copy()
    start[0], goal[0] = -0.8, 0.8
    chord_middle = (envelope.robot.tcp_pose(start).position + envelope.robot.tcp_pose(goal).position) / 2
    thin = Box.of("thin", chord_middle - 0.005, chord_middle + 0.005)
    checked = make(envelope, keep_out=(thin,))
    positions = np.vstack([start, goal])
    assert checked.check_path(positions) == ()  # the motion itself is clear
    path = checked._path_parameter(np.arange(2.0), positions)
    targets = np.array([0.0, path.total / 2, path.total])
    samples = samples_at(path, targets)
    found, _ = checked._refine(path, targets, samples, np.array([True, False, True]), 1, False)
    assert found == {}


# ---------------------------------------------------------------------------- compiled = numpy
def _said(violations) -> list[tuple[Code, str | None, float | None, str]]:
    return [(v.code, v.body, v.time_s, v.detail) for v in violations]


def _pair(envelope: Envelope, *changes: dict) -> tuple[Envelope, Envelope]:
    merged = {k: v for change in changes for k, v in change.items()}
    return _numpy(envelope, **merged), _compiled(envelope, **merged)


def _random_scene(rng: np.random.Generator, envelope: Envelope, lo: np.ndarray, hi: np.ndarray) -> dict:
    """Zero to three keep-out boxes near the arm and, half the time, a random workspace box."""
    robot = envelope.robot
    centre = robot.tcp_pose(rng.uniform(lo, hi) if rng.integers(0, 2) else READY).position
    zones = []
    for k in range(int(rng.integers(0, 4))):
        middle = centre + rng.uniform(-0.4, 0.4, 3)
        half = rng.uniform(0.002, 0.15, 3)
        zones.append(Box.of(f"zone{k}", middle - half, middle + half))
    changes: dict = {"keep_out": tuple(zones)}
    if rng.integers(0, 2):
        ws_lo = rng.uniform([-1.0, -1.0, -0.3], [-0.2, -0.2, 0.2])
        ws_hi = rng.uniform([0.2, 0.2, 0.5], [1.0, 1.0, 1.3])
        changes["workspace"] = Box.of("workspace", ws_lo, ws_hi)
    return changes


def _random_path(rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Two to four waypoints within the limits, each step up to ~1 rad per joint; half the time
    near the ready pose (mostly clear of the table and the arm itself, so the passes refine
    around near misses rather than stop at a contact)."""
    first = rng.uniform(lo, hi) if rng.integers(0, 2) else np.clip(READY + rng.uniform(-0.5, 0.5, len(lo)), lo, hi)
    steps = [first]
    for _ in range(int(rng.integers(1, 4))):
        steps.append(np.clip(steps[-1] + rng.uniform(-1.0, 1.0, len(lo)) * rng.uniform(0.0, 1.0), lo, hi))
    return np.vstack(steps)


SEEDS = st.integers(0, 2**32 - 1)
FUZZ = {"deadline": None, "suppress_health_check": [HealthCheck.too_slow, HealthCheck.function_scoped_fixture]}


def paths_judged_alike(seed: int, envelope: Envelope) -> None:
    """A random scene and path: `check_path` (full and first_only) and `check` of a timed version
    say the same in both envelopes, word for word."""
    rng = np.random.default_rng(seed)
    lo, hi = envelope.limits.lower_rad, envelope.limits.upper_rad
    numpy_envelope, compiled_envelope = _pair(envelope, _random_scene(rng, envelope, lo, hi))
    positions = _random_path(rng, lo, hi)
    for first_only in (False, True):
        expected = numpy_envelope.check_path(positions, first_only=first_only)
        assert _said(compiled_envelope.check_path(positions, first_only=first_only)) == _said(expected)
    times = np.concatenate([[0.0], np.cumsum(rng.uniform(0.05, 2.0, len(positions) - 1))])
    trajectory = JointTrajectory(envelope.robot.joint_names, times, positions)
    expected_report = numpy_envelope.check(trajectory)
    report = compiled_envelope.check(trajectory)
    assert _said(report.violations) == _said(expected_report.violations)
    assert report.samples_checked == expected_report.samples_checked
    assert report.tcp_path_length_m == pytest.approx(expected_report.tcp_path_length_m, abs=1e-12)


@settings(max_examples=40, **FUZZ)
@given(seed=SEEDS)
def test_compiled_and_numpy_checks_find_the_same_on_random_paths_and_scenes(seed: int, envelope: Envelope) -> None:
    paths_judged_alike(seed, envelope)


@pytest.mark.slow
@settings(max_examples=400, **FUZZ)
@given(seed=SEEDS)
def test_compiled_and_numpy_checks_find_the_same_on_random_paths_and_scenes_full_budget(seed: int,
                                                                                      envelope: Envelope) -> None:
    paths_judged_alike(seed, envelope)


def passes_flag_alike(seed: int, envelope: Envelope) -> None:
    """One pass over random samples with random inflations: the same flags, TCP positions and
    findings, with and without the TCP's segments between samples."""
    rng = np.random.default_rng(seed)
    lo, hi = envelope.limits.lower_rad, envelope.limits.upper_rad
    numpy_envelope, compiled_envelope = _pair(envelope, _random_scene(rng, envelope, lo, hi))
    n = int(rng.integers(1, 12))
    start, end = rng.uniform(lo, hi), rng.uniform(lo, hi)
    positions = start + np.linspace(0.0, 1.0, n)[:, None] * (end - start) * rng.uniform(0.0, 1.0)
    bodies, pairs = len(envelope.robot.capsules) + 1, len(envelope.self_collision_pairs)
    samples = Samples(np.sort(rng.uniform(0.0, 5.0, n)), positions, rng.uniform(0.0, 0.05, (n, bodies)),
                      rng.uniform(0.0, 0.05, (n, pairs)))
    segments = bool(rng.integers(0, 2))
    expected, expected_flags, expected_tcp = numpy_envelope._geometry_pass(samples, segments)
    found, flags, tcp = compiled_envelope._geometry_pass(samples, segments)
    assert flags.tolist() == expected_flags.tolist()
    np.testing.assert_allclose(tcp, expected_tcp, rtol=0, atol=1e-12)
    assert sorted(_said(found.values()), key=repr) == sorted(_said(expected.values()), key=repr)


@settings(max_examples=60, **FUZZ)
@given(seed=SEEDS)
def test_compiled_and_numpy_passes_flag_the_same_samples(seed: int, envelope: Envelope) -> None:
    passes_flag_alike(seed, envelope)


@settings(max_examples=60, **FUZZ)
@given(seed=SEEDS)
def test_compiled_and_numpy_judge_one_configuration_and_its_arrival_alike(seed: int, envelope: Envelope) -> None:
    rng = np.random.default_rng(seed)
    lo, hi = envelope.limits.lower_rad, envelope.limits.upper_rad
    numpy_envelope, compiled_envelope = _pair(envelope, _random_scene(rng, envelope, lo, hi))
    q = rng.uniform(lo - 0.1, hi + 0.1)  # now and then past a limit
    for first_only in (False, True):
        assert _said(compiled_envelope.check_path(q, first_only=first_only)) == _said(
            numpy_envelope.check_path(q, first_only=first_only))
    share = float(rng.uniform(0.0, 2.0))
    assert _said(compiled_envelope.check_arrival(q, share)) == _said(numpy_envelope.check_arrival(q, share))


# ---------------------------------------------------------------------------- the cases that matter most
@BOTH
def test_the_tcp_segment_between_two_samples_catches_a_thin_zone_neither_sample_touches(envelope: Envelope, make) -> None:
    """Within a pass the TCP's straight segment from the sample before counts: a 4 mm zone on the
    chord between two TCP positions flags the second sample, though neither TCP is near it."""
    start, goal = READY.copy(), READY.copy()
    start[0], goal[0] = -0.4, 0.4
    a, b = envelope.robot.tcp_pose(start).position, envelope.robot.tcp_pose(goal).position
    thin = Box.of("thin", (a + b) / 2 - 0.002, (a + b) / 2 + 0.002)
    checked = make(envelope, keep_out=(thin,))
    bodies, pairs = len(envelope.robot.capsules) + 1, len(envelope.self_collision_pairs)
    samples = Samples(np.array([0.0, 1.0]), np.vstack([start, goal]), np.zeros((2, bodies)), np.zeros((2, pairs)))
    found, flagged, _ = checked._geometry_pass(samples)
    assert [(v.code, v.body, v.time_s) for v in found.values()] == [(Code.KEEP_OUT, "fr3_hand_tcp", 1.0)]
    assert flagged.tolist() == [False, True]
    alone, _, _ = checked._geometry_pass(samples, segments=False)
    assert alone == {}


@BOTH
def test_folding_the_wrist_onto_the_upper_arm_is_found_by_both(envelope: Envelope, make) -> None:
    goal = READY.copy()
    goal[3], goal[5] = -3.0, 0.6  # elbow fully folded, wrist bent back toward the upper arm
    checked = make(envelope)
    findings = checked.check_path(np.vstack([READY, goal]))
    assert any(v.code is Code.SELF_COLLISION for v in findings)
    assert _said(findings) == _said(_numpy(envelope).check_path(np.vstack([READY, goal])))


#: the hand folded down onto the FR3's base (link 0, fixed to the world)
HAND_ON_THE_BASE = np.array([1.38, -1.062, -2.367, -2.643, 2.423, 3.68, -1.807])


@BOTH
def test_a_body_fixed_to_the_world_collides_with_the_hand(envelope: Envelope, make) -> None:
    everywhere = Box.of("workspace", [-5.0, -5.0, -5.0], [5.0, 5.0, 5.0])
    checked = make(envelope, workspace=everywhere, keep_out=())
    findings = checked.check_path(HAND_ON_THE_BASE)
    assert [(v.code, v.body) for v in findings] == [(Code.SELF_COLLISION, "fr3_link0|fr3_hand")]
    assert _said(findings) == _said(_numpy(envelope, workspace=everywhere, keep_out=()).check_path(HAND_ON_THE_BASE))


@BOTH
def test_bodies_fixed_to_the_world_are_not_checked_against_zones_or_the_workspace(envelope: Envelope, make) -> None:
    around_the_base = Box.of("base", [-0.3, -0.3, -0.2], [0.2, 0.3, 0.1])
    checked = make(envelope, keep_out=(around_the_base,))
    assert [v for v in checked.check_path(READY) if v.body == "fr3_link0"] == []


def test_a_non_finite_configuration_is_refused_as_the_numpy_check_refuses_it(envelope: Envelope) -> None:
    q = READY.copy()
    q[2] = np.nan
    expected = _numpy(envelope).check_path(np.vstack([READY, q]))
    assert any(v.is_hard for v in expected)
    assert _said(_compiled(envelope).check_path(np.vstack([READY, q]))) == _said(expected)
    assert _said(_compiled(envelope).check_path(q)) == _said(_numpy(envelope).check_path(q))


@BOTH
def test_first_only_reports_the_first_of_the_full_checks_findings(envelope: Envelope, make) -> None:
    """A search asks only whether something is hit: it gets one geometric finding, the one the
    full check reports first (wording every finding costs more than the check itself)."""
    checked = make(envelope)
    full = checked.check_path(HAND_ON_THE_BASE)
    assert len(full) > 1 and all(v.code is not Code.JOINT_LIMIT and v.code is not Code.NEAR_JOINT_LIMIT for v in full)
    assert checked.check_path(HAND_ON_THE_BASE, first_only=True) == full[:1]
    motion = np.vstack([READY, HAND_ON_THE_BASE])
    first = checked.check_path(motion, first_only=True)
    assert len(first) == 1 and (first[0].code, first[0].body) in {(v.code, v.body) for v in checked.check_path(motion)}
