"""Planning around what blocked the straight line: a straight TCP line, other goal configurations,
then a joint-space search within the per-plan caps.

The straight-line planners (`planning.planners`) stay the first and, when the envelope accepts
their plan, the only word: an unobstructed target costs exactly what it cost before and gives the
identical plan. Only when the envelope rejects the straight line for reasons a different path can
avoid (a link in a keep-out zone or outside the workspace, a self-collision, and for pose targets
a goal configuration that travels too far) does `DetourPlanner.plan` run, within the policy's
`motion.planning_time_s`:

0. a target further from the TCP in a straight line than the TCP path cap
   (`motion.max_cartesian_step_m`) is refused at once: no path is shorter than that line;
1. pose targets: the straight TCP line to the target (`plan_cartesian_path`), the shortest
   path there is;
2. pose targets: other IK solutions (`planning.goals`; any turn about the tool axis where the
   request allows a free yaw), collision-free ones only, best first; the first whose straight
   joint line (or line to its approach, directly or through home) is clear and within the caps
   is taken as it is;
3. otherwise a bidirectional search from the start to any of those goals (`planning.detour`)
   that keeps every partial path within the TCP path and joint travel caps while it searches,
   whose validity test is the envelope's own; to a goal close to an obstacle it searches to the
   goal's approach configuration a few centimetres back (`GoalSelector.approach`: TCP above, or
   behind along the tool axis) and goes straight in from there, the leg counted against the caps,
   because a goal hemmed in by a zone is a narrow passage a sampler rarely threads;
4. the path is timed with the existing parameterisation, coming to rest at each corner.

It returns a proposal; the caller runs the unchanged `Envelope.check` on it before any plan id
exists. When nothing is found in time the straight-line plan is returned as it was (still
rejected by the envelope) with a `NO_DETOUR` violation naming what blocked the straight line and
why no detour was found.
"""

from __future__ import annotations

import hashlib
import itertools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from armwarden.core.trajectory import JointTrajectory
from armwarden.planning.detour import DetourSearch, SearchResult
from armwarden.planning.goals import CLOSE_TO_A_ZONE, GoalSelection, GoalSelector
from armwarden.planning.planners import Planner, PlanOutcome, PoseTarget
from armwarden.planning.timing import TimingError, time_parameterize
from armwarden.safety.envelope import Envelope
from armwarden.safety.limits import EnvelopeReport
from armwarden.safety.violations import Code, Violation

#: what a different path can avoid; anything else hard (a goal past a joint limit, malformed input) it cannot
_GEOMETRIC = frozenset({Code.KEEP_OUT, Code.WORKSPACE, Code.SELF_COLLISION})
#: a pose target may also be reached by a goal configuration that travels less
_POSE_EXTRA = frozenset({Code.STEP_TOO_LARGE, Code.CARTESIAN_STEP_TOO_LARGE})
#: share of the budget goal selection may use before the search starts
_GOAL_SHARE = 0.35
#: part of the budget kept for timing and the final check after the search
_RESERVE_SHARE = 0.05
#: searches per plan call (each after the previous path failed the whole-plan check), budget permitting
_MAX_SEARCHES = 4
#: what may help when every goal lies within a few millimetres of a zone (`GoalSelector.arrival`)
_CLOSE_TO_A_ZONE = ("every goal configuration found lies within a few millimetres of a zone or the workspace edge, "
                    "and the final check gives a plan's last sample a sweep allowance of up to half of "
                    "motion.sweep_resolution_m, so most plans ending there fail it: moving the target a few "
                    "millimetres further away, or a finer motion.sweep_resolution_m (slower planning), may help")

Kind = Literal["joints", "pose"]


