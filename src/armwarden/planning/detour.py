"""The joint-space search around obstacles: OMPL's RRTConnect, validated by the envelope's own checks.

Why OMPL: it is the maintained reference library of sampling-based planners (MoveIt's default
pipeline runs its RRTConnect), its official Python bindings (`ompl` on PyPI) let a Python
object be the state validity checker *and* the motion validator, and it brings path
simplification. RRTConnect (two trees grown towards each other, greedy connection) finds a first
path fastest in the narrow-but-not-maze problems a table-top arm meets; we want a safe path
quickly, not an optimal one.

**No second collision model.** A state is valid when `Envelope.check_path` finds no hard
violation at that configuration, and a motion (the straight joint segment between two states,
which is exactly how the executed trajectory interpolates) when it finds none along the
segment: the same joint limits, the same padded capsules, zones and self-collision pairs, and
the same sweep bound between samples as the final check. OMPL's own discrete motion checking
(fixed-resolution state sampling) is replaced, never used. Whatever this module returns is a
proposal: the caller times it and the unchanged `Envelope.check` decides.

**Only where a plan may go.** The search space is the joint limits (inside the soft margin)
intersected with the per-plan travel cap around the start: a path leaving that box travels too
far in some joint and would fail the final check whatever else it did.

**Reproducible.** OMPL draws every random number from generators seeded from one process-wide
seed; it is set from the request-derived seed right before the search objects are built, and
only fixed-step simplification is used (no time-bounded polishing), so the same request, start
state and policy give the same path whenever the search ends within its budget. The planning
thread is the only user of OMPL in the daemon (one plan at a time), so the process-wide seed
is not shared.
"""

from __future__ import annotations

import functools
import itertools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from armwarden.safety.envelope import Envelope

if TYPE_CHECKING:
    from types import ModuleType

    from ompl.geometric import PathGeometric

#: extra travel of one joint over its straight start-to-goal travel that `_straighten_joints` removes [rad]
_WANDER_RAD = 0.05
#: how much of a wandering joint's deviation from its straight line `_straighten_joints` tries to keep
_WANDER_KEPT = (0.0, 0.5, 0.25)



@dataclass(frozen=True)
class SearchOptions:
    """Settings of the RRTConnect search, with units."""

    range_rad: float = 1.0  # longest tree edge [rad, Euclidean in joint space]
    planner: str = "RRTConnect"  # the OMPL geometric planner's class name
    simplify_steps: int = 20  # vertex-reduction attempts after a path is found (fixed: reproducible)


@dataclass(frozen=True)
class SearchResult:
    """A joint polyline from the start to one of the goals (None: none found), and the effort."""

    path: np.ndarray | None
    goal_index: int | None  # which goal it reaches
    state_checks: int
    motion_checks: int
    elapsed_s: float
    stopped_early: bool  # the caller asked to stop (an e-stop), not the budget


@functools.cache
def _ompl() -> tuple[ModuleType, ModuleType, type]:
    """OMPL's base and geometric modules and our motion validator class, imported on the first
    search only: ompl 2.0.1's bindings report leaked default-argument objects on stderr when the
    interpreter exits, which a daemon that never searched should not print."""
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    # INFO lines ("created N states") go to stdout, which carries MCP under stdio: warnings and
    # errors only (OMPL writes those to stderr)
    ou.setLogLevel(ou.LOG_WARN)

    class EnvelopeMotions(ob.MotionValidator):
        """OMPL motion validator: a straight joint segment is valid when the envelope finds nothing hard."""

        def __init__(self, si: Any, search: DetourSearch) -> None:
            super().__init__(si)
            self._search = search

        def checkMotion(self, s1: Any, s2: Any, *last_valid: Any) -> bool:
            search = self._search
            search.motion_checks += 1
            return search.segment_is_clear(search.to_array(s1), search.to_array(s2))

    return ob, og, EnvelopeMotions


