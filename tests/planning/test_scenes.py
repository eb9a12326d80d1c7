"""The benchmark's scenes (scripts/_bench/planner_scenes.py): every plan the planner returns as
accepted there passes the independent dense oracle with zero findings, and none raises.

The default run takes one scene; `-m slow` all of them and the near-obstacle set.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

from armwarden.guard.planning import plan_and_check
from armwarden.preflight import RuntimeModel
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
    model = with_zones(runtime, *scene.zones)
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
