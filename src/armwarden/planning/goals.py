"""Goal selection for pose targets: several IK solutions, the blocked ones dropped, the rest ranked.

One TCP pose has many joint solutions (elbow up/down, wrist flipped, a redundant arm's null
space). The nearest one may fold the wrist into the forearm or park the elbow in a keep-out zone
while another is free. So: solve IK from the current state, from home and from seeded random
configurations; drop every solution whose configuration fails the envelope's own static checks
(`Envelope.check_path` on that one configuration: joint limits, workspace, keep-out,
self-collision) or that lies beyond the joint travel cap from the start (for a position-only
target a blocked solution first gets its last joint turned, if the TCP lies on that joint's axis:
the hand turns out of the way without moving the TCP); drop every solution so close to a zone
that no plan can end there (the final check inflates a plan's last sample by the sweep allowance
of the interval before it: `Envelope.check_arrival`), and rank those clear even with the largest
such allowance before those clear only with the smallest; find each one's
approach (a configuration a few centimetres back from which the line in is clear); rank those
with an approach first, those inside the soft joint-limit margin last, then by weighted joint
travel from the start, the weight of
a joint being how far it can move the TCP per radian (`RobotModel.reach`), so that a solution
that swings the shoulder ranks behind one that turns the wrist.

The random seeds come from a generator seeded by the caller (derived from the request), so the
same request gives the same goals.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from itertools import chain

import numpy as np

from armwarden.robot.ik import IkSolver
from armwarden.safety.envelope import Envelope
from armwarden.safety.violations import Violation

#: two TCP positions closer than this are the same (far inside any IK tolerance) [m]
_SAME_POSITION_M = 1e-9
#: sweep allowances of a plan's last sample, as shares of `motion.sweep_resolution_m`
#: (`Envelope.check_arrival`): the largest any motion gets, then the smallest a longer one gets
ARRIVAL_SHARES = (0.5, 0.25)


@dataclass(frozen=True)
class GoalOptions:
    """How many goal configurations to look for, and how they are approached."""

    local_seeds: int = 8  # IK restarts from seeded random configurations near the start (±`local_spread_rad`)
    local_spread_rad: float = 0.6
    random_seeds: int = 8  # then from seeded random configurations anywhere within the limits
    extra_seeds: int = 16  # while no goal has a clear approach: more restarts within the travel cap (deadline permitting)
    max_goals: int = 4  # stop once this many distinct goals with a clear approach are found
    distinct_rad: float = 0.1  # solutions whose largest joint difference is below this are one
    retreat_m: float = 0.06  # how far the TCP backs off from a goal for its approach [m]
    retreat_max_rad: float = 0.5  # a retreat further than this from its goal (largest joint) is another branch


@dataclass(frozen=True)
class GoalSelection:
    """Collision-free goal configurations, best first, each with its approach configuration (None:
    none found), and what was wrong with the others."""

    goals: tuple[np.ndarray, ...]
    approaches: tuple[np.ndarray | None, ...]
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

    def approach(self, goal: np.ndarray) -> np.ndarray | None:
        """A configuration with the TCP `retreat_m` above the goal's, or back along its tool axis,
        same orientation, from which the straight joint line into the goal passes the envelope.

        A goal close to a zone can be entered from few directions only, and every plan's last
        sample is tested with the sweep allowance of its last step: a goal without a clear
        approach may be unreachable by any plan (ranked last), and one with an approach gives
        the search a wide target instead of a narrow one."""
        opts = self.options
        pose = self.envelope.robot.tcp_pose(goal)
        for offset in (np.array([0.0, 0.0, opts.retreat_m]), -opts.retreat_m * pose.rotation[:, 2]):
            result = self.ik.solve_from(pose.position + offset, pose.rotation, goal)
            if (result.success and np.max(np.abs(result.q - goal)) < opts.retreat_max_rad
                    and not any(v.is_hard for v in self.envelope.check_path(np.vstack([result.q, goal]), first_only=True))):
                return result.q
        return None

    def arrival(self, q: np.ndarray) -> tuple[int | None, Violation | None]:
        """How surely a checked plan can end at `q` (which passes the static checks): 0 when `q`
        is clear with the largest sweep allowance the final check gives a plan's last sample, 1
        when only with the smallest (whether a plan passes then depends on where its samples
        fall), None when not even with that, with the finding that blocks it: the final check
        would refuse every plan ending there, however it got there."""
        blocking = None
        for rank, share in enumerate(ARRIVAL_SHARES):
            hard = [v for v in self.envelope.check_arrival(q, share) if v.is_hard]
            if not hard:
                return rank, None
            blocking = hard[0]
        return None, blocking

    def _turned_clear(self, q: np.ndarray, start: np.ndarray, travel_cap: float,
                      ) -> tuple[np.ndarray, tuple[Violation, ...], int] | None:
        """For a position-only target whose solution `q` is blocked: `q` with the last joint
        turned to another angle (where the start has it first, then in quarter and eighth turns)
        that passes the envelope's static checks and can end a plan (`arrival`), with its
        findings and arrival rank; None if none does, or if turning the last joint moves the TCP
        (it then does not lie on that joint's axis)."""
        robot = self.envelope.robot
        position = robot.tcp_pose(q).position
        for angle in (start[-1], q[-1] + np.pi / 2, q[-1] - np.pi / 2, q[-1] + np.pi / 4, q[-1] - np.pi / 4):
            if not robot.lower[-1] <= angle <= robot.upper[-1] or abs(angle - start[-1]) > travel_cap:
                continue
            turned = q.copy()
            turned[-1] = angle
            if np.linalg.norm(robot.tcp_pose(turned).position - position) > _SAME_POSITION_M:
                return None
            findings = self.envelope.check_path(turned)
            if not any(v.is_hard for v in findings):
                rank, _ = self.arrival(turned)
                if rank is not None:
                    return turned, findings, rank
        return None

    def select(
        self, start: np.ndarray, position: np.ndarray, rotation: np.ndarray | None, seed: int, deadline: float,
        first: np.ndarray | None = None,
    ) -> GoalSelection:
        """Goal configurations for the TCP at `position` (and `rotation`, None: free), best first:
        those with a clear approach before those without, then those a plan surely can end at
        (`arrival` 0) before the others, those inside the soft joint-limit margin last, then by
        weighted joint travel from `start`.

        `first` is a solution already known (the straight-line planner's); `deadline` is on the
        `time.monotonic` clock and stops the search early (the goals found so far are kept).
        """
        opts = self.options
        rng = np.random.default_rng(seed)
        lower, upper = self.envelope.robot.lower, self.envelope.robot.upper
        spread = opts.local_spread_rad
        seeds = [start, self.home_rad]
        seeds += [np.clip(start + rng.uniform(-spread, spread, len(start)), lower, upper) for _ in range(opts.local_seeds)]
        seeds += [rng.uniform(lower, upper) for _ in range(opts.random_seeds)]
        travel_cap = self.envelope.limits.max_joint_step_rad
        found: list[np.ndarray] = []
        ranked: list[tuple[tuple[bool, int, bool, float], np.ndarray, np.ndarray | None]] = []
        blocked: Counter[str] = Counter()

        def approachable() -> int:
            return sum(approach is not None for _, _, approach in ranked)

        def extra() -> Iterator[np.ndarray]:
            # within the travel cap of the start: a solution far beyond it could never be a goal
            for _ in range(opts.extra_seeds):
                if approachable():
                    return
                yield np.clip(start + rng.uniform(-travel_cap, travel_cap, len(start)), lower, upper)

        candidates = chain([first] if first is not None else [], seeds, extra())
        for index, seed_q in enumerate(candidates):
            if approachable() >= opts.max_goals or (index > 0 and time.monotonic() > deadline):
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
            rank, near = (None, None) if hard else self.arrival(q)
            if rank is None:  # a position target's hand may turn about its own axis out of the way
                turned = self._turned_clear(q, start, travel_cap) if rotation is None else None
                if turned is None:
                    blocked[f"{hard[0].code.value} {hard[0].body}" if hard else _arrival_reason(near, self.envelope)] += 1
                    continue
                q, findings, rank = turned
                found.append(q)
            approach = self.approach(q)
            ranked.append(((approach is None, rank, bool(findings), self.weighted_travel(start, q)), q, approach))
        ranked.sort(key=lambda item: item[0])
        ranked = ranked[: opts.max_goals]
        return GoalSelection(tuple(q for _, q, _ in ranked), tuple(a for _, _, a in ranked), len(found), blocked)


#: the mark of a solution dropped because no plan can end there (see `_arrival_reason`)
ARRIVAL_MARK = "sweep allowance of a plan's last sample"


def _arrival_reason(violation: Violation | None, envelope: Envelope) -> str:
    """Why a solution clear in itself was dropped: what its padded bodies reach into once given the
    smallest sweep allowance of a plan's last sample."""
    allowance_mm = ARRIVAL_SHARES[-1] * envelope.limits.sweep_resolution_m * 1e3
    what = "unknown" if violation is None else f"{violation.code.value} {violation.body}"
    return f"{what} within the {allowance_mm:.1f} mm {ARRIVAL_MARK}"
