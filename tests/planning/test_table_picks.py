"""Table picks (issue 25): top-down picks on the 56-cell table grid, through the Guard, densely checked.

The grid, the pick (pre-grasp by `plan_to_pose`, straight descent and lift by
`plan_cartesian_path`, from home, bundled policy) and the runner are in
`scripts/_bench/table_picks.py`, shared with `scripts/bench.py table`; the dense check is
`scripts/_bench/dense_check.py`; here, the denominator and the dense check itself.

The denominator — the cells a real FR3 reaches hand-down within its joint limits — is committed
(`tests/planning/data/table_reachable.yaml`, made from Franka's meshes by the command its header
names), so CI needs no meshes: here its witnesses are checked to be what they claim, and where
the mesh cache exists (`scripts/_bench/dense_check.py --source PATH`) the file is recomputed from
the meshes; without it that test skips, saying so.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from armwarden.policy import Policy

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts" / "_bench"))

import dense_check  # scripts/_bench, on the path above
import table_picks
from dense_check import ArmKinematics, DenseChecker, Zone

#: the issue's bar: picked cells among those a real FR3 reaches
GOAL = 0.95
MESHES = dense_check.load_meshes()
needs_meshes = pytest.mark.skipif(
    MESHES is None,
    reason=f"no mesh cache at {dense_check.mesh_cache_path()} (Franka's meshes are fetched, never committed): make it "
    "with `.venv/bin/python scripts/_bench/dense_check.py --source PATH-TO-franka_description` "
    f"or point {dense_check.MESH_CACHE_ENV} at one",
)


@pytest.fixture(scope="module")
def reachable() -> dict:
    return table_picks.load_reachable()


@pytest.fixture(scope="module")
def zones(fr3_policy: Policy) -> tuple[Zone, ...]:
    return dense_check.policy_zones(fr3_policy)


@pytest.fixture(scope="module")
def arm() -> ArmKinematics:
    return ArmKinematics(table_picks.GRIPPER_WIDTH_M)


# ------------------------------------------------------------------ the denominator


def test_the_committed_denominator_covers_the_grid_with_witnesses_that_reach_their_cells(reachable, arm) -> None:
    cells = reachable["cells"]
    assert [(c["x"], c["y"]) for c in cells] == table_picks.grid_cells()
    assert reachable["reachable"] == sum(c["reachable"] for c in cells) == len(table_picks.reachable_set(reachable))
    for cell in (c for c in cells if c["reachable"]):
        q = np.array(cell["q"])
        assert np.all(q >= arm.lower) and np.all(q <= arm.upper), cell
        tcp = arm.tcp_pose(q)
        assert tcp.translation == pytest.approx([cell["x"], cell["y"], table_picks.GRASP_Z_M], abs=1e-5), cell
        assert math.degrees(math.acos(min(1.0, -tcp.rotation[2, 2]))) < 0.01, cell  # the hand points down


@needs_meshes
def test_the_denominator_regenerates_from_the_meshes_as_committed(reachable, zones) -> None:
    assert MESHES is not None
    assert MESHES.commit == reachable["meshes_commit"]
    options = table_picks.SearchOptions(**{k: reachable["search"][k] for k in ("seeds", "rng_seed", "iterations")})
    fresh = table_picks.reachable_cells(MESHES, zones, options)
    assert [(r.x, r.y, r.reachable) for r in fresh] == [(c["x"], c["y"], c["reachable"]) for c in reachable["cells"]]
    for result, cell in zip(fresh, reachable["cells"], strict=True):
        if result.reachable:
            assert result.q == pytest.approx(cell["q"], abs=1e-6)
            assert min(result.clearance_m.values()) > 0.0


# ------------------------------------------------------------------ the dense check itself


def test_the_fast_forward_kinematics_of_the_dense_check_equals_pinocchio(arm) -> None:
    qs = np.random.default_rng(25).uniform(arm.lower, arm.upper, (200, 7))
    assert np.max(np.abs(arm.joint_frames(qs) - arm.joint_frames_pinocchio(qs))) < 1e-12


def test_no_point_of_any_fitted_capsule_moves_more_than_a_millimetre_between_dense_checks(arm, zones) -> None:
    checker = DenseChecker(arm, dense_check.fitted_capsules(arm), zones)
    rng = np.random.default_rng(3)
    path = rng.uniform(arm.lower, arm.upper, (4, 7))  # long jumps: each segment is cut many times
    samples = dense_check.resample(path, checker.reach)
    # points on every capsule's surface: its end points pushed out by its radius along ±x, ±y, ±z
    offsets = np.vstack([np.eye(3), -np.eye(3)])
    moved = 0.0
    frames = arm.joint_frames(samples)
    for body in (b for b in checker.geometry.bodies if b.joint >= 0):
        local = (body.points[:, None, :] + body.radius_m * offsets[None]).reshape(-1, 3)
        world = np.einsum("nij,pj->npi", frames[:, body.joint, :3, :3], local) + frames[:, body.joint, None, :3, 3]
        moved = max(moved, float(np.max(np.linalg.norm(np.diff(world, axis=0), axis=2))))
    assert len(samples) > 1000
    assert moved <= dense_check.MAX_STEP_M


def test_the_dense_check_finds_the_fingers_pushed_into_the_table(arm, zones) -> None:
    ik = table_picks.HandDownIk(arm, table_picks.SearchOptions())
    above = ik.solve(np.array([0.45, 0.0, 0.05]), np.array(table_picks.HOME))
    assert above is not None
    into = ik.solve(np.array([0.45, 0.0, -0.005]), above)  # the TCP 5 mm into the table
    assert into is not None
    checker = DenseChecker(arm, dense_check.fitted_capsules(arm), zones)

    assert checker.check(np.vstack([above, above])).clear
    report = checker.check(np.vstack([above, into]))
    assert not report.clear and "table" in report.contacts[0]
    assert report.table_clearance_m < 0.0


def test_the_dense_check_finds_a_thin_zone_crossed_between_two_waypoints(arm) -> None:
    """Both waypoints are clear of a 2 mm wall; the straight joint line between them crosses it."""
    ik = table_picks.HandDownIk(arm, table_picks.SearchOptions())
    right = ik.solve(np.array([0.45, -0.15, 0.10]), np.array(table_picks.HOME))
    assert right is not None
    left = ik.solve(np.array([0.45, 0.15, 0.10]), right)
    assert left is not None
    wall = Zone("wall", np.array([0.40, -0.001, 0.05]), np.array([0.50, 0.001, 0.15]))
    checker = DenseChecker(arm, dense_check.fitted_capsules(arm), [wall])

    assert checker.check(np.vstack([right, right])).clear and checker.check(np.vstack([left, left])).clear
    report = checker.check(np.vstack([right, left]))
    assert not report.clear and "'wall'" in report.contacts[0]
    assert report.zone_clearance_m["wall"] == 0.0
