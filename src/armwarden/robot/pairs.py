"""Self-collision pairs by analysis: a body pair is left out only with a proof, never by luck.

Two fitted capsules, on different links, may be left out of the self-collision check for one of
two reasons, each *proved* over every configuration within the joint limits:

- **apart** — they can never come within `clearance_m` of each other;
- **overlapping** — they overlap at every configuration (two bodies around one joint, say): a
  check on them would refuse every motion, so it must go, and the proof says it is not hiding
  anything that could change;
- **adjacent** — the other body pairs of two links joined by a single joint (or rigidly) of
  which one body pair is proved overlapping: those links are in contact by construction.

Everything else is checked. "Not seen colliding in N random samples" is never a reason: samples
are used here only to *find* a configuration where a pair touches and one where it does not,
which ends the search for a proof early (the pair stays in).

The proof is a branch and bound over the joints between the two bodies. Express both in the
frame of their deepest common ancestor joint; at the centre `q_m` of a box of joint intervals
compute the capsules' segment distance `D(q_m)` exactly. Turning joint `i` by at most `w_i`
(the box's half-width) moves any point at most `2·d_i·sin(w_i/2)` (`w_i` for a prismatic
joint), where `d_i` bounds the distance of the body from joint `i`'s origin over every
configuration (the joint-to-joint offsets along the chain plus the body's farthest end point,
taken from the Pinocchio model: any robot, nothing typed in). With `δ` the sum of those bounds
for both bodies, the distance anywhere in the box lies in `[D − δ, D + δ]`. A box with
`D − δ > r_a + r_b + clearance` is proved apart, one with `D + δ < r_a + r_b` proved
overlapping; any other box is halved across the joint that contributes most to `δ`. A pair whose
every box is proved one way is excluded for that reason; a pair seen both ways, or not settled
within `max_boxes`, stays in (the conservative answer).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow

from armwarden.core.errors import RobotModelError
from armwarden.core.geometry import segment_segment_distance
from armwarden.robot.fitted_file import ExcludedPair, FittedGeometry

__all__ = ["PairAnalysis", "PairOptions", "PairVerdict", "PlacedBody", "analyse_pairs", "place_bodies"]


@dataclass(frozen=True)
class PlacedBody:
    """A fitted capsule on the joint that moves it: end points in that joint's frame [m]."""

    name: str
    link: str
    joint: int  # Pinocchio joint id (0: fixed to the world)
    p0: np.ndarray
    p1: np.ndarray
    radius_m: float


@dataclass(frozen=True)
class PairOptions:
    """Settings of `analyse_pairs`."""

    clearance_m: float = 0.0  # "apart" means never closer than this [m] (capsule surfaces)
    max_boxes: int = 100_000  # per link pair; past it the open pairs stay in
    witness_samples: int = 1000  # random configurations per link pair, to find touching/apart early
    seed: int = 0

    def __post_init__(self) -> None:
        if self.clearance_m < 0 or self.max_boxes < 1 or self.witness_samples < 0:
            raise ValueError("clearance_m must be ≥ 0, max_boxes ≥ 1, witness_samples ≥ 0")


@dataclass(frozen=True)
class PairVerdict:
    """What the analysis concluded for one body pair, with the proof or the reason it stays in."""

    bodies: tuple[str, str]
    decision: Literal["apart", "overlapping", "adjacent", "included"]
    reason: str


@dataclass(frozen=True)
class PairAnalysis:
    verdicts: tuple[PairVerdict, ...]
    joint_limits: dict[str, tuple[float, float]]
    clearance_m: float

    @property
    def included(self) -> tuple[tuple[str, str], ...]:
        return tuple(v.bodies for v in self.verdicts if v.decision == "included")

    @property
    def excluded(self) -> tuple[ExcludedPair, ...]:
        return tuple(ExcludedPair(v.bodies, v.decision, v.reason) for v in self.verdicts if v.decision != "included")


