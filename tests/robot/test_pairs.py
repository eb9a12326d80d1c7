"""Self-collision pairs by analysis (armwarden.robot.pairs).

A toy arm checks each kind of verdict and that a pair touching only in a sliver of its joint
range is kept although no random sample sees it; the bundled FR3's analysis is held against a
dense sampled check — which can only confirm the proofs, never replace them.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import pytest

from armwarden.core.geometry import segment_segment_distance
from armwarden.robot.fitted_file import FittedBody, FittedGeometry, LinkFit, load_fitted
from armwarden.robot.model import resolve_description
from armwarden.robot.pairs import PairOptions, PlacedBody, analyse_pairs, place_bodies

FITTED_PATH = resolve_description("builtin:fr3").parent / "fitted.yaml"

TOY_URDF = """<?xml version="1.0"?>
<robot name="toy">
  <link name="base"/>
  <joint name="j1" type="revolute"><origin xyz="0 0 0"/><parent link="base"/><child link="arm1"/>
    <axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <link name="arm1"/>
  <joint name="j2" type="revolute"><origin xyz="0.3 0 0"/><parent link="arm1"/><child link="arm2"/>
    <axis xyz="0 0 1"/><limit lower="-1" upper="{upper}" effort="1" velocity="1"/></joint>
  <link name="arm2"/>