class DetourPlanner:
    """Proposes a path around what blocked the straight line (on the planning thread; not thread safe)."""

    def __init__(self, planner: Planner, envelope: Envelope, budget_s: float,
                 goals: GoalSelector | None = None, search: DetourSearch | None = None) -> None:
        self.planner = planner
        self.envelope = envelope
        self.budget_s = float(budget_s)
        self.goals = goals or GoalSelector(planner.ik, envelope, planner.settings.home_rad)
        self.search = search or DetourSearch(envelope, ik=planner.ik)

    def worth_trying(self, kind: str, report: EnvelopeReport) -> bool:
        """Whether the envelope's verdict on the straight line is one a different path could change."""
        if kind not in ("joints", "pose"):
            return False  # a Cartesian path is a straight TCP line by definition
        searchable = _GEOMETRIC | (_POSE_EXTRA if kind == "pose" else frozenset())
        hard = report.hard
        return bool(hard) and all(v.code in searchable for v in hard)

    def plan(
        self, kind: Kind, start: np.ndarray, straight: PlanOutcome, report: EnvelopeReport,
        target: PoseTarget | None = None, should_stop: Callable[[], bool] = lambda: False,
    ) -> PlanOutcome:
        """A detour proposal, or `straight` with a `NO_DETOUR` violation explaining why there is none."""
        began = time.monotonic()
        deadline = began + self.budget_s * (1.0 - _RESERVE_SHARE)
        assert straight.trajectory is not None
        start = np.asarray(start, dtype=float)
        first_goal = np.asarray(straight.trajectory.goal, dtype=float)
        seed = request_seed(kind, start, first_goal if kind == "joints" else target)
        if not self.search.configuration_is_clear(start):
            return self._refuse(straight, report, "the start configuration itself violates the envelope")
        too_far = self._beyond_the_tcp_cap(kind, start, first_goal, target)
        if too_far is not None:
            return self._refuse(straight, report, too_far)

        rejected: list[str] = []
        context = _Context(straight, report, began, rejected)
        if kind == "pose" and target is not None:
            # first the straight TCP line: it needs no goal selection, and no path is shorter
            proposal = self._tcp_line(context, start, target)
            if proposal is not None:
                return proposal
            selection = self.goals.select(start, target.position, target.rotation, seed,
                                          began + self.budget_s * _GOAL_SHARE, first=first_goal, free_yaw=target.free_yaw)
            if not selection.goals:
                return self._refuse(straight, report, _no_goal_reason(selection))
            goals: Sequence[np.ndarray] = selection.goals
            retreats: Sequence[np.ndarray | None] = selection.approaches
            arrivals: Sequence[int] = selection.arrivals
        else:
            if not self.search.configuration_is_clear(first_goal):
                return self._refuse(straight, report, "the goal configuration itself violates the envelope")
            goals, retreats = (first_goal,), (self.goals.approach(first_goal),)
            arrivals = (self.goals.arrival(first_goal),)

        # cheap candidates first: a clear straight line to another goal configuration; then, since
        # a goal close to an obstacle can only be entered from a few directions, lines to its
        # approach configuration a few centimetres back (directly, or through home) and straight in
        hint = f"; {_CLOSE_TO_A_ZONE}" if all(rank == CLOSE_TO_A_ZONE for rank in arrivals) else ""
        home = self.planner.settings.home_rad
        for goal, retreat in zip(goals, retreats, strict=True):
            near = [goal] if retreat is None else [retreat, goal]
            candidates = [[start, goal], [start, *near], [start, home, *near]]
            for path in candidates[:1] + candidates[2 - (retreat is not None):]:  # no line tried twice
                if self._clear(path):
                    proposal = self._accepted(context, np.vstack(path), searched=False)
                    if proposal is not None:
                        return proposal
        # then the search, within the caps, to the goals and to their retreat points where there
        # are some (the leg on to the goal counted against the caps: a way in from a few
        # centimetres back is a wide target, a goal itself the shorter one); a path the whole-plan
        # check refuses (its samples fall differently from the search's) is followed by another
        # search while the budget lasts, with other random numbers
        entries: list[np.ndarray] = []
        tails: list[np.ndarray | None] = []
        for goal, retreat in zip(goals, retreats, strict=True):
            entries += [goal] if retreat is None else [retreat, goal]
            tails += [None] if retreat is None else [goal, None]
        for attempt in range(_MAX_SEARCHES):
            result = self.search.find(start, entries, seed, deadline, should_stop, attempt=attempt, tails=tails)
            if result.path is None or result.goal_index is None:
                why = _search_failure(result, len(goals), self.budget_s, rejected)
                return self._refuse(straight, report, why if result.stopped_early else why + hint)
            path = result.path
            tail = tails[result.goal_index]
            if tail is not None:
                path = np.vstack([path, tail])
            proposal = self._accepted(context, path, searched=True)
            if proposal is not None:
                return proposal
            rejected[-1] = "search: " + rejected[-1]
        return self._refuse(straight, report, "every path found fails the envelope as a whole (" + rejected[-1] + ")" + hint)

    # ------------------------------------------------------------------ helpers
    def _clear(self, path: Sequence[np.ndarray]) -> bool:
        """Within the per-plan caps (TCP path and joint travel, as the search measures them: no
        time spent checking a line the whole-plan check refuses for its length) and every leg
        clear (the envelope's untimed check)."""
        return self.search.within_caps(self.search.path_cost(np.vstack(path))) and all(
            self.search.segment_is_clear(a, b) for a, b in itertools.pairwise(path))

    def _beyond_the_tcp_cap(self, kind: Kind, start: np.ndarray, goal: np.ndarray, target: PoseTarget | None) -> str | None:
        """Why no path can be short enough, if the straight TCP distance is already over the TCP
        path cap (no path is shorter than the straight line): refused at once, without a search."""
        robot, cap = self.planner.robot, self.envelope.limits.max_cartesian_step_m
        to = target.position if kind == "pose" and target is not None else robot.tcp_pose(goal).position
        distance = float(np.linalg.norm(np.asarray(to, dtype=float) - robot.tcp_pose(start).position))
        if distance <= cap:
            return None
        return (f"the target is {distance:.3f} m from the TCP in a straight line, more than the TCP path of one plan "
                f"may be (motion.max_cartesian_step_m {cap:.3f} m): no path is shorter; plan it in two steps")

    def _accepted(self, context: _Context, path: np.ndarray, searched: bool) -> PlanOutcome | None:
        """The path timed, if the envelope accepts the whole timed plan (its travel and TCP-length
        caps apply to the whole detour, and its samples fall differently than the search's); else
        None, with the reason appended to `context.rejected`."""
        straight = context.straight
        settings = self.planner.settings
        vel, acc = straight.velocity_scaling, straight.acceleration_scaling
        try:
            trajectory = time_parameterize(
                self.planner.robot.joint_names, path, settings.max_velocity_rad_s * vel,
                settings.max_acceleration_rad_s2 * acc, stops=tuple(range(1, len(path) - 1)),
            )
        except TimingError as exc:
            context.rejected.append(f"the path could not be timed: {exc}")
            return None
        how = (f"a joint-space search within the per-plan caps found a way through {len(path) - 2} intermediate "
               "configuration(s)" if searched else f"a clear line to a collision-free goal configuration through "
               f"{len(path) - 2} intermediate configuration(s)")
        return self._checked(context, trajectory, how)

    def _tcp_line(self, context: _Context, start: np.ndarray, target: PoseTarget) -> PlanOutcome | None:
        """The straight TCP line to a pose target (`plan_cartesian_path`: the shortest TCP path
        there is, so the one most likely within the TCP cap), the orientation turned on the way
        to the target's (kept, for a position-only target; the turn nearest the start's, for a
        free yaw), if the envelope accepts it; else None, the reason in `context.rejected`."""
        straight = context.straight
        rotation = target.rotation_near(self.planner.robot.tcp_pose(start).rotation)
        line = self.planner.plan_cartesian_path(start, [PoseTarget(target.position, rotation)],
                                                straight.velocity_scaling, straight.acceleration_scaling)
        if line.trajectory is None:
            context.rejected.append(f"straight TCP line: {line.violations[0].detail}" if line.violations
                                    else "straight TCP line: not planned")
            return None
        return self._checked(context, line.trajectory, "a straight TCP line to the target is clear")

    def _checked(self, context: _Context, trajectory: JointTrajectory, how: str) -> PlanOutcome | None:
        """The proposal, if the envelope accepts the whole timed plan; else None, with the reason
        appended to `context.rejected`."""
        straight = context.straight
        checked = self.envelope.check(trajectory)
        if checked.hard:
            context.rejected.append(f"{checked.hard[0].code.value}: {checked.hard[0].detail}")
            return None
        straight_tcp = context.report.tcp_path_length_m
        elapsed = time.monotonic() - context.began
        ratio = f", {checked.tcp_path_length_m / straight_tcp:.2f}× the" if straight_tcp > 0 else "; the"
        note = (f"detour planned: the straight line was blocked; {how}; TCP path {checked.tcp_path_length_m:.3f} m"
                f"{ratio} straight line's {straight_tcp:.3f} m; planned in {elapsed * 1e3:.0f} ms")
        return replace(straight, trajectory=trajectory, violations=(), notes=(*straight.notes, note))

    def _refuse(self, straight: PlanOutcome, report: EnvelopeReport, why: str) -> PlanOutcome:
        blocked = "; ".join(v.detail for v in report.hard[:3])
        violation = Violation(Code.NO_DETOUR, f"the straight line is blocked ({blocked}); no safe detour: {why}")
        return replace(straight, violations=(*straight.violations, violation))