def place_bodies(model: pin.Model, geometry: FittedGeometry) -> list[PlacedBody]:
    """Every fitted body on the joint of its link (links are Pinocchio BODY frames)."""
    placed = []
    for link, fit in geometry.links.items():
        if not model.existFrame(link, pin.FrameType.BODY):
            raise RobotModelError(f"fitted link {link!r} is not a link of the model")
        frame = model.frames[model.getFrameId(link, pin.FrameType.BODY)]
        for body in fit.bodies:
            placed.append(PlacedBody(
                name=body.name,
                link=link,
                joint=int(frame.parentJoint),
                p0=frame.placement.act(np.array(body.p0_m, dtype=float)),
                p1=frame.placement.act(np.array(body.p1_m, dtype=float)),
                radius_m=body.radius_m,
            ))
    return placed


# --------------------------------------------------------------------------- the chain


def _chain(model: pin.Model, joint: int) -> list[int]:
    """[joint, its parent, …, 0]."""
    chain = [joint]
    while chain[-1] != 0:
        chain.append(int(model.parents[chain[-1]]))
    return chain


def _is_prismatic(model: pin.Model, joint: int) -> bool:
    return "JointModelP" in model.joints[joint].shortname()


@dataclass
class _Side:
    """One link's bodies as seen from the common ancestor: the joints that move them and, per
    joint and body, the bound `d` on the body's distance from that joint's origin."""

    joints: list[int]  # moving joints, nearest the ancestor first
    bodies: list[PlacedBody]
    reach: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))  # (len(joints), len(bodies))


def _side(model: pin.Model, bodies: list[PlacedBody], ancestor: int, lower: np.ndarray, upper: np.ndarray) -> _Side:
    joint = bodies[0].joint
    below = _chain(model, joint)
    moving = below[: below.index(ancestor)][::-1]
    reach = np.zeros((len(moving), len(bodies)))
    far = np.array([max(float(np.linalg.norm(b.p0)), float(np.linalg.norm(b.p1))) for b in bodies])
    for row in range(len(moving)):
        offset = 0.0
        for nxt in moving[row + 1:]:
            offset += float(np.linalg.norm(model.jointPlacements[nxt].translation))
            if _is_prismatic(model, nxt):
                idx = model.joints[nxt].idx_q
                offset += max(abs(float(lower[idx])), abs(float(upper[idx])))
        reach[row] = offset + far
    return _Side(moving, bodies, reach)


# --------------------------------------------------------------------------- the analysis