</robot>
"""


def toy(upper: float, bodies: dict[str, list[tuple[tuple[float, float, float], tuple[float, float, float], float]]]
        ) -> tuple[pin.Model, list[PlacedBody]]:
    model = pin.buildModelFromXML(TOY_URDF.format(upper=upper))
    links = {
        link: LinkFit(link, "toy", tuple(FittedBody(f"{link}/{i}", p0, p1, r) for i, (p0, p1, r) in enumerate(specs)), 0, 0, 0.0, ())
        for link, specs in bodies.items()
    }
    geometry = FittedGeometry(robot="toy", source={}, margin_m=0.0, links=links)
    return model, place_bodies(model, geometry)


def decisions(model: pin.Model, bodies: list[PlacedBody], **options: int | float) -> dict[tuple[str, str], str]:
    return {v.bodies: v.decision for v in analyse_pairs(model, bodies, PairOptions(**options)).verdicts}  # type: ignore[arg-type]


ARM2 = [((0.05, 0.0, 0.0), (0.25, 0.0, 0.0), 0.03)]


def test_a_post_out_of_the_arms_reach_is_proved_apart() -> None:
    model, bodies = toy(1.0, {"base": [((-0.6, 0.0, 0.0), (-0.6, 0.0, 0.2), 0.05)], "arm2": ARM2})
    assert decisions(model, bodies) == {("base/0", "arm2/0"): "apart"}


def test_housings_around_one_joint_axis_are_proved_overlapping() -> None:
    model, bodies = toy(1.0, {"arm1": [((0.3, 0.0, -0.05), (0.3, 0.0, 0.05), 0.04)],
                              "arm2": [((0.0, 0.0, -0.04), (0.0, 0.0, 0.04), 0.04)]})
    assert decisions(model, bodies) == {("arm1/0", "arm2/0"): "overlapping"}


def test_the_other_bodies_of_adjacent_links_always_in_contact_are_left_out_naming_the_witness() -> None:
    model, bodies = toy(1.0, {"arm1": [((0.3, 0.0, -0.05), (0.3, 0.0, 0.05), 0.04), ((0.4393, 0.1435, 0.0), (0.4393, 0.1435, 0.0), 0.01)],
                              "arm2": [((0.0, 0.0, -0.04), (0.0, 0.0, 0.04), 0.04), *ARM2]})
    verdicts = {v.bodies: v for v in analyse_pairs(model, bodies, PairOptions()).verdicts}
    assert verdicts[("arm1/0", "arm2/0")].decision == "overlapping"
    swinging = verdicts[("arm1/1", "arm2/1")]
    assert swinging.decision == "adjacent"
    assert "arm1/0 and arm2/0 overlap at every configuration" in swinging.reason


def test_links_two_joints_apart_are_never_left_out_for_being_in_contact() -> None:
    # base is two joints away from arm2: a body pair there that always overlaps does not drag
    # the base's other body pair with it
    model, bodies = toy(1.0, {"base": [((0.0, 0.0, -0.5), (0.0, 0.0, 0.5), 0.6), ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.01)],
                              "arm2": ARM2})
    found = decisions(model, bodies)
    assert found[("base/0", "arm2/0")] == "overlapping"
    assert found[("base/1", "arm2/0")] != "adjacent"


def test_a_pair_that_touches_only_in_a_sliver_at_the_joint_limit_stays_in_though_no_sample_sees_it() -> None:
    # a knob on arm1 that arm2's capsule reaches only for q2 within ~1e-3 rad of its upper limit:
    # random samples miss it; the branch and bound cannot prove the pair apart, so it stays in
    upper = 1.2
    reach = 0.2  # the knob's distance from joint 2's axis
    gap = 0.03 + 0.005  # arm2's radius plus the knob's
    angle = upper + np.arcsin(gap / reach) - 1e-3  # contact starts 1e-3 rad before the limit
    knob = (0.3 + reach * np.cos(angle), reach * np.sin(angle), 0.0)
    model, bodies = toy(upper, {"arm1": [(knob, knob, 0.005)], "arm2": ARM2})
    sampled = analyse_pairs(model, bodies, PairOptions(witness_samples=0, max_boxes=1)).verdicts[0]
    assert sampled.decision == "included"  # one box proves nothing: kept
    verdict = analyse_pairs(model, bodies, PairOptions(witness_samples=200, seed=3)).verdicts[0]
    assert verdict.decision == "included"
    # and with the joint limit 2 mrad lower the same pair is proved apart
    model, bodies = toy(upper - 2e-3, {"arm1": [(knob, knob, 0.005)], "arm2": ARM2})
    assert decisions(model, bodies) == {("arm1/0", "arm2/0"): "apart"}


def test_no_random_sample_sees_the_sliver() -> None:
    """The premise of the test above: its 200 seeded samples (the analysis seeds each link pair's
    generator with [seed, index of the first link, index of the second]) never touch."""
    upper, reach, gap = 1.2, 0.2, 0.035
    angle = upper + np.arcsin(gap / reach) - 1e-3
    rng = np.random.default_rng([3, 0, 1])
    q2 = -1.0 + rng.random(200) * (upper + 1.0)
    tips = np.stack([np.cos(q2), np.sin(q2), np.zeros_like(q2)], axis=1)
    knob = np.array([reach * np.cos(angle), reach * np.sin(angle), 0.0])
    distance = segment_segment_distance(0.05 * tips, 0.25 * tips, np.broadcast_to(knob, tips.shape), np.broadcast_to(knob, tips.shape))
    assert np.all(distance > gap)


def test_clearance_keeps_a_close_pair_in() -> None:
    model, bodies = toy(1.0, {"base": [((-0.6, 0.0, 0.0), (-0.6, 0.0, 0.2), 0.05)], "arm2": ARM2})
    assert decisions(model, bodies, clearance_m=1.0) == {("base/0", "arm2/0"): "included"}


# --------------------------------------------------------------------------- the bundled FR3


@pytest.fixture(scope="module")
def fr3() -> tuple[pin.Model, dict[str, PlacedBody], FittedGeometry]:
    model = pin.buildModelFromUrdf(str(resolve_description("builtin:fr3")))
    geometry = load_fitted(FITTED_PATH)
    return model, {b.name: b for b in place_bodies(model, geometry)}, geometry


def _chain(model: pin.Model, joint: int) -> list[int]:
    chain = [joint]
    while chain[-1] != 0:
        chain.append(int(model.parents[chain[-1]]))
    return chain


def _sampled_distances(model: pin.Model, a: PlacedBody, b: PlacedBody, n: int, rng: np.random.Generator) -> np.ndarray:
    """Segment distances over n configurations: every corner of the joints' box, then uniform."""
    joints = sorted(set(_chain(model, a.joint)) ^ set(_chain(model, b.joint)))
    idx = [model.joints[j].idx_q for j in joints]
    lower, upper = model.lowerPositionLimit[idx], model.upperPositionLimit[idx]
    if idx:
        corners = np.array(np.meshgrid(*[[lo, hi] for lo, hi in zip(lower, upper, strict=True)], indexing="ij")).reshape(len(idx), -1).T
        values = np.vstack([corners, lower + rng.random((n, len(idx))) * (upper - lower)])
    else:  # fixed to each other: one configuration says it all
        values = np.zeros((1, 0))
    data = model.createData()
    ends = np.empty((len(values), 4, 3))
    q = pin.neutral(model)
    for k, v in enumerate(values):
        q[idx] = v
        pin.forwardKinematics(model, data, q)
        ma, mb = data.oMi[a.joint], data.oMi[b.joint]
        ends[k] = (ma.act(a.p0), ma.act(a.p1), mb.act(b.p0), mb.act(b.p1))
    return segment_segment_distance(ends[:, 0], ends[:, 1], ends[:, 2], ends[:, 3])


