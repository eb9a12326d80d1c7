"""Goal selection for pose targets: several IK solutions, the blocked ones dropped, the rest ranked.

One TCP pose has many joint solutions (elbow up/down, wrist flipped, a redundant arm's null
space). The nearest one may fold the wrist into the forearm or park the elbow in a keep-out zone
while another is free. So: solve IK from the current state, from home and from seeded random
configurations; drop every solution whose configuration fails the envelope's own static checks
(`Envelope.check_path` on that one configuration: joint limits, workspace, keep-out,
self-collision) or that lies beyond the joint travel cap from the start (for a position-only
target, or one whose yaw about the tool axis is free, a blocked solution first gets its last
joint turned, if the TCP lies on that joint's axis: the hand turns out of the way without moving
the TCP or tilting the tool axis); a free-yaw target is solved, from each seed, at the turn about
the tool axis nearest the seed's own (`PoseTarget.rotation_near`), so the seeds' spread covers
the yaws as it covers the arm's branches; rank solutions clear even with the largest
sweep allowance the final check can give a plan's last sample before those only clear with less
(`GoalSelector.arrival`: a goal a few millimetres from a zone makes many plans into it fail the
final check, however they get there); find each one's
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

from armwarden.planning.planners import yaw_towards
from armwarden.robot.ik import IkSolver
from armwarden.safety.envelope import Envelope
from armwarden.safety.violations import Violation

#: two TCP positions closer than this are the same (far inside any IK tolerance) [m]
_SAME_POSITION_M = 1e-9
#: two tool axes (unit vectors) closer than this are the same [1]
_SAME_AXIS = 1e-9
#: body growths, as shares of `motion.sweep_resolution_m`, a goal is tried with (`Envelope.check_arrival`):
#: the largest sweep allowance the final check can give a plan's last sample, then half of it
ARRIVAL_SHARES = (0.5, 0.25)
#: the arrival rank of a goal clear with none of `ARRIVAL_SHARES` (see `GoalSelector.arrival`)
CLOSE_TO_A_ZONE = len(ARRIVAL_SHARES)


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
    arrivals: tuple[int, ...] = ()  # each goal's `GoalSelector.arrival` rank

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

    def arrival(self, q: np.ndarray) -> int:
        """How likely the final check is to let a plan end at `q` (which passes the static checks),
        as far as zones and the workspace box decide: 0 when `q` is clear of them with its bodies
        grown by half of `motion.sweep_resolution_m` — no body's allowance at a plan's last sample
        is larger, so no zone fails a plan there at its last sample; 1 when clear only with a
        quarter; `CLOSE_TO_A_ZONE` when not even then. The allowance a plan's last sample gets
        depends on the motion into it (a body that barely moves gets almost none), so a goal
        ranked low can still end some plans: goals are ranked by it, never dropped."""
        for rank, share in enumerate(ARRIVAL_SHARES):
            if not any(v.is_hard for v in self.envelope.check_arrival(q, share)):
                return rank
        return CLOSE_TO_A_ZONE

    def _turned_clear(self, q: np.ndarray, start: np.ndarray, travel_cap: float, below: int = CLOSE_TO_A_ZONE + 1,
                      keep_axis: bool = False) -> tuple[np.ndarray, tuple[Violation, ...], int] | None:
        """For a position-only or free-yaw target whose solution `q` is blocked, or ranks `below`
        (see `arrival`) or worse: `q` with the last joint turned to another angle (where the start
        has it first, then in quarter and eighth turns) that passes the envelope's static checks
        and ranks better than `below`, with its findings and rank; None if none does, or if turning
        the last joint moves the TCP (it then does not lie on that joint's axis) or, with
        `keep_axis` (a free yaw), tilts the tool axis (it is then not that joint's axis)."""
        robot = self.envelope.robot
        pose = robot.tcp_pose(q)
        for angle in (start[-1], q[-1] + np.pi / 2, q[-1] - np.pi / 2, q[-1] + np.pi / 4, q[-1] - np.pi / 4):
            if not robot.lower[-1] <= angle <= robot.upper[-1] or abs(angle - start[-1]) > travel_cap:
                continue
            turned = q.copy()
            turned[-1] = angle
            turned_pose = robot.tcp_pose(turned)
            if np.linalg.norm(turned_pose.position - pose.position) > _SAME_POSITION_M or (
                    keep_axis and np.linalg.norm(turned_pose.rotation[:, 2] - pose.rotation[:, 2]) > _SAME_AXIS):
                return None
            findings = self.envelope.check_path(turned, first_only=True)
            if not any(v.is_hard for v in findings) and (rank := self.arrival(turned)) < below:
                return turned, findings, rank
        return None

    def select(
        self, start: np.ndarray, position: np.ndarray, rotation: np.ndarray | None, seed: int, deadline: float,
        first: np.ndarray | None = None, free_yaw: bool = False,
    ) -> GoalSelection:
        """Goal configurations for the TCP at `position` (and `rotation`, None: free; with
        `free_yaw`, any turn of it about the tool axis), best first:
        those with a clear approach before those without, then by `arrival` rank, those inside
        the soft joint-limit margin last, then by weighted joint travel from `start`. Goal
        seeking continues until `max_goals` goals with an approach and an arrival rank better
        than `CLOSE_TO_A_ZONE` are found (or the seeds or the deadline run out).

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
        turnable = rotation is None or free_yaw
        found: list[np.ndarray] = []
        ranked: list[tuple[tuple[bool, int, bool, float], np.ndarray, np.ndarray | None]] = []
        blocked: Counter[str] = Counter()

        def approachable() -> int:
            return sum(approach is not None and key[1] < CLOSE_TO_A_ZONE for key, _, approach in ranked)

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
                seed_q = np.asarray(seed_q, dtype=float)
                wanted = rotation if rotation is None or not free_yaw else yaw_towards(
                    rotation, self.envelope.robot.tcp_pose(seed_q).rotation)
                result = self.ik.solve_from(position, wanted, seed_q)
                if not result.success:
                    continue
                q = result.q
            if any(np.max(np.abs(q - other)) < opts.distinct_rad for other in found):
                continue
            found.append(q)
            if np.max(np.abs(q - start)) > travel_cap:  # every path there travels at least this far
                blocked["STEP_TOO_LARGE"] += 1
                continue
            findings = self.envelope.check_path(q, first_only=True)
            hard = [v for v in findings if v.is_hard]
            if hard:  # a position or free-yaw target's hand may turn about its own axis out of the way
                turned = self._turned_clear(q, start, travel_cap, keep_axis=free_yaw) if turnable else None
                if turned is None:
                    blocked[f"{hard[0].code.value} {hard[0].body}"] += 1
                    continue
                q, findings, rank = turned
                found.append(q)
                approach = self.approach(q)
            else:
                rank, approach = self.arrival(q), self.approach(q)
                better = self._turned_clear(q, start, travel_cap, below=rank, keep_axis=free_yaw) if turnable and rank else None
                # the hand turned away from a zone it came close to, unless that loses the way in
                if better is not None and ((turned_approach := self.approach(better[0])) is not None or approach is None):
                    q, findings, rank = better
                    approach = turned_approach
                    found.append(q)
            ranked.append(((approach is None, rank, bool(findings), self.weighted_travel(start, q)), q, approach))
        ranked.sort(key=lambda item: item[0])
        ranked = ranked[: opts.max_goals]
        return GoalSelection(tuple(q for _, q, _ in ranked), tuple(a for _, _, a in ranked), len(found), blocked,
                             tuple(key[1] for key, _, _ in ranked))