class _LinkPair:
    """The analysis of all body pairs of two links over the joints between them (arrays over
    the A × B body pairs: what was seen where, and the tightest proof margins)."""

    def __init__(self, model: pin.Model, a: list[PlacedBody], b: list[PlacedBody], lower: np.ndarray,
                 upper: np.ndarray, options: PairOptions) -> None:
        self.model = model
        self.data = model.createData()
        chain_b = set(_chain(model, b[0].joint))
        self.ancestor = next(j for j in _chain(model, a[0].joint) if j in chain_b)
        self.side_a = _side(model, a, self.ancestor, lower, upper)
        self.side_b = _side(model, b, self.ancestor, lower, upper)
        self.joints = self.side_a.joints + self.side_b.joints
        self.idx = np.array([model.joints[j].idx_q for j in self.joints], dtype=np.intp)
        self.prismatic = np.array([_is_prismatic(model, j) for j in self.joints], dtype=bool)
        self.lower, self.upper = lower[self.idx], upper[self.idx]
        self.reference = pin.neutral(model)
        self.options = options
        self.ends = [(np.array([x.p0 for x in side]), np.array([x.p1 for x in side])) for side in (a, b)]
        self.radius_sum = np.array([[x.radius_m + y.radius_m for y in b] for x in a])
        shape = self.radius_sum.shape
        self.close_at = np.full((*shape, len(self.joints)), np.nan)  # first configuration refuting "apart"
        self.separate_at = np.full((*shape, len(self.joints)), np.nan)  # first refuting "overlapping"
        self.close_seen = np.zeros(shape, dtype=bool)
        self.separate_seen = np.zeros(shape, dtype=bool)
        self.apart_slack = np.full(shape, np.inf)
        self.overlap_slack = np.full(shape, np.inf)
        # per joint, the reach of each body pair's moving body: (J, A, B)
        n_a = len(self.side_a.joints)
        reach = np.zeros((len(self.joints), len(a), len(b)))
        reach[:n_a] = self.side_a.reach[:, :, None]
        reach[n_a:] = self.side_b.reach[:, None, :]
        self.reach = reach

    def distances(self, values: np.ndarray) -> np.ndarray:
        """(A, B) segment distances with the moving joints at `values`."""
        q = self.reference.copy()
        q[self.idx] = values
        pin.forwardKinematics(self.model, self.data, q)
        to_ancestor = self.data.oMi[self.ancestor].inverse()
        moved = []
        for side, (p0, p1) in zip((self.side_a, self.side_b), self.ends, strict=True):
            placement = to_ancestor * self.data.oMi[side.bodies[0].joint]
            rotation, translation = placement.rotation, placement.translation
            moved.append((p0 @ rotation.T + translation, p1 @ rotation.T + translation))
        (a0, a1), (b0, b1) = moved
        return segment_segment_distance(a0[:, None], a1[:, None], b0[None, :], b1[None, :])

    def motion_bound(self, half_width: np.ndarray) -> np.ndarray:
        """(J, A, B): per joint, how far the pair's relative position can move within the box."""
        turn = np.where(self.prismatic, half_width, 2.0 * np.sin(np.minimum(half_width, np.pi) / 2.0))
        return np.where(self.prismatic[:, None, None], turn[:, None, None], turn[:, None, None] * self.reach)

    def observe(self, values: np.ndarray, distance: np.ndarray) -> None:
        """Note a configuration that refutes 'apart' (the pair within the clearance) or one that
        refutes 'overlapping' (the pair not overlapping); a pair with both stays in."""
        close = (distance <= self.radius_sum + self.options.clearance_m) & ~self.close_seen
        separate = (distance >= self.radius_sum) & ~self.separate_seen
        self.close_at[close] = values
        self.separate_at[separate] = values
        self.close_seen |= close
        self.separate_seen |= separate

    def open_mask(self) -> np.ndarray:
        return ~(self.close_seen & self.separate_seen)

    def sample(self, rng: np.random.Generator) -> None:
        """Random configurations, only to find a touching and an apart configuration early."""
        for _ in range(self.options.witness_samples):
            if not self.open_mask().any():
                return
            values = self.lower + rng.random(len(self.joints)) * (self.upper - self.lower)
            self.observe(values, self.distances(values))

    def prove(self) -> tuple[np.ndarray, int]:
        """Branch and bound: (A, B) flags 'every box searched for this pair proved it one way',
        and the number of boxes searched. A box carries the pairs its parent left unresolved."""
        clearance = self.options.clearance_m
        proved = np.ones(self.radius_sum.shape, dtype=bool)
        stack = [(self.lower.copy(), self.upper.copy(), self.open_mask())]
        boxes = 0
        while stack:
            lo, hi, pending = stack.pop()
            pending = pending & self.open_mask()
            if not pending.any():
                continue
            if boxes >= self.options.max_boxes:
                for _, _, left in [*stack, (lo, hi, pending)]:
                    proved[left] = False
                break
            boxes += 1
            centre = (lo + hi) / 2.0
            distance = self.distances(centre)
            self.observe(centre, distance)
            bound = self.motion_bound((hi - lo) / 2.0)
            delta = bound.sum(axis=0)
            apart = pending & (distance - delta > self.radius_sum + clearance)
            overlap = pending & (distance + delta < self.radius_sum)
            self.apart_slack = np.where(apart, np.minimum(self.apart_slack, distance - delta - self.radius_sum), self.apart_slack)
            self.overlap_slack = np.where(overlap, np.minimum(self.overlap_slack, self.radius_sum - distance - delta),
                                          self.overlap_slack)
            unresolved = pending & ~apart & ~overlap
            if not unresolved.any():
                continue
            if len(self.joints) == 0:  # nothing moves and the pair touches exactly: keep it
                proved[unresolved] = False
                continue
            split = int(np.argmax(np.max(np.where(unresolved[None], bound, 0.0), axis=(1, 2))))
            middle = centre[split]
            lower_hi, upper_lo = hi.copy(), lo.copy()
            lower_hi[split] = middle
            upper_lo[split] = middle
            stack += [(upper_lo, hi, unresolved), (lo, lower_hi, unresolved)]  # the lower half first
        return proved, boxes

    def describe_box(self) -> str:
        if not self.joints:
            return "no joint between them (fixed relative pose)"
        names = self.model.names
        return ", ".join(f"{names[j]} in [{lo:.4f}, {hi:.4f}]" for j, lo, hi in zip(self.joints, self.lower, self.upper, strict=True))