class DetourSearch:
    """Plans a joint path from a start to any of several goals around what the envelope forbids.

    Not thread safe (the envelope's Pinocchio data, OMPL's process-wide seed): the daemon runs it
    on its one planning thread.
    """

    def __init__(self, envelope: Envelope, options: SearchOptions | None = None) -> None:
        self.envelope = envelope
        self.options = options or SearchOptions()
        robot = envelope.robot
        self._n = robot.nq
        margin = envelope.limits.joint_limit_margin_rad
        # search inside the soft margin, so that a detour never adds a near-limit warning of its own
        self._lower = robot.lower + margin
        self._upper = robot.upper - margin
        self.state_checks = 0
        self.motion_checks = 0

    # ------------------------------------------------------------------ validity (the envelope's checks)
    def to_array(self, state) -> np.ndarray:
        return np.fromiter((state[i] for i in range(self._n)), dtype=float, count=self._n)

    def configuration_is_clear(self, q: np.ndarray) -> bool:
        return not any(v.is_hard for v in self.envelope.check_path(q, first_only=True))

    def segment_is_clear(self, q0: np.ndarray, q1: np.ndarray) -> bool:
        return not any(v.is_hard for v in self.envelope.check_path(np.vstack([q0, q1]), first_only=True))

    def _state_is_valid(self, state) -> bool:
        self.state_checks += 1
        return self.configuration_is_clear(self.to_array(state))

    # ------------------------------------------------------------------ search
    def find(
        self, start: np.ndarray, goals: Sequence[np.ndarray], seed: int, deadline: float,
        should_stop: Callable[[], bool] = lambda: False, reseed: bool = True,
    ) -> SearchResult:
        """A valid joint path from `start` to one of `goals`, or none before `deadline`
        (`time.monotonic`). `reseed` False continues OMPL's generators from the previous search
        (a second search for the same request, which must differ from the first)."""
        began = time.monotonic()
        self.state_checks = self.motion_checks = 0
        if not goals:
            return SearchResult(None, None, 0, 0, 0.0, False)
        ob, og, envelope_motions = _ompl()
        if reseed:
            _seed_ompl(seed)
        n = self._n
        space = ob.RealVectorStateSpace(n)
        bounds = ob.RealVectorBounds(n)
        every = np.vstack([start, *goals])
        # no joint further from the start than the per-plan travel cap: a path that goes there
        # travels too far and fails the final check anyway, so the search need not look there
        cap = self.envelope.limits.max_joint_step_rad
        lower = np.maximum(self._lower, start - cap)
        upper = np.minimum(self._upper, start + cap)
        lower = np.minimum(lower, every.min(axis=0))  # the start or a goal may sit inside the margin
        upper = np.maximum(upper, every.max(axis=0))
        for i in range(n):
            bounds.setLow(i, float(lower[i]))
            bounds.setHigh(i, float(upper[i]))
        space.setBounds(bounds)
        si = ob.SpaceInformation(space)
        si.setStateValidityChecker(self._state_is_valid)
        validator = envelope_motions(si, self)
        si.setMotionValidator(validator)
        si.setup()
        problem = ob.ProblemDefinition(si)
        problem.addStartState(self._state(si, start))
        goal_states = ob.GoalStates(si)
        for goal in goals:
            goal_states.addState(self._state(si, goal))
        problem.setGoal(goal_states)
        planner = getattr(og, self.options.planner)(si)
        if hasattr(planner, "setRange"):
            planner.setRange(self.options.range_rad)
        planner.setProblemDefinition(problem)
        planner.setup()
        stopped = {"early": False}

        def terminate() -> bool:
            if should_stop():
                stopped["early"] = True
                return True
            return time.monotonic() > deadline

        planner.solve(ob.PlannerTerminationCondition(terminate))
        if not problem.hasExactSolution():
            return self._result(None, None, began, stopped["early"])
        path = cast("PathGeometric", problem.getSolutionPath())  # a geometric planner's solution
        og.PathSimplifier(si).reduceVertices(path, self.options.simplify_steps)
        positions = np.vstack([self.to_array(path.getState(i)) for i in range(path.getStateCount())])
        positions[0] = start  # exactly, not through OMPL's copy
        end = int(np.argmin([np.max(np.abs(positions[-1] - g)) for g in goals]))
        positions[-1] = goals[end]
        return self._result(self._straighten_joints(self._shortcut(positions)), end, began, False)

    def _shortcut(self, positions: np.ndarray) -> np.ndarray:
        """Greedy, deterministic: from each kept vertex jump to the farthest later one in clear sight."""
        kept = [0]
        while kept[-1] < len(positions) - 1:
            i = kept[-1]
            j = len(positions) - 1
            while j > i + 1 and not self.segment_is_clear(positions[i], positions[j]):
                j -= 1
            kept.append(j)
        return positions[kept]

    def _straighten_joints(self, positions: np.ndarray) -> np.ndarray:
        """Per joint, deterministic: a joint that wanders (the random tree turns the wrist back and
        forth while it searches for the elbow's way) is put back on its straight line from start to
        goal along the path, wherever the path stays clear; where the straight line is not clear,
        halfway and three quarters of the way back to it are tried. Joint travel counts against
        the policy's per-plan cap, so a wandering joint can get a good path rejected."""
        if len(positions) < 3:
            return positions
        steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
        fraction = np.concatenate([[0.0], np.cumsum(steps)]) / max(float(np.sum(steps)), 1e-12)
        cap = self.envelope.limits.max_joint_step_rad
        for j in range(positions.shape[1]):
            straight = positions[0, j] + fraction * (positions[-1, j] - positions[0, j])
            travel = float(np.sum(np.abs(np.diff(positions[:, j]))))
            if travel - abs(positions[-1, j] - positions[0, j]) < _WANDER_RAD and travel <= cap:
                continue  # a little wander is harmless, unless it takes the joint past the travel cap
            for kept in _WANDER_KEPT:  # the share of the wander left: none first
                candidate = positions.copy()
                candidate[:, j] = straight + kept * (positions[:, j] - straight)
                if all(self.segment_is_clear(a, b) for a, b in itertools.pairwise(candidate)):
                    positions = candidate
                    break
        return positions

    def _state(self, si, q: np.ndarray):
        state = si.allocState()
        for i, value in enumerate(q):
            state[i] = float(value)
        return state

    def _result(self, path: np.ndarray | None, goal_index: int | None, began: float, early: bool) -> SearchResult:
        return SearchResult(path, goal_index, self.state_checks, self.motion_checks, time.monotonic() - began, early)


def _seed_ompl(seed: int) -> None:
    """Seed OMPL's generators for this search (quietly: OMPL logs an error when it is re-seeded
    after its first use, although the new seed takes effect, as the determinism tests show)."""
    from ompl import util as ou

    ou.noOutputHandler()
    try:
        ou.RNG.setSeed(seed % (2**31 - 1) + 1)  # OMPL ignores a zero seed
    finally:
        ou.restorePreviousOutputHandler()
