"""What the envelope's geometry checks look at, built once per robot and limits: every checked
body (the robot's capsules, padded, then the TCP point), the self-collision pairs with their
radii and reaches, the workspace box and the keep-out zones. The numpy passes, the findings'
wording and the compiled kernels' tables all read this one record."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from armwarden.core.errors import RobotModelError
from armwarden.robot.capsules import Capsule
from armwarden.robot.model import RobotModel
from armwarden.safety.limits import Box, EnvelopeLimits


@dataclass(frozen=True)
class CheckedBodies:
    """B capsules and the TCP point (last: zero radius, no padding), P pairs, Z zones."""

    names: tuple[str, ...]  # (B+1,) how findings name each body (several may share one)
    padded_radii: np.ndarray  # (B+1,) radius plus the link's padding [m]
    moving: np.ndarray  # (B+1,) bool: not fixed to the world
    pairs: np.ndarray  # (P, 2) body indices
    pair_radii: np.ndarray  # (P,) summed radii, unpadded [m]
    pair_reach: np.ndarray  # (n, P) relative reach per joint (`relative_reach`)
    pair_sphere_reach: np.ndarray  # (P,) summed radii and half lengths: the bounding spheres' reach
    workspace_lo: np.ndarray
    workspace_hi: np.ndarray
    keep_out: tuple[Box, ...]
    keep_out_lo: np.ndarray  # (Z, 3)
    keep_out_hi: np.ndarray  # (Z, 3)

    @classmethod
    def build(cls, robot: RobotModel, limits: EnvelopeLimits) -> CheckedBodies:
        """The bodies of `robot` under `limits`; refuses padding for a link the robot does not
        have, and two keep-out zones of one name (findings name their zone)."""
        names = [body_name(robot, c) for c in robot.capsules]
        # the TCP point is the last body (zero radius, no padding); a TCP frame that is also a link
        # with bodies of its own (`tcp_frame: fr3_hand`) is told apart from that link's bodies
        names.append(robot.tcp_frame if robot.tcp_frame not in names else f"{robot.tcp_frame} (TCP)")
        unknown = sorted(set(limits.padding_by_link_m) - set(robot.link_names()))
        if unknown:
            raise RobotModelError(f"padding_by_link_m names unknown link(s) {unknown}; valid links: {sorted(robot.link_names())}")
        padding = [limits.padding_by_link_m.get(c.link, limits.link_padding_m) for c in robot.capsules]
        pairs = robot.self_collision_pairs if limits.self_collision else np.zeros((0, 2), dtype=np.intp)
        pair_radii = robot.capsule_radii[pairs[:, 0]] + robot.capsule_radii[pairs[:, 1]]
        half_lengths = np.array([np.linalg.norm(np.subtract(c.p1_m, c.p0_m)) / 2.0 for c in robot.capsules])
        zone_names = [z.name for z in limits.keep_out]
        if len(set(zone_names)) != len(zone_names):  # the policy refuses it too: findings name their zone
            raise ValueError(f"keep-out zone names must be unique; got {zone_names}")
        if limits.keep_out:
            keep_out_lo = np.stack([z.lo for z in limits.keep_out])
            keep_out_hi = np.stack([z.hi for z in limits.keep_out])
        else:
            keep_out_lo = keep_out_hi = np.zeros((0, 3))
        return cls(
            names=tuple(names),
            padded_radii=np.concatenate([robot.capsule_radii + np.array(padding, dtype=float), [0.0]]),
            # bodies fixed to the world (the base) cannot move into a zone or out of the box: only
            # self-collision looks at them (the TCP point, last, always moves with the arm)
            moving=np.array([c.joint_index != 0 for c in robot.capsules] + [True]),
            pairs=pairs,
            pair_radii=pair_radii,
            pair_reach=relative_reach(robot, pairs),
            pair_sphere_reach=pair_radii + half_lengths[pairs[:, 0]] + half_lengths[pairs[:, 1]],
            workspace_lo=limits.workspace.lo,
            workspace_hi=limits.workspace.hi,
            keep_out=tuple(limits.keep_out),
            keep_out_lo=keep_out_lo,
            keep_out_hi=keep_out_hi,
        )


def relative_reach(robot: RobotModel, pairs: np.ndarray) -> np.ndarray:
    """`(n, P)`: bound on how far the distal capsule of each pair moves *relative to the other*
    per unit motion of each joint. Only the joints between the two capsules move one relative
    to the other, so pairs near the base get far smaller allowances than the sum of both
    capsules' absolute motions. Capsules on separate branches keep the sum (conservative)."""
    model, capsules, reach = robot.model, robot.capsules, robot.reach
    out = np.zeros((robot.nq, len(pairs)))
    for index, (a, b) in enumerate(pairs):
        ja, jb = capsules[a].joint_index, capsules[b].joint_index
        if ja > jb:
            a, b, ja, jb = b, a, jb, ja
        chain, j = set(), jb
        while j > 0:
            chain.add(j)
            j = model.parents[j]
        if ja == 0 or ja in chain:
            between = [model.joints[j].idx_q for j in chain if j > ja]
            out[between, index] = reach[between, b]
        else:
            out[:, index] = reach[:, a] + reach[:, b]
    return out


def body_name(robot: RobotModel, capsule: Capsule) -> str:
    """How findings name a body: its link, or `link#capsule` when the link has several primitives
    from the URDF. Fitted bodies (`link/k`) are named by their link: they are pieces of one
    surface, and a finding per link (its first) is what a person reads."""
    if capsule.name.startswith(f"{capsule.link}/"):
        return capsule.link
    if sum(1 for c in robot.capsules if c.link == capsule.link) > 1:
        return f"{capsule.link}#{capsule.name}"
    return capsule.link