def analyse_pairs(model: pin.Model, bodies: Sequence[PlacedBody], options: PairOptions | None = None) -> PairAnalysis:
    """Verdicts for every pair of bodies on different links, over the model's joint limits."""
    options = options or PairOptions()
    lower = np.asarray(model.lowerPositionLimit, dtype=float)
    upper = np.asarray(model.upperPositionLimit, dtype=float)
    links: dict[str, list[PlacedBody]] = {}
    for body in bodies:
        links.setdefault(body.link, []).append(body)
    names = list(links)
    verdicts: list[PairVerdict] = []
    for ia, link_a in enumerate(names):
        for link_b in names[ia + 1:]:
            pair = _LinkPair(model, links[link_a], links[link_b], lower, upper, options)
            pair.sample(np.random.default_rng([options.seed, ia, names.index(link_b)]))
            proved, boxes = pair.prove()
            span = pair.describe_box()
            found = [
                _verdict(pair, i, j, body_a.name, body_b.name, bool(proved[i, j]), boxes, span)
                for i, body_a in enumerate(pair.side_a.bodies)
                for j, body_b in enumerate(pair.side_b.bodies)
            ]
            verdicts += _adjacent(pair, found)
    used = sorted({j for b in bodies for j in _chain(model, b.joint) if j != 0})
    limits = {model.names[j]: (float(lower[model.joints[j].idx_q]), float(upper[model.joints[j].idx_q])) for j in used}
    return PairAnalysis(tuple(verdicts), limits, options.clearance_m)


def _verdict(pair: _LinkPair, i: int, j: int, a: str, b: str, proved: bool, boxes: int, span: str) -> PairVerdict:
    if pair.close_seen[i, j] and pair.separate_seen[i, j]:
        within = "touching" if pair.options.clearance_m == 0 else f"within {pair.options.clearance_m} m"
        return PairVerdict((a, b), "included",
                           f"{within} at {_q(pair.close_at[i, j])}, not overlapping at {_q(pair.separate_at[i, j])}")
    if not proved:
        return PairVerdict((a, b), "included", f"not settled within {pair.options.max_boxes} boxes")
    if not pair.close_seen[i, j]:
        return PairVerdict((a, b), "apart", (
            f"branch and bound over {span} ({boxes} boxes searched): every box covering this pair keeps the "
            f"capsules more than {pair.options.clearance_m} m apart (centre distance - motion bound - radii "
            f">= {pair.apart_slack[i, j]:.4f} m)"))
    return PairVerdict((a, b), "overlapping", (
        f"branch and bound over {span} ({boxes} boxes searched): in every box covering this pair the "
        f"capsules overlap (radii - centre distance - motion bound >= {pair.overlap_slack[i, j]:.4f} m)"))


def _adjacent(pair: _LinkPair, found: list[PairVerdict]) -> list[PairVerdict]:
    """Links joined by one joint (or none) whose bodies overlap at every configuration are in
    contact by construction: a check on any of their body pairs tells nothing the joint's limits
    do not, and the included ones would refuse motions near the joint for the fit's margin alone.
    They are left out too, naming the pair that always overlaps. Links two or more joints apart
    are never left out this way."""
    witness = next((v for v in found if v.decision == "overlapping"), None)
    if witness is None or len(pair.joints) > 1:
        return found
    joint = pair.model.names[pair.joints[0]] if pair.joints else "none (rigidly fixed)"
    reason = (f"adjacent links (joint between them: {joint}) always in contact: {witness.bodies[0]} and "
              f"{witness.bodies[1]} overlap at every configuration (see their proof)")
    return [PairVerdict(v.bodies, "adjacent", reason) if v.decision == "included" else v for v in found]


def _q(values: np.ndarray) -> str:
    return "[" + ", ".join(f"{v:.3f}" for v in values) + "]"
