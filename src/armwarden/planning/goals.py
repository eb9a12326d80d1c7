"""Goal selection for pose targets: several IK solutions, the blocked ones dropped, the rest ranked.

One TCP pose has many joint solutions (elbow up/down, wrist flipped, a redundant arm's null
space). The nearest one may fold the wrist into the forearm or park the elbow in a keep-out zone
while another is free. So: solve IK from the current state, from home and from seeded random
configurations; drop every solution whose configuration fails the envelope's own static checks
(`Envelope.check_path` on that one configuration: joint limits, workspace, keep-out,
self-collision) or that lies beyond the joint travel cap from the start; rank the rest (those
inside the soft joint-limit margin last) by weighted joint travel from the start, the weight of
a joint being how far it can move the TCP per radian (`RobotModel.reach`), so that a solution
that swings the shoulder ranks behind one that turns the wrist.

The random seeds come from a generator seeded by the caller (derived from the request), so the
same request gives the same goals.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field
from itertools import chain

import numpy as np

from armwarden.robot.ik import IkSolver
from armwarden.safety.envelope import Envelope


@dataclass(frozen=True)
class GoalOptions:
    """How many goal configurations to look for."""

    local_seeds: int = 8  # IK restarts from seeded random configurations near the start (±`local_spread_rad`)
    local_spread_rad: float = 0.6
    random_seeds: int = 8  # then from seeded random configurations anywhere within the limits
    max_goals: int = 4  # stop once this many distinct collision-free goals are found
    distinct_rad: float = 0.1  # solutions whose largest joint difference is below this are one


@dataclass(frozen=True)
class GoalSelection:
    """Collision-free goal configurations, best first, and what was wrong with the others."""

    goals: tuple[np.ndarray, ...]
    solutions: int  # distinct IK solutions found
    blocked: Counter[str] = field(default_factory=Counter)  # "KEEP_OUT fr3_link5" → how many solutions

    def describe_blocked(self) -> str:
        """One line: why solutions were dropped (most common first)."""
        return ", ".join(f"{reason} ({count}×)" for reason, count in self.blocked.most_common(4)) or "none"


class GoalSelector:
    """Finds and ranks goal configurations for a TCP target (not thread safe: shares the model)."""

    def __init__(self, ik: IkSolver, envelope: Envelope, home_rad: np.ndarray, options: GoalOptions | None = None) -> None:
        self.ik = ik
        self.envelope = envelope
        self.home_rad = np.asarray(home_rad, dtype=float)
        self.options = options or GoalOptions()
        robot = envelope.robot
        self.travel_weights = robot.reach[:, -1]  # metres of TCP motion per radian of each joint (TCP is the last body)

    def weighted_travel(self, start: np.ndarray, goal: np.ndarray) -> float:
        return float(np.sum(self.travel_weights * np.abs(goal - start)))

    def select(
        self, start: np.ndarray, position: np.ndarray, rotation: np.ndarray | None, seed: int, deadline: float,
        first: np.ndarray | None = None,
    ) -> GoalSelection:
        """Goal configurations for the TCP at `position` (and `rotation`, None: free), best first.

        `first` is a solution already known (the straight-line planner's); `deadline` is on the
        `time.monotonic` clock and stops the search early (the goals found so far are kept).
        """
        opts = self.options
        rng = np.random.default_rng(seed)
        seeds = [start, self.home_rad]
        lower, upper = self.envelope.robot.lower, self.envelope.robot.upper
        spread = opts.local_spread_rad
        seeds += [np.clip(start + rng.uniform(-spread, spread, len(start)), lower, upper) for _ in range(opts.local_seeds)]
        seeds += [rng.uniform(lower, upper) for _ in range(opts.random_seeds)]
        travel_cap = self.envelope.limits.max_joint_step_rad
        found: list[np.ndarray] = []
        goals: list[np.ndarray] = []
        near_limit: set[int] = set()  # ids of goals within the soft joint-limit margin: ranked last
        blocked: Counter[str] = Counter()
        candidates = chain([first] if first is not None else [], seeds)
        for index, seed_q in enumerate(candidates):
            if len(goals) >= opts.max_goals or (index > 0 and time.monotonic() > deadline):
                break
            if first is not None and index == 0:
                q = np.asarray(first, dtype=float)
            else:
                result = self.ik.solve_from(position, rotation, np.asarray(seed_q, dtype=float))
                if not result.success:
                    continue
                q = result.q
            if any(np.max(np.abs(q - other)) < opts.distinct_rad for other in found):
                continue
            found.append(q)
            if np.max(np.abs(q - start)) > travel_cap:  # every path there travels at least this far
                blocked["STEP_TOO_LARGE"] += 1
                continue
            findings = self.envelope.check_path(q)
            hard = [v for v in findings if v.is_hard]
            if hard:
                blocked[f"{hard[0].code.value} {hard[0].body}"] += 1
                continue
            if findings:
                near_limit.add(id(q))
            goals.append(q)
        goals.sort(key=lambda q: (id(q) in near_limit, self.weighted_travel(start, q)))
        return GoalSelection(tuple(goals), len(found), blocked)
