"""The joint-space search (OMPL RRTConnect) with the envelope's own checks as its validity test."""

from __future__ import annotations

import itertools
import time

import numpy as np

from armwarden.planning.detour import DetourSearch
from armwarden.preflight import RuntimeModel
from tests.helpers import READY
from tests.planning.scenarios import PILLAR, PILLAR_GOAL, PILLAR_START, base_turn, hemmed_block, with_zones


def test_every_leg_of_a_found_path_passes_the_envelope(runtime: RuntimeModel) -> None:
    model = with_zones(runtime, PILLAR)
    result = DetourSearch(model.envelope).find(PILLAR_START, [PILLAR_GOAL], seed=1, deadline=time.monotonic() + 2)
    assert result.path is not None
    np.testing.assert_array_equal(result.path[0], PILLAR_START)
    np.testing.assert_array_equal(result.path[-1], PILLAR_GOAL)
    for a, b in itertools.pairwise(result.path):
        assert not [v for v in model.envelope.check_path(np.vstack([a, b])) if v.is_hard]


def test_the_same_seed_gives_the_same_path(runtime: RuntimeModel) -> None:
    search = DetourSearch(with_zones(runtime, PILLAR).envelope)
    paths = [search.find(PILLAR_START, [PILLAR_GOAL], seed, time.monotonic() + 2).path for seed in (4, 4)]
    assert paths[0] is not None and paths[1] is not None
    np.testing.assert_array_equal(paths[0], paths[1])


def test_a_search_that_cannot_succeed_ends_at_its_deadline(runtime: RuntimeModel) -> None:
    search = DetourSearch(with_zones(runtime, hemmed_block(runtime)).envelope)
    budget = 0.2
    began = time.monotonic()
    result = search.find(base_turn(0.6), [READY], seed=1, deadline=began + budget)
    elapsed = time.monotonic() - began
    assert result.path is None and not result.stopped_early
    assert budget <= elapsed <= 1.2 * budget
    assert result.motion_checks > 0


def test_a_stop_request_ends_the_search(runtime: RuntimeModel) -> None:
    search = DetourSearch(with_zones(runtime, hemmed_block(runtime)).envelope)
    calls = iter(range(1000))
    began = time.monotonic()
    result = search.find(base_turn(0.6), [READY], seed=1, deadline=began + 5, should_stop=lambda: next(calls) > 20)
    assert result.path is None and result.stopped_early
    assert time.monotonic() - began < 1.0
