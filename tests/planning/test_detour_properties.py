"""Properties of planning around zones (hypothesis): random keep-out boxes and targets.

Every plan that comes back accepted passes the independent dense oracle (no point of any link
enters a zone, leaves the workspace or touches another link, resampled at ≤ 1 mm point motion);
every refusal is a plan with hard violations, never an exception. Each example costs up to the
search budget plus the oracle's time (seconds), so the default run tries a few and `-m slow` many.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from armwarden.guard.planning import plan_and_check
from armwarden.planning.planners import PoseTarget
from armwarden.preflight import RuntimeModel
from armwarden.safety.limits import Box
from tests.helpers import DOWN, READY
from tests.planning.scenarios import oracle_for, with_zones

SEEDS = st.integers(0, 2**32 - 1)
FUZZ = {"deadline": None, "suppress_health_check": [HealthCheck.too_slow]}
BUDGET_S = 0.15


def findings_of_a_random_scene(seed: int, runtime: RuntimeModel) -> list[str]:
    """A box on the table in front of the robot and a pose target near one of its faces; plan
    around it. Returns the oracle's findings on an accepted plan ([] for a refusal)."""
    rng = np.random.default_rng(seed)
    centre = np.array([rng.uniform(0.3, 0.6), rng.uniform(-0.3, 0.3), 0.0])
    half = rng.uniform([0.03, 0.03, 0.05], [0.15, 0.15, 0.25])
    box = Box.of("random_box", centre - [half[0], half[1], 0.0], centre + half)
    face = rng.integers(0, 5)  # top, ±x, ±y
    offset = rng.uniform(0.02, 0.10)
    target = centre + rng.uniform(-1.0, 1.0, 3) * np.array([half[0], half[1], 0.0])
    target[2] = rng.uniform(0.05, max(0.06, 2 * half[2]))
    if face == 0:
        target[2] = 2 * half[2] + offset
    else:
        axis, sign = (face - 1) // 2, 1.0 if face % 2 else -1.0
        target[axis] = centre[axis] + sign * (half[axis] + offset)
    pose = PoseTarget(target, DOWN if rng.random() < 0.5 else None)
    model = with_zones(runtime, box, budget_s=BUDGET_S)
    outcome, report = plan_and_check(model, "pose", READY, {"target": pose})
    hard = [v for v in (*outcome.violations, *(report.violations if report else ())) if v.is_hard]
    if hard or outcome.trajectory is None:
        assert hard, "a refusal must say why"
        return []
    return oracle_for(model).violations(outcome.trajectory)


@settings(max_examples=3, **FUZZ)
@given(seed=SEEDS)
def test_every_accepted_plan_around_a_random_box_passes_the_dense_oracle(seed: int, runtime: RuntimeModel) -> None:
    assert findings_of_a_random_scene(seed, runtime) == []


@pytest.mark.slow
@settings(max_examples=40, **FUZZ)
@given(seed=SEEDS)
def test_every_accepted_plan_around_a_random_box_passes_the_dense_oracle_full_budget(seed: int, runtime: RuntimeModel) -> None:
    assert findings_of_a_random_scene(seed, runtime) == []
