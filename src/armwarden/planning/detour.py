"""The joint-space search around obstacles: a bidirectional RRT that searches only within the
per-plan caps, validated by the envelope's own checks.

**Within the caps while it searches.** A plan is refused when any joint travels more than
`motion.max_joint_step_rad` in all (summed along the path) or the TCP's path is longer than
`motion.max_cartesian_step_m`. A search that finds a way first and measures it afterwards mostly
finds ways that are too long (with a bin-sized obstacle and a 0.5 m cap, every path OMPL's
RRTConnect found was). So every tree node carries what its path from the tree's root has already
used — TCP path length (measured at samples of the joint segment, `tcp_spacing_m` apart at most)
and travel per joint — and a node is kept only if that plus the least the rest could use (the
straight TCP distance, the straight per-joint distance to the other end, plus the approach leg
after a goal) stays within the caps. Samples are drawn only where a path through them can stay
within the caps: per joint, inside the interval whose detour through it travels no more than
the cap (a box); in TCP space, inside the ellipsoid whose foci are the start's and the goal's
TCP and whose sum of focal distances is the TCP cap (checked with batched forward kinematics).
Two trees (from the start, and from every goal at once) grow towards each sample and towards
each other (RRT-Connect's greedy connection); a connection counts only when the two halves
together stay within the caps.

Why our own search, not OMPL's: OMPL's planners know one cost (an optimisation objective) and
no per-joint budgets; carrying eight running budgets through RRTConnect's trees from Python
would mean guessing tree membership inside a motion validator, and its informed planners would
call back into Python for every cost. The tree here is a few hundred lines of NumPy whose every
number is ours, and its random numbers come from a NumPy generator seeded from the request
(`around.request_seed`) and the attempt number: no process-wide seed, the same request, start
state and policy give the same path.

**No second collision model.** A state is valid when `Envelope.check_path` finds no hard
violation at that configuration, and a motion (the straight joint segment between two states,
which is exactly how the executed trajectory interpolates) when it finds none along the
segment: the same joint limits, the same padded bodies, zones and self-collision pairs, and the
same sweep bound between samples as the final check. Whatever this module returns is a
proposal: the caller times it and the unchanged `Envelope.check` decides.

**Only where a plan may go.** The search space is the joint limits (inside the soft margin,
unless the start or a goal sits in it) intersected with the per-plan travel boxes above.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.planning.search_tree import SearchEnds, SearchTree
from armwarden.robot.batch_fk import BatchFK
from armwarden.robot.ik import IkSolver
from armwarden.safety.envelope import Envelope

#: extra travel of one joint over its straight start-to-goal travel that `_straighten_joints` removes [rad]
_WANDER_RAD = 0.05
#: how much of a wandering joint's deviation from its straight line `_straighten_joints` tries to keep
_WANDER_KEPT = (0.0, 0.5, 0.25)
#: joint-space distances below this are one configuration [rad]
_SAME_RAD = 1e-9
#: slack on the joint travel cap for rounding: travel is summed exactly as the final check sums it [rad]
_TRAVEL_EPS = 1e-9


@dataclass(frozen=True)
class SearchOptions:
    """Settings of the search, with units."""

    range_rad: float = 0.5  # longest tree edge [rad, Euclidean in joint space]
    tcp_spacing_m: float = 0.005  # TCP path length measured at samples that move the TCP at most this far apart [m]
    tcp_margin: float = 0.002  # share of the TCP cap the search leaves unused (the final check samples differently)
    batch: int = 64  # configurations drawn at a time, before the caps' filter
    along_line_every: int = 2  # every this many draws, one configuration by IK near the straight TCP line (0: never)
    max_nodes: int = 4000  # per tree: a search that needs more is over budget anyway


@dataclass(frozen=True)
class SearchResult:
    """A joint polyline from the start to one of the goals (None: none found), and the effort."""

    path: np.ndarray | None
    goal_index: int | None  # which goal it reaches
    state_checks: int
    motion_checks: int
    elapsed_s: float
    stopped_early: bool  # the caller asked to stop (an e-stop), not the budget
    goals_within_caps: int = 0  # goals some path could reach within the caps (the others were not searched for)


@dataclass(frozen=True)
class PathCost:
    """What a joint polyline uses of the per-plan caps."""

    tcp_m: float  # TCP path length
    travel_rad: np.ndarray  # per joint, summed along the path


class DetourSearch:
    """Plans a joint path from a start to any of several goals around what the envelope forbids,
    within the per-plan caps.

    Not thread safe (the envelope's Pinocchio data): the daemon runs it on its one planning thread.
    """

    def __init__(self, envelope: Envelope, options: SearchOptions | None = None, ik: IkSolver | None = None) -> None:
        self.envelope = envelope
        self.options = options or SearchOptions()
        self.ik = ik  # None: no samples near the straight TCP line
        robot = envelope.robot
        self._n = robot.nq
        margin = envelope.limits.joint_limit_margin_rad
        # search inside the soft margin, so that a detour never adds a near-limit warning of its own
        self._lower = robot.lower + margin
        self._upper = robot.upper - margin
        self._tcp_reach = robot.reach[:, -1]  # metres of TCP motion per radian of each joint at most
        base = robot.model.frames[robot.frame_id(robot.base_frame)]
        self._fk = BatchFK.from_model(robot.model, [robot.tcp_frame],
                                      None if base.placement.isIdentity() else base.placement.inverse())
        self.travel_cap = float(envelope.limits.max_joint_step_rad)
        self.tcp_cap = float(envelope.limits.max_cartesian_step_m) * (1.0 - self.options.tcp_margin)
        self.state_checks = 0
        self.motion_checks = 0

    # ------------------------------------------------------------------ validity (the envelope's checks)
    def configuration_is_clear(self, q: np.ndarray) -> bool:
        return not any(v.is_hard for v in self.envelope.check_path(q, first_only=True))

    def segment_is_clear(self, q0: np.ndarray, q1: np.ndarray) -> bool:
        return not any(v.is_hard for v in self.envelope.check_path(np.vstack([q0, q1]), first_only=True))

    # ------------------------------------------------------------------ what a path uses of the caps
    def tcp_points(self, qs: np.ndarray) -> np.ndarray:
        """TCP positions (N, 3) of configurations `qs` (N, n), base frame."""
        return self.tcp_poses(qs)[:, :3, 3]

    def tcp_poses(self, qs: np.ndarray) -> np.ndarray:
        """TCP poses (N, 4, 4) of configurations `qs` (N, n), base frame."""
        return self._fk.poses_batch(np.ascontiguousarray(qs, dtype=float))[:, self._fk.n_joints]

    def segment_tcp_length(self, q0: np.ndarray, q1: np.ndarray) -> tuple[float, np.ndarray]:
        """The TCP path length of the straight joint segment (chords between samples whose TCP
        moves at most `tcp_spacing_m` apart: within a fraction of a millimetre of the arc, and at
        least what the final check measures on its sparser samples), and the TCP at `q1`."""
        bound = float(np.abs(q1 - q0) @ self._tcp_reach)
        pieces = max(1, int(np.ceil(bound / self.options.tcp_spacing_m)))
        alpha = np.linspace(0.0, 1.0, pieces + 1)[:, None]
        points = self.tcp_points(q0 + alpha * (q1 - q0))
        return float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1))), points[-1]

    def path_cost(self, path: np.ndarray) -> PathCost:
        """What the joint polyline `path` uses of the caps."""
        path = np.atleast_2d(np.asarray(path, dtype=float))
        tcp = sum(self.segment_tcp_length(a, b)[0] for a, b in itertools.pairwise(path))
        return PathCost(float(tcp), np.sum(np.abs(np.diff(path, axis=0)), axis=0))

    def within_caps(self, cost: PathCost) -> bool:
        return cost.tcp_m <= self.tcp_cap and bool(np.all(cost.travel_rad <= self.travel_cap + _TRAVEL_EPS))

    # ------------------------------------------------------------------ search
    def find(
        self, start: np.ndarray, goals: Sequence[np.ndarray], seed: int, deadline: float,
        should_stop: Callable[[], bool] = lambda: False, attempt: int = 0,
        tails: Sequence[np.ndarray | None] | None = None,
    ) -> SearchResult:
        """A valid joint path from `start` to one of `goals` within the per-plan caps, or none
        before `deadline` (`time.monotonic`). `tails[k]`, if given, is where the plan goes
        straight on to after goal k (an approach leg): its use of the caps counts. `attempt`
        varies the random numbers for a later search of the same request."""
        began = time.monotonic()
        self.state_checks = self.motion_checks = 0
        start = np.asarray(start, dtype=float)
        ends = self._ends(start, goals, tails)
        reachable = self._within_reach(ends)
        if not np.any(reachable):
            return SearchResult(None, None, 0, 0, time.monotonic() - began, False, 0)
        rng = np.random.default_rng([seed, attempt])
        opts = self.options
        start_tree = SearchTree(self._n, opts.max_nodes)
        goal_tree = SearchTree(self._n, opts.max_nodes)
        start_tree.add(start, ends.start_tcp, 0.0, np.zeros(self._n), -1, -1)
        for k in np.flatnonzero(reachable):
            goal_tree.add(ends.goals[k], ends.goal_tcp[k], float(ends.tail_tcp[k]), ends.tail_travel[k], -1, int(k))
        boxes = self._sampling_boxes(ends, reachable)
        pending: list[np.ndarray] = []
        stopped = False
        trees = (start_tree, goal_tree)
        for turn in itertools.count():
            if should_stop():
                stopped = True
                break
            if time.monotonic() > deadline or start_tree.full or goal_tree.full:
                break
            if not pending:
                pending = self._draw(rng, ends, boxes, turn)
                if not pending:
                    continue
            q_rand = pending.pop()
            grow, other = trees if turn % 2 == 0 else trees[::-1]
            added = self._extend(grow, q_rand, ends)
            if added is None:
                continue
            joined = self._connect(other, grow.q[added], ends)
            if joined is None:
                continue
            a, b = (added, joined) if grow is start_tree else (joined, added)
            used_tcp = start_tree.used_tcp[a] + goal_tree.used_tcp[b]
            used_travel = start_tree.used_travel[a] + goal_tree.used_travel[b]
            if used_tcp > self.tcp_cap or np.any(used_travel > self.travel_cap + _TRAVEL_EPS):
                continue  # the two halves meet, but together they use too much
            path = np.vstack(start_tree.branch(a)[::-1] + goal_tree.branch(b)[1:])
            end = int(goal_tree.root[b])
            path[0], path[-1] = start, ends.goals[end]  # exactly, not copies through arithmetic
            tail = None if tails is None else tails[end]
            return self._result(self._polish(path, tail), end, began, False, int(np.sum(reachable)))
        return self._result(None, None, began, stopped, int(np.sum(reachable)))

    def _ends(self, start: np.ndarray, goals: Sequence[np.ndarray], tails: Sequence[np.ndarray | None] | None) -> SearchEnds:
        goal_array = np.array([np.asarray(g, dtype=float) for g in goals]).reshape(len(goals), self._n)
        tail_tcp = np.zeros(len(goals))
        tail_travel = np.zeros((len(goals), self._n))
        for k, tail in enumerate(tails or ()):
            if tail is not None:
                tail_tcp[k] = self.segment_tcp_length(goal_array[k], np.asarray(tail, dtype=float))[0]
                tail_travel[k] = np.abs(np.asarray(tail, dtype=float) - goal_array[k])
        poses = self.tcp_poses(np.vstack([start, goal_array]))
        return SearchEnds(start, poses[0, :3, 3], poses[0, :3, :3], goal_array, poses[1:, :3, 3], poses[1:, :3, :3],
                     tail_tcp, tail_travel)

    def _within_reach(self, ends: SearchEnds) -> np.ndarray:
        """Per goal: whether the straight TCP distance and the straight joint travel (plus its
        approach leg) are within the caps — no path to it uses less."""
        tcp = np.linalg.norm(ends.goal_tcp - ends.start_tcp, axis=1) + ends.tail_tcp
        travel = np.abs(ends.goals - ends.start) + ends.tail_travel
        return (tcp <= self.tcp_cap) & np.all(travel <= self.travel_cap + _TRAVEL_EPS, axis=1)

    def _sampling_boxes(self, ends: SearchEnds, reachable: np.ndarray) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """Per reachable goal: the joint box a path to it may pass through (per joint, a detour to
        q travels |q - start| + |goal - q| ≥ the straight travel plus twice the excursion)."""
        boxes = []
        every = np.vstack([ends.start, ends.goals])
        lower = np.minimum(self._lower, every.min(axis=0))  # the start or a goal may sit inside the margin
        upper = np.maximum(self._upper, every.max(axis=0))
        for k in np.flatnonzero(reachable):
            slack = (self.travel_cap - np.abs(ends.goals[k] - ends.start) - ends.tail_travel[k]) / 2.0
            lo = np.maximum(lower, np.minimum(ends.start, ends.goals[k]) - slack)
            hi = np.minimum(upper, np.maximum(ends.start, ends.goals[k]) + slack)
            boxes.append((int(k), lo, hi))
        return boxes

    def _draw(self, rng: np.random.Generator, ends: SearchEnds, boxes: list[tuple[int, np.ndarray, np.ndarray]],
              turn: int) -> list[np.ndarray]:
        """A batch of configurations in one goal's box (the goals in turn) whose TCP lies in its
        ellipsoid: a path through them can stay within both caps. Maybe none.

        Uniform samples in the box: where the TCP cap leaves little room beyond the straight
        TCP distance, the ellipsoid is a thin tube few of them hit, so every
        `along_line_every`-th draw adds one configuration solved by IK for a point near the
        straight TCP line (within the tube's width there), the orientation turned part of the
        way from the start's to the goal's, seeded from the joints as far along their line."""
        k, lo, hi = boxes[turn % len(boxes)]
        qs = rng.uniform(lo, hi, (self.options.batch, self._n))
        every = self.options.along_line_every
        if self.ik is not None and every and turn % every == every - 1:
            near_line = self._near_line(rng, ends, k)
            if near_line is not None:
                qs = np.vstack([qs, np.clip(near_line, lo, hi)])
        tcp = self.tcp_points(qs)
        lower_bound = (np.linalg.norm(tcp - ends.start_tcp, axis=1) + np.linalg.norm(tcp - ends.goal_tcp[k], axis=1)
                       + ends.tail_tcp[k])
        return list(qs[lower_bound <= self.tcp_cap][::-1])

    def _near_line(self, rng: np.random.Generator, ends: SearchEnds, k: int) -> np.ndarray | None:
        """One IK solution for a random point of the TCP tube from the start to goal `k` (None:
        IK missed it)."""
        assert self.ik is not None
        fraction = float(rng.uniform(0.05, 0.95))
        half_axis = (self.tcp_cap - ends.tail_tcp[k]) / 2.0
        half_focal = float(np.linalg.norm(ends.goal_tcp[k] - ends.start_tcp)) / 2.0
        width = np.sqrt(max(half_axis**2 - half_focal**2, 0.0)) * np.sqrt(1.0 - (2.0 * fraction - 1.0) ** 2)
        offset = rng.normal(size=3)
        offset *= width * float(rng.uniform()) ** (1.0 / 3.0) / max(float(np.linalg.norm(offset)), 1e-12)
        point = ends.start_tcp + fraction * (ends.goal_tcp[k] - ends.start_tcp) + offset
        rotation = pin.Quaternion(ends.start_rotation).slerp(fraction, pin.Quaternion(ends.goal_rotation[k])).toRotationMatrix()
        result = self.ik.solve_from(point, rotation, ends.start + fraction * (ends.goals[k] - ends.start))
        return result.q if result.success else None

    def _admissible(self, tree_is_start: bool, tcp: np.ndarray, q: np.ndarray, used_tcp: float,
                    used_travel: np.ndarray, ends: SearchEnds) -> bool:
        """Whether a node's path so far plus the least the rest could use stays within the caps."""
        if tree_is_start:  # the rest: to some goal, and its approach leg
            rest_tcp = np.linalg.norm(ends.goal_tcp - tcp, axis=1) + ends.tail_tcp
            rest_travel = np.abs(ends.goals - q) + ends.tail_travel
            ok = (used_tcp + rest_tcp <= self.tcp_cap) & np.all(used_travel + rest_travel <= self.travel_cap + _TRAVEL_EPS,
                                                                 axis=1)
            return bool(np.any(ok))
        # the goal tree's rest is the way to the start, whichever goal it came from
        return (used_tcp + float(np.linalg.norm(ends.start_tcp - tcp)) <= self.tcp_cap
                and bool(np.all(used_travel + np.abs(ends.start - q) <= self.travel_cap + _TRAVEL_EPS)))

    def _extend(self, tree: SearchTree, target: np.ndarray, ends: SearchEnds) -> int | None:
        """One step of at most `range_rad` from the nearest node towards `target`: the new node,
        or None when the step leaves the caps or the envelope refuses it."""
        if tree.full:
            return None
        i = tree.nearest(target)
        q_near = tree.q[i]
        step = target - q_near
        distance = float(np.linalg.norm(step))
        if distance < _SAME_RAD:
            return i
        q_new = target if distance <= self.options.range_rad else q_near + step * (self.options.range_rad / distance)
        edge_tcp, tcp = self.segment_tcp_length(q_near, q_new)
        used_tcp = float(tree.used_tcp[i]) + edge_tcp
        used_travel = tree.used_travel[i] + np.abs(q_new - q_near)
        root = int(tree.root[i])
        if not self._admissible(root < 0, tcp, q_new, used_tcp, used_travel, ends):
            return None
        self.state_checks += 1
        if not self.configuration_is_clear(q_new):
            return None
        self.motion_checks += 1
        if not self.segment_is_clear(q_near, q_new):
            return None
        return tree.add(q_new, tcp, used_tcp, used_travel, i, root)

    def _connect(self, tree: SearchTree, target: np.ndarray, ends: SearchEnds) -> int | None:
        """RRT-Connect's greedy connection: steps towards `target` until it is reached (the node
        at `target`) or a step fails (None)."""
        while True:
            added = self._extend(tree, target, ends)
            if added is None:
                return None
            if float(np.linalg.norm(tree.q[added] - target)) < _SAME_RAD:
                return added

    def _polish(self, path: np.ndarray, tail: np.ndarray | None) -> np.ndarray:
        """Shortcut, then straighten wandering joints, keeping each change only while the whole
        path (with its approach leg) stays within the caps."""
        shortened = self._shortcut(path)
        straightened = self._straighten_joints(shortened)
        legs = (lambda p: p) if tail is None else (lambda p: np.vstack([p, tail]))
        if straightened is not shortened and not self.within_caps(self.path_cost(legs(straightened))):
            return shortened
        return straightened

    def _shortcut(self, positions: np.ndarray) -> np.ndarray:
        """Greedy, deterministic: from each kept vertex jump to the farthest later one in clear
        sight whose straight segment moves the TCP no further than the path it replaces (a
        straight joint segment is not a straight TCP line: it can be longer), so that a path within
        the caps stays within them (per-joint travel never grows by the triangle inequality)."""
        lengths = [self.segment_tcp_length(a, b)[0] for a, b in itertools.pairwise(positions)]
        along = np.concatenate([[0.0], np.cumsum(lengths)])
        kept = [0]
        while kept[-1] < len(positions) - 1:
            i = kept[-1]
            j = len(positions) - 1
            while j > i + 1 and not (self.segment_tcp_length(positions[i], positions[j])[0] <= along[j] - along[i] + 1e-12
                                     and self.segment_is_clear(positions[i], positions[j])):
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

    def _result(self, path: np.ndarray | None, goal_index: int | None, began: float, early: bool,
                reachable: int) -> SearchResult:
        return SearchResult(path, goal_index, self.state_checks, self.motion_checks, time.monotonic() - began, early,
                            reachable)