@dataclass(frozen=True)
class _Context:
    """One `plan` call's facts the candidates are judged and described with."""

    straight: PlanOutcome
    report: EnvelopeReport  # the envelope's verdict on the straight line
    began: float
    rejected: list[str]  # why candidates failed the whole-plan check, in order


def request_seed(kind: str, start: np.ndarray, goal: np.ndarray | PoseTarget | None) -> int:
    """A 63-bit seed from the request: the same request and start state always search alike."""
    hasher = hashlib.sha256(kind.encode())
    hasher.update(np.ascontiguousarray(start, dtype=float).tobytes())
    if isinstance(goal, PoseTarget):
        hasher.update(np.ascontiguousarray(goal.position, dtype=float).tobytes())
        if goal.rotation is not None:
            hasher.update(np.ascontiguousarray(goal.rotation, dtype=float).tobytes())
            if goal.free_yaw:  # only then: the seeds of exact-rotation requests stay what they were
                hasher.update(b"free_yaw")
    elif goal is not None:
        hasher.update(np.ascontiguousarray(goal, dtype=float).tobytes())
    return int.from_bytes(hasher.digest()[:8], "big") >> 1


def _no_goal_reason(selection: GoalSelection) -> str:
    return (f"none of the {selection.solutions} IK solution(s) found is a collision-free goal configuration "
            f"(blocked: {selection.describe_blocked()})")


def _search_failure(result: SearchResult, n_goals: int, budget_s: float, rejected: list[str]) -> str:
    if result.stopped_early:
        return "the search was stopped (an e-stop latched)"
    also = f"; shorter candidates failed the whole-plan check ({rejected[0]})" if rejected else ""
    if result.goals_within_caps == 0:
        return (f"every one of the {n_goals} collision-free goal configuration(s) lies further than one plan may go: "
                "its straight TCP distance or straight joint travel is over motion.max_cartesian_step_m or "
                f"motion.max_joint_step_rad, and no path is shorter{also}")
    return (f"no path within the per-plan caps to any of {result.goals_within_caps} collision-free goal configuration(s) "
            f"found within the planning budget of {budget_s:.2f} s (motion.planning_time_s; {result.state_checks} "
            f"configurations and {result.motion_checks} motions checked){also}")