def test_the_bundled_analysis_covers_every_pair_of_bodies_on_different_links(fr3) -> None:
    _, bodies, geometry = fr3
    listed = {frozenset(p) for p in geometry.included_pairs} | {frozenset(p.bodies) for p in geometry.excluded_pairs}
    expected = {frozenset((a.name, b.name)) for a in bodies.values() for b in bodies.values() if a.link < b.link}
    assert listed == expected
    assert len(geometry.included_pairs) + len(geometry.excluded_pairs) == len(expected)


def test_the_bundled_analysis_used_the_urdf_joint_limits(fr3) -> None:
    model, _, geometry = fr3
    for joint, (lo, hi) in geometry.joint_limits.items():
        idx = model.joints[model.getJointId(joint)].idx_q
        assert (lo, hi) == (model.lowerPositionLimit[idx], model.upperPositionLimit[idx])


def test_pairs_proved_apart_never_touch_on_a_dense_sampled_sweep(fr3) -> None:
    model, bodies, geometry = fr3
    rng = np.random.default_rng(11)
    apart = [p for p in geometry.excluded_pairs if p.reason == "apart"]
    assert apart
    for pair in apart:
        a, b = bodies[pair.bodies[0]], bodies[pair.bodies[1]]
        distance = _sampled_distances(model, a, b, 500, rng)
        assert np.min(distance) > a.radius_m + b.radius_m + geometry.pair_clearance_m, pair.bodies


def test_pairs_proved_overlapping_overlap_on_a_dense_sampled_sweep(fr3) -> None:
    model, bodies, geometry = fr3
    rng = np.random.default_rng(12)
    overlapping = [p for p in geometry.excluded_pairs if p.reason == "overlapping"]
    assert overlapping
    for pair in overlapping:
        a, b = bodies[pair.bodies[0]], bodies[pair.bodies[1]]
        assert np.max(_sampled_distances(model, a, b, 500, rng)) < a.radius_m + b.radius_m, pair.bodies


def test_pairs_left_out_as_adjacent_are_on_links_one_joint_apart_with_an_overlapping_witness(fr3) -> None:
    model, bodies, geometry = fr3
    overlapping = {frozenset(bodies[n].link for n in p.bodies) for p in geometry.excluded_pairs if p.reason == "overlapping"}
    for pair in (p for p in geometry.excluded_pairs if p.reason == "adjacent"):
        a, b = bodies[pair.bodies[0]], bodies[pair.bodies[1]]
        assert frozenset((a.link, b.link)) in overlapping
        assert len(set(_chain(model, a.joint)) ^ set(_chain(model, b.joint))) <= 1


def test_the_wrist_and_the_flange_stay_checked_against_each_other(fr3) -> None:
    """link5 and link7 are two joints apart: some of their bodies meet within the limits."""
    _, bodies, geometry = fr3
    wrist_flange = [p for p in geometry.included_pairs if {bodies[n].link for n in p} == {"fr3_link5", "fr3_link7"}]
    assert wrist_flange
