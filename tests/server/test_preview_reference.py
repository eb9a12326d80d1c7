"""The cheap plan preview draws what the previous renderer drew: the same plans rendered by both
(`preview_before.py`, the renderer before issue 13) agree pixel for pixel within a small
tolerance, and the cached static scene never carries one plan's strokes into the next picture."""

from __future__ import annotations

import io
import sys
import threading

import numpy as np
import pytest

from armwarden.core.trajectory import JointTrajectory
from armwarden.policy import bundled_policy, load_policy
from armwarden.preflight import RuntimeModel, load_runtime_model
from armwarden.preview.render import PlanPreviewer
from tests.helpers import READY
from tests.server import preview_before

Image = pytest.importorskip("PIL.Image")

#: a pixel "differs" when a channel is off by more than this (anti-aliasing and rounding noise)
CHANNEL_TOLERANCE = 24
#: at most this share of the pixels may differ (a few stroke-edge pixels, nothing drawn elsewhere)
PIXEL_SHARE_TOLERANCE = 0.002

#: fixed joint-space goals, as offsets from READY [rad]: a small turn, a reach into the monitor
#: zone (hard violation, red crosses), a long sweep, a dive towards the table, and a reach far
#: beyond the workspace (a larger picture scale than the workspace box's)
GOALS = {
    "small_turn": [0.6, 0, 0, 0, 0, 0, 0],
    "into_monitor": [0.9, 1.085398, 0, 0.756194, 0, 0, 0],
    "long_sweep": [0.5, 0.25, -0.2, 0.3, 0.2, -0.3, 0.4],
    "towards_table": [-0.4, 0.9, 0.0, 0.6, 0.0, 0.4, 0.0],
    "far_out": [0.0, 2.2, 0.0, 2.28, 0.0, -1.0, 0.0],
}


@pytest.fixture(scope="module")
def runtime() -> RuntimeModel:
    return load_runtime_model(load_policy(bundled_policy("fr3")))


def plan(runtime: RuntimeModel, name: str):
    goal = READY + np.asarray(GOALS[name])
    trajectory = runtime.planner.plan_to_joints(READY, goal).trajectory
    assert trajectory is not None
    return trajectory, runtime.envelope.check(trajectory)


def pixels(png: bytes | None) -> np.ndarray:
    assert png is not None
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)


def differing_share(a: np.ndarray, b: np.ndarray) -> float:
    assert a.shape == b.shape
    return float(np.mean(np.abs(a - b).max(axis=2) > CHANNEL_TOLERANCE))


@pytest.mark.parametrize("name", sorted(GOALS))
def test_the_cheap_preview_draws_what_the_previous_renderer_drew(runtime: RuntimeModel, name: str) -> None:
    trajectory, report = plan(runtime, name)
    before = preview_before.render_plan_preview(runtime.robot, runtime.envelope.limits, trajectory, report)
    now = PlanPreviewer(runtime.envelope.limits).render(runtime.robot, trajectory, report)
    assert differing_share(pixels(before), pixels(now)) <= PIXEL_SHARE_TOLERANCE


def test_a_preview_without_a_trajectory_shows_the_same_boxes_as_before(runtime: RuntimeModel) -> None:
    _, report = plan(runtime, "small_turn")
    before = preview_before.render_plan_preview(runtime.robot, runtime.envelope.limits, None, report, status="rejected")
    now = PlanPreviewer(runtime.envelope.limits).render(runtime.robot, None, report, status="rejected")
    assert differing_share(pixels(before), pixels(now)) <= PIXEL_SHARE_TOLERANCE


def test_a_different_size_draws_what_the_previous_renderer_drew_at_that_size(runtime: RuntimeModel) -> None:
    trajectory, report = plan(runtime, "into_monitor")
    before = preview_before.render_plan_preview(runtime.robot, runtime.envelope.limits, trajectory, report, size=(520, 280))
    now = PlanPreviewer(runtime.envelope.limits, (520, 280)).render(runtime.robot, trajectory, report)
    assert differing_share(pixels(before), pixels(now)) <= PIXEL_SHARE_TOLERANCE


def test_a_reused_previewer_draws_each_plan_as_a_fresh_one_would(runtime: RuntimeModel) -> None:
    shared = PlanPreviewer(runtime.envelope.limits)
    for name in ("into_monitor", "far_out", "small_turn", "long_sweep"):  # scales change and come back
        trajectory, report = plan(runtime, name)
        fresh = PlanPreviewer(runtime.envelope.limits).render(runtime.robot, trajectory, report)
        assert shared.render(runtime.robot, trajectory, report) == fresh


def test_plans_inside_the_workspace_share_one_static_scene(runtime: RuntimeModel) -> None:
    previewer = PlanPreviewer(runtime.envelope.limits)
    for name in ("small_turn", "long_sweep", "into_monitor"):
        previewer.render(runtime.robot, *plan(runtime, name))
    assert len(previewer._scenes) == 1


def test_a_malformed_trajectory_draws_the_boxes_alone_as_before(runtime: RuntimeModel) -> None:
    trajectory, report = plan(runtime, "small_turn")
    broken = JointTrajectory(trajectory.joint_names, trajectory.times, np.full_like(trajectory.positions, np.nan))
    before = preview_before.render_plan_preview(runtime.robot, runtime.envelope.limits, broken, report)
    now = PlanPreviewer(runtime.envelope.limits).render(runtime.robot, broken, report)
    assert differing_share(pixels(before), pixels(now)) <= PIXEL_SHARE_TOLERANCE


def test_a_previewer_shared_by_two_threads_gives_each_plan_its_own_picture() -> None:
    """Each thread brings its own robot model (Pinocchio's data is not thread safe); the previewer,
    whose pictures share one canvas per scene, draws one at a time."""
    policy = load_policy(bundled_policy("fr3"))
    runtimes = [load_runtime_model(policy), load_runtime_model(policy)]
    plans = [plan(runtimes[0], "small_turn"), plan(runtimes[0], "into_monitor")]  # one scene, two pictures
    shared = PlanPreviewer(runtimes[0].envelope.limits)
    expected = [shared.render(runtimes[0].robot, *planned) for planned in plans]
    wrong = [0, 0]

    def draw(k: int) -> None:
        for _ in range(100):
            wrong[k] += shared.render(runtimes[k].robot, *plans[k]) != expected[k]

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-5)  # threads take turns often: a picture shared between them shows at once
    try:
        threads = [threading.Thread(target=draw, args=(k,)) for k in (0, 1)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
    finally:
        sys.setswitchinterval(interval)
    assert wrong == [0, 0]
