"""The benchmark's scenes (scripts/_bench/planner_scenes.py): every plan the planner returns as
accepted there passes the independent dense oracle with zero findings, and none raises.

The default run takes one scene; `-m slow` all of them and the near-obstacle set.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

from armwarden.guard.planning import plan_and_check
from armwarden.planning.planners import PoseTarget
from armwarden.preflight import RuntimeModel
from armwarden.safety.envelope import Envelope
from tests.planning.scenarios import oracle_for, with_zones

SCENES_PATH = Path(__file__).resolve().parents[2] / "scripts" / "_bench" / "planner_scenes.py"


def load_scenes() -> ModuleType:
    spec = importlib.util.spec_from_file_location("planner_scenes", SCENES_PATH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("planner_scenes", module)
    spec.loader.exec_module(module)
    return module


SCENES = load_scenes()
SCENE_NAMES = [scene.name for scene in SCENES.scene_set()]


def oracle_findings(runtime: RuntimeModel, scene) -> tuple[int, list[str]]:
    """(accepted plans, the oracle's findings on them) for every target of `scene`."""
    model = with_zones(runtime, *scene.zones, budget_s=runtime.policy.motion.planning_time_s)  # as the benchmark
    oracle = oracle_for(model)
    accepted, findings = 0, []
    for target in scene.targets:
        outcome, report = plan_and_check(model, "pose", scene.start, {"target": target})
        if report is None or report.hard or outcome.trajectory is None:
            continue
        accepted += 1
        findings += [f"{scene.name} {target.position}: {f}" for f in oracle.violations(outcome.trajectory)]
    return accepted, findings


def test_accepted_plans_in_the_bin_scene_pass_the_dense_oracle(runtime: RuntimeModel) -> None:
    (scene,) = [s for s in SCENES.scene_set() if s.name == "bin in front"]
    accepted, findings = oracle_findings(runtime, scene)
    assert accepted >= 1 and findings == []


@pytest.mark.slow
@pytest.mark.parametrize("name", SCENE_NAMES)
def test_accepted_plans_in_every_scene_pass_the_dense_oracle(runtime: RuntimeModel, name: str) -> None:
    (scene,) = [s for s in SCENES.scene_set() if s.name == name]
    _, findings = oracle_findings(runtime, scene)
    assert findings == []


@pytest.mark.slow
def test_accepted_plans_of_the_near_obstacle_set_pass_the_dense_oracle(runtime: RuntimeModel) -> None:
    accepted, findings = oracle_findings(runtime, SCENES.near_obstacle_set())
    assert accepted >= 1 and findings == []


@pytest.mark.slow
@pytest.mark.parametrize("finer", [False, True], ids=["caps raised", "caps raised, finer sweep resolution"])
def test_accepted_plans_of_the_near_obstacle_set_with_relaxed_limits_pass_the_dense_oracle(runtime: RuntimeModel,
                                                                                          finer: bool) -> None:
    relaxed = SCENES.with_raised_caps(runtime, SCENES.FINER_SWEEP_RESOLUTION_M if finer else None)
    accepted, findings = oracle_findings(relaxed, SCENES.near_obstacle_set())
    assert accepted >= 1 and findings == []


def test_a_target_farther_than_the_tcp_path_cap_is_beyond_the_per_plan_caps(runtime: RuntimeModel) -> None:
    start = SCENES.READY
    here = runtime.robot.tcp_pose(start).position
    far = here + [0.0, runtime.envelope.limits.max_cartesian_step_m + 0.02, 0.0]

    assert not SCENES.within_caps(runtime, start, PoseTarget(far, None))


def test_a_target_a_few_centimetres_from_the_start_is_within_the_per_plan_caps(runtime: RuntimeModel) -> None:
    start = SCENES.READY
    near = runtime.robot.tcp_pose(start).position + [0.05, 0.0, -0.05]

    assert SCENES.within_caps(runtime, start, PoseTarget(near, None))


def caps(runtime: RuntimeModel, travel_rad: float) -> RuntimeModel:
    """`runtime` with a generous TCP path cap and `travel_rad` as the joint travel cap."""
    limits = dataclasses.replace(runtime.envelope.limits, max_cartesian_step_m=2.0, max_joint_step_rad=travel_rad)
    return dataclasses.replace(runtime, envelope=Envelope(runtime.robot, limits))


def behind_the_robot(runtime: RuntimeModel):
    """The ready pose's TCP mirrored behind the base: reached only by swinging the base round."""
    return PoseTarget(runtime.robot.tcp_pose(SCENES.READY).position * [-1.0, 1.0, 1.0], None)


def test_a_target_whose_only_goals_travel_too_far_is_beyond_the_per_plan_caps(runtime: RuntimeModel) -> None:
    assert not SCENES.within_caps(caps(runtime, 1.0), SCENES.READY, behind_the_robot(runtime))


def test_the_same_target_is_within_a_looser_travel_cap(runtime: RuntimeModel) -> None:
    assert SCENES.within_caps(caps(runtime, 2.0), SCENES.READY, behind_the_robot(runtime))
