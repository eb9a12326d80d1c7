"""The envelope's geometry checks at compiled speed: the same samples, predicates and findings.

`Envelope` checks a path by sampling it (coarse to fine, `envelope.REFINEMENT`) and testing every
padded, inflated capsule at every sample against the workspace box, the keep-out zones and the
other capsules. Written with numpy over whole batches, that costs ~250 µs for one configuration
and milliseconds for one motion: a planner's budget buys a few hundred checks. Here the same work
runs in numba kernels — forward kinematics (`robot.batch_fk`'s `fk_into`, derived from the
Pinocchio model), the sampling of the path, the three checks and the refinement — with nothing
crossing back into Python until the answer is known.

**Same answer.** The kernels place the samples exactly where `Envelope._samples_at` places them
(the same arithmetic, operation for operation: `_unit_targets`, `searchsorted`, the linear
interpolation, `_half_neighbour_bound`; the per-segment body bounds come in from numpy's own
product), give each body and pair the same inflation, check flagged samples without allowance and
refine the rest in the same depth-first order (`Envelope._refine`), and confirm every candidate
with the predicates of `safety.geometry`, ported line for line: capsule bounds in the workspace
box; the segment–box distance, and for the TCP also the slab test of its straight segment from
the previous sample; the segment–segment distance against the pair's summed radii plus its
inflation. Findings are kept per key as `Envelope` keeps them (see "findings" below), and each
returned row says what `Envelope` needs to word it: kind, body or pair, zone, time, the body's
first end point, distance, allowance. tests/safety/test_geometry_kernel.py holds compiled and
numpy envelopes to the same violations, word for word, and the same per-sample flags, on random
paths, zones and workspace boxes. (Forward kinematics agrees with Pinocchio to ~1e-15 m, not bit
for bit, so a sample lying within that of a limit could be judged differently; nothing else
differs.)

**Only faster, never weaker: the broad phases.** Per sample, each link's capsules are first
tested as one bounding sphere (fixed in the link's joint frame) grown by an upper bound of their
inflations; a link whose sphere is inside the workspace box, apart from a zone, or apart from
another link's sphere by more than the pairs' radii plus their inflation bound cannot give any of
its capsules a finding, and they are skipped. The bounds are proofs, not guesses: a body's
inflation is half its motion bound over the neighbouring sample intervals, and that bound grows
along the path at most at the rate Σ_i rate_i · reach_i, where rate_i is joint i's largest step
per unit of path parameter (`_joint_rates`) — and never faster than `sweep_resolution_m` per
unit, which is how the path parameter is defined; likewise a pair's relative-motion bound with
the pairs' relative reaches. A pair that survives gets the numpy pass's bounding-sphere test, a
bounding-box test against its allowance, then the exact distance — on a path first against a
bound of its inflation (its own relative-motion rate times half the sample gap), so that its
exact inflation is computed only for a pair that comes within the bound. A pair apart by a
margin is not tested again while the path parameter stays within margin ÷ rate of that sample
(its segments cannot close the margin sooner), at that sample gap or a smaller one. Margins of
1e-9 m absorb rounding in the bounds. A sample of a pass whose findings are never reported (one that only decides where to
refine) stops at its first hit; the densest pass does not test a key whose kept finding it cannot
make earlier.

**Compilation.** Like `robot.batch_fk`: eager, explicit signatures, numba's on-disk cache (or
in memory with a warning where no cache directory is writable). The first import compiles for
20–40 s (the three entry points share `_evaluate`); later imports load the machine code. The
static tables (`Tables`) are packed into one int64 and one float64 array, so a call unboxes few
arguments (numba's dispatcher costs about 0.1 µs per argument). numba's cache keys on this file
only: after editing `batch_fk._fk_into`, delete this module's `__pycache__/geometry_kernel.*`
files so the kernels here pick the change up.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np

from armwarden.robot.batch_fk import KinematicChain, _compile, fk_into  # pyright: ignore[reportPrivateUsage]

__all__ = [
    "HIT_COLUMNS",
    "KIND_KEEP_OUT",
    "KIND_SELF",
    "KIND_WORKSPACE",
    "NON_FINITE",
    "Tables",
    "check_configuration",
    "check_path",
    "check_samples",
    "kernel_array",
    "kernels_cached",
]

#: finding kinds in column 0 of a hit row
KIND_WORKSPACE = 0
KIND_KEEP_OUT = 1
KIND_SELF = 2
#: a hit row: kind, body or pair, zone (-1), sample time, the body's p0 (x, y, z), distance, allowance, key slot
HIT_COLUMNS = 10
#: what the kernels return instead of a count when a configuration holds a non-finite value
NON_FINITE = -1
#: bounds and radii of the broad phases are grown by this much [m] (rounding in the bounds)
CULL_EPS = 1e-9

# evaluation modes of one sample
_FLAG = 0  # is anything hit? stop at the first hit (a pass whose findings are not reported)
_STILL = 1  # a flagged sample without inflation: record findings, and test everything (its flag says "certain")
_LAST = 2  # the densest level: record findings; keys that cannot get an earlier finding are not tested
_FULL = 3  # record findings, test everything (flags exact: the pass-level API)
# what `_evaluate` returns
_CLEAR = 0
_HIT = 1

# int tables: row ranges of `Tables.ints` (columns beyond a table's own are padding)
_I_NODE = 0  # (J, 3) batch_fk node table: parent, kind, q index
_I_BODY = 1  # (B+1, 4): FK node, group (-1: the TCP), moving (0/1), name key
_I_GROUP = 2  # (G, 4): FK node, moving, first and end index into _I_GROUP_BODIES
_I_GROUP_BODIES = 3  # (B, 1): body indices, grouped
_I_PAIR = 4  # (P, 3): body a, body b, name-pair key
_I_GROUP_PAIR = 5  # (GP, 4): group a, group b, first and end index into _I_GROUP_PAIR_PAIRS
_I_GROUP_PAIR_PAIRS = 6  # (P, 1): pair indices, grouped
_I_COUNTS = 7  # (1, 2): number of body names, of name pairs
_I_RANK = 8  # (S, 1): each key slot's place in the order findings are reported in (`Tables.build`)
_N_INT_TABLES = 9
# float tables: row ranges of `Tables.floats`
_F_NODE = 0  # (J, 15) batch_fk node table
_F_BODY = 1  # (B+1, 7): p0, p1 in the joint frame, padded radius
_F_GROUP = 2  # (G, 5): sphere centre in the joint frame, radius around the segments, around the capsules
_F_PAIR = 3  # (P, 2): summed radii, bounding-sphere reach
_F_GROUP_PAIR = 4  # (GP, 1): largest summed radii of its pairs
_F_BOX = 5  # (1+Z, 6): the workspace box, then every keep-out zone: lo xyz, hi xyz
_F_GROUP_REACH = 6  # (G, nq): largest reach of the group's bodies per joint
_F_GROUP_PAIR_REACH = 7  # (GP, nq): largest relative reach of the group pair's pairs per joint
_F_PAIR_REACH = 8  # (P, nq): relative reach of each pair
_F_LIMITS = 9  # (2, nq): lower, upper joint limits
_F_PARAMS = 10  # (1, 4 + L): sweep_resolution_m, check_resolution_rad, joint_limit_margin_rad, L, refinement...
_N_FLOAT_TABLES = 11


# ---------------------------------------------------------------------------------------- tables
@dataclass(frozen=True)
class Tables:
    """What the kernels know of one envelope, packed into two 2-D arrays: `ints` starts with a
    header row (first row, end row) per table — int tables (rows of `ints`), then float tables
    (rows of `floats`) — and every table is a range of rows (see the `_I_*`/`_F_*` ids), so a
    kernel takes a table as a row slice, no copy and no reshape."""

    ints: np.ndarray
    floats: np.ndarray
    n_bodies: int  # B+1, the TCP last
    n_pairs: int
    n_zones: int
    nq: int

    @property
    def hit_capacity(self) -> int:
        """The most findings one check can return: one per (body, workspace), (body, zone), pair."""
        return self.n_bodies * (1 + self.n_zones) + self.n_pairs

    @classmethod
    def build(
        cls,
        *,
        chain: KinematicChain,
        body_joint: Sequence[int],
        body_p0: np.ndarray,
        body_p1: np.ndarray,
        body_group: Sequence[str],
        body_name: Sequence[str],
        report_order: Callable[[int, str, int], Any],
        padded_radii: np.ndarray,
        moving: np.ndarray,
        pairs: np.ndarray,
        pair_radii: np.ndarray,
        pair_sphere_reach: np.ndarray,
        reach: np.ndarray,
        pair_reach: np.ndarray,
        workspace_lo: np.ndarray,
        workspace_hi: np.ndarray,
        keep_out_lo: np.ndarray,
        keep_out_hi: np.ndarray,
        lower: np.ndarray,
        upper: np.ndarray,
        sweep_resolution_m: float,
        check_resolution_rad: float,
        joint_limit_margin_rad: float,
        refinement: Sequence[float],
    ) -> Tables:
        """Tables for B+1 bodies (the TCP point last: its p0 = p1, its group name ignored) on the
        joints of `chain` (a joints-only `KinematicChain`, Pinocchio joint ids; id 0 is fixed to
        the world), P self-collision pairs and Z keep-out zones, as `Envelope` holds them.

        Bodies are grouped by `body_group` (their link) for the broad phases; a group's bodies
        must share one joint and one `moving` flag. Findings are keyed by `body_name` (several
        bodies may share one), pairs by their bodies' names, as `Envelope` keys its violations;
        bodies of one name must be in one group. `report_order(kind, subject, zone)` (subject: the
        body's name, or "a|b" for a pair; zone: index or -1) gives a key that sorts findings of one
        sample time as `Envelope` reports them: the kernels return findings in that order."""
        n_bodies = len(body_joint)
        n_links = n_bodies - 1
        nq = chain.nq
        body_p0 = np.asarray(body_p0, dtype=float).reshape(n_bodies, 3)
        body_p1 = np.asarray(body_p1, dtype=float).reshape(n_bodies, 3)
        padded_radii = np.asarray(padded_radii, dtype=float)
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        n_pairs = len(pairs)
        reach = np.asarray(reach, dtype=float).reshape(nq, n_bodies)
        pair_reach = np.asarray(pair_reach, dtype=float).reshape(nq, n_pairs)

        names = list(dict.fromkeys(body_group[:n_links]))
        group_of = np.array([names.index(body_group[b]) for b in range(n_links)] + [-1], dtype=np.int64)
        group_rows, group_bodies, group_floats = [], [], []
        group_reach = np.zeros((nq, len(names)))
        for g in range(len(names)):
            members = np.flatnonzero(group_of == g)
            joints = {int(body_joint[int(b)]) for b in members}
            flags = {bool(moving[b]) for b in members}
            if len(joints) != 1 or len(flags) != 1:
                raise ValueError(f"bodies of {names[g]!r} must share one joint and one moving flag: {joints}, {flags}")
            ends = np.vstack([body_p0[members], body_p1[members]])
            centre = (ends.min(axis=0) + ends.max(axis=0)) / 2.0
            around_segments = float(np.max(np.linalg.norm(ends - centre, axis=1)))
            around_capsules = float(max(
                max(np.linalg.norm(body_p0[b] - centre), np.linalg.norm(body_p1[b] - centre)) + padded_radii[b]
                for b in members
            ))
            group_rows.append([joints.pop(), int(flags.pop()), len(group_bodies), len(group_bodies) + len(members)])
            group_bodies.extend(int(b) for b in members)
            group_floats.append([*centre, around_segments, around_capsules])
            group_reach[:, g] = reach[:, members].max(axis=1)

        pair_group_keys = [tuple(sorted((int(group_of[a]), int(group_of[b])))) for a, b in pairs]
        keys = list(dict.fromkeys(pair_group_keys))
        gp_rows, gp_pairs, gp_floats = [], [], []
        gp_reach = np.zeros((nq, len(keys)))
        for index, key in enumerate(keys):
            members = [p for p in range(n_pairs) if pair_group_keys[p] == key]
            gp_rows.append([key[0], key[1], len(gp_pairs), len(gp_pairs) + len(members)])
            gp_pairs.extend(members)
            gp_floats.append([float(np.max(np.asarray(pair_radii)[members]))])
            gp_reach[:, index] = pair_reach[:, members].max(axis=1)

        names_in_order = list(dict.fromkeys(body_name))
        body_key = np.array([names_in_order.index(name) for name in body_name], dtype=np.int64)
        for key in range(len(names_in_order)):
            if len({int(group_of[b]) for b in np.flatnonzero(body_key == key)}) != 1:
                raise ValueError(f"bodies named {names_in_order[key]!r} are on several links")
        pair_names = [(int(body_key[a]), int(body_key[b])) for a, b in pairs]
        pair_names_in_order = list(dict.fromkeys(pair_names))
        pair_key = np.array([pair_names_in_order.index(k) for k in pair_names], dtype=np.int64)
        body_ints = np.column_stack([
            np.asarray(body_joint, dtype=np.int64), group_of, np.asarray(moving, dtype=np.int64), body_key,
        ])
        n_zones = len(np.asarray(keep_out_lo).reshape(-1, 3))
        pair_subjects = [f"{names_in_order[a]}|{names_in_order[b]}" for a, b in pair_names_in_order]
        slots = ([(KIND_WORKSPACE, name, -1) for name in names_in_order]
                 + [(KIND_KEEP_OUT, name, zone) for name in names_in_order for zone in range(n_zones)]
                 + [(KIND_SELF, subject, -1) for subject in pair_subjects])
        by_report = sorted(range(len(slots)), key=lambda slot: report_order(*slots[slot]))
        slot_rank = np.empty(len(slots), dtype=np.int64)
        slot_rank[by_report] = np.arange(len(slots))
        node_ints, node_floats = chain.node_tables()
        int_tables = [
            node_ints,
            body_ints,
            np.array(group_rows, dtype=np.int64).reshape(-1, 4),
            np.array(group_bodies, dtype=np.int64).reshape(-1, 1),
            np.column_stack([pairs, pair_key]).reshape(-1, 3),
            np.array(gp_rows, dtype=np.int64).reshape(-1, 4),
            np.array(gp_pairs, dtype=np.int64).reshape(-1, 1),
            np.array([[len(names_in_order), len(pair_names_in_order)]], dtype=np.int64),
            slot_rank.reshape(-1, 1),
        ]
        keep_out_lo = np.asarray(keep_out_lo, dtype=float).reshape(-1, 3)
        keep_out_hi = np.asarray(keep_out_hi, dtype=float).reshape(-1, 3)
        boxes = np.vstack([
            np.concatenate([workspace_lo, workspace_hi])[None],
            np.hstack([keep_out_lo, keep_out_hi]),
        ])
        params = [sweep_resolution_m, check_resolution_rad, joint_limit_margin_rad, len(refinement), *refinement]
        float_tables = [
            node_floats,
            np.hstack([body_p0, body_p1, padded_radii[:, None]]),
            np.array(group_floats, dtype=float).reshape(-1, 5),
            np.column_stack([np.asarray(pair_radii, dtype=float), np.asarray(pair_sphere_reach, dtype=float)]).reshape(-1, 2),
            np.array(gp_floats, dtype=float).reshape(-1, 1),
            boxes,
            group_reach.T,
            gp_reach.T,
            pair_reach.T,
            np.vstack([np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)]),
            np.array(params, dtype=float)[None],
        ]
        assert len(int_tables) == _N_INT_TABLES and len(float_tables) == _N_FLOAT_TABLES
        ints, floats = _pack(int_tables, float_tables)
        return cls(
            ints=ints,
            floats=floats,
            n_bodies=n_bodies,
            n_pairs=n_pairs,
            n_zones=len(keep_out_lo),
            nq=nq,
        )


def _pack(int_tables: list[np.ndarray], float_tables: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(ints, floats): the header rows then the int tables' rows; the float tables' rows. Each
    array as wide as its widest table."""
    n_header = len(int_tables) + len(float_tables)
    int_width = max(2, *(t.shape[1] for t in int_tables))
    float_width = max(t.shape[1] for t in float_tables)
    ints = np.zeros((n_header + sum(len(t) for t in int_tables), int_width), dtype=np.int64)
    floats = np.zeros((sum(len(t) for t in float_tables), float_width), dtype=np.float64)
    row = n_header
    for index, table in enumerate(int_tables):
        ints[index, :2] = (row, row + len(table))
        ints[row:row + len(table), : table.shape[1]] = table
        row += len(table)
    row = 0
    for index, table in enumerate(float_tables):
        ints[len(int_tables) + index, :2] = (row, row + len(table))
        floats[row:row + len(table), : table.shape[1]] = table
        row += len(table)
    return ints, floats


# ---------------------------------------------------------------------------------------- helpers
# Compiled into the entry points below (no signatures of their own; `cache=False`: the entry
# points' cache holds them). Every array a function binds (an argument, a row view, a tuple's
# element) costs an atomic reference-count pair, ~10 ns: the hot helpers take the whole arrays and
# indices rather than rows, and the ones that loop or branch are real calls, not inlined, whose
# counting numba can prune (an inlined body's bindings it often cannot).
_inner = numba.njit(nogil=True, cache=False)
# numba types an int constant passed to a function as a literal and compiles a specialisation of
# the callee for each value (minutes of compile time for `_evaluate`): values passed on are made
# plain with np.int64(...) or float(...), and the tiny table look-ups, called with literal table
# ids, are inlined in numba's IR instead.
_inline = numba.njit(nogil=True, cache=False, inline="always")


@_inline
def _int_table(ints, index):  # pragma: no cover - compiled
    return ints[ints[index, 0]:ints[index, 1]]


@_inline
def _float_table(ints, floats, index):  # pragma: no cover - compiled
    return floats[ints[_N_INT_TABLES + index, 0]:ints[_N_INT_TABLES + index, 1]]


@_inner
def _segment_box_distance(p0x, p0y, p0z, p1x, p1y, p1z, boxes, row, knots):  # pragma: no cover - compiled
    """`geometry.segment_box_distance` for one segment and the box `boxes[row]` (lo xyz, hi
    xyz): the same knots, pieces, minimisers and candidates. `knots`: scratch (at least 8)."""
    p0 = (p0x, p0y, p0z)
    d = (p1x - p0x, p1y - p0y, p1z - p0z)
    lo = (boxes[row, 0], boxes[row, 1], boxes[row, 2])
    hi = (boxes[row, 3], boxes[row, 4], boxes[row, 5])
    knots[0] = 0.0
    knots[1] = 1.0
    for a in range(3):
        if abs(d[a]) > 1e-12:
            knots[2 + a] = min(max((lo[a] - p0[a]) / d[a], 0.0), 1.0)
            knots[5 + a] = min(max((hi[a] - p0[a]) / d[a], 0.0), 1.0)
        else:
            knots[2 + a] = 0.0
            knots[5 + a] = 0.0
    for i in range(1, 8):  # insertion sort (numba's sort costs seconds of compile time)
        value = knots[i]
        j = i - 1
        while j >= 0 and knots[j] > value:
            knots[j + 1] = knots[j]
            j -= 1
        knots[j + 1] = value
    best = np.inf
    for c in range(15):
        if c < 8:
            t = knots[c]
        else:
            start = knots[c - 8]
            end = knots[c - 7]
            half = (start + end) / 2.0
            curvature = 0.0
            pull = 0.0
            for a in range(3):
                middle = p0[a] + half * d[a]
                if middle < lo[a]:
                    curvature += d[a] * d[a]
                    pull += d[a] * (lo[a] - p0[a])
                elif middle > hi[a]:
                    curvature += d[a] * d[a]
                    pull += d[a] * (hi[a] - p0[a])
            if curvature == 0.0:
                t = half
            else:
                t = min(max(pull / curvature, start), end)
        total = 0.0
        for a in range(3):
            x = p0[a] + t * d[a]
            out = x - min(max(x, lo[a]), hi[a])
            total += out * out
        if total < best:
            best = total
    return math.sqrt(best)


@_inline
def _segment_hits_box(tcp, boxes, row, grow):  # pragma: no cover - compiled
    """`geometry.segments_hit_boxes` (the slab test) for the segment tcp[0]–tcp[1] and the box
    `boxes[row]` grown by `grow`."""
    enter = -np.inf
    leave = np.inf
    for a in range(3):
        lo = boxes[row, a] - grow
        hi = boxes[row, 3 + a] + grow
        start = tcp[0, a]
        d = tcp[1, a] - start
        if abs(d) > 1e-12:
            inv = 1.0 / d
            t_a = (lo - start) * inv
            t_b = (hi - start) * inv
            near = min(t_a, t_b)
            far = max(t_a, t_b)
        elif start >= lo and start <= hi:
            near = -np.inf
            far = np.inf
        else:
            near = np.inf
            far = -np.inf
        enter = max(enter, near)
        leave = min(leave, far)
    return enter <= leave and leave >= 0.0 and enter <= 1.0


@_inline
def _clip01(x):  # pragma: no cover - compiled
    return min(max(x, 0.0), 1.0)


@_inline
def _segment_segment_distance(points, ia, ib):  # pragma: no cover - compiled
    """`geometry.segment_segment_distance` for the segments of bodies ia and ib (`points` rows:
    p0 xyz, p1 xyz)."""
    eps = 1e-12
    d1x, d1y, d1z = points[ia, 3] - points[ia, 0], points[ia, 4] - points[ia, 1], points[ia, 5] - points[ia, 2]
    d2x, d2y, d2z = points[ib, 3] - points[ib, 0], points[ib, 4] - points[ib, 1], points[ib, 5] - points[ib, 2]
    rx, ry, rz = points[ia, 0] - points[ib, 0], points[ia, 1] - points[ib, 1], points[ia, 2] - points[ib, 2]
    a = d1x * d1x + d1y * d1y + d1z * d1z
    e = d2x * d2x + d2y * d2y + d2z * d2z
    f = d2x * rx + d2y * ry + d2z * rz
    c = d1x * rx + d1y * ry + d1z * rz
    b = d1x * d2x + d1y * d2y + d1z * d2z
    a_safe = max(a, eps)
    e_safe = max(e, eps)
    denom = a * e - b * b
    if denom > eps * max(a * e, eps):
        s = _clip01((b * f - c * e) / max(denom, eps))
    else:
        s = 0.0
    t = (b * s + f) / e_safe
    if t < 0.0:
        s = _clip01(-c / a_safe)
    elif t > 1.0:
        s = _clip01((b - c) / a_safe)
    t = _clip01(t)
    p_is_point = a <= eps
    q_is_point = e <= eps
    if p_is_point:
        s = 0.0
        t = _clip01(f / e_safe)
    if q_is_point:
        t = 0.0
        if not p_is_point:
            s = _clip01(-c / a_safe)
    x = (points[ia, 0] + s * d1x) - (points[ib, 0] + t * d2x)
    y = (points[ia, 1] + s * d1y) - (points[ib, 1] + t * d2y)
    z = (points[ia, 2] + s * d1z) - (points[ib, 2] + t * d2z)
    return math.sqrt(x * x + y * y + z * z)


@_inline
def _transform(poses, j, x, y, z):  # pragma: no cover - compiled
    """R · (x, y, z) + t for the homogeneous pose `poses[j]`."""
    return (poses[j, 0, 0] * x + poses[j, 0, 1] * y + poses[j, 0, 2] * z + poses[j, 0, 3],
            poses[j, 1, 0] * x + poses[j, 1, 1] * y + poses[j, 1, 2] * z + poses[j, 1, 3],
            poses[j, 2, 0] * x + poses[j, 2, 1] * y + poses[j, 2, 2] * z + poses[j, 2, 3])


@_inner
def _place_group(g, group, group_bodies, body_ints, body_floats, poses, points, placed):  # pragma: no cover - compiled
    """World end points of group g's bodies into points[b] (p0 xyz, p1 xyz, midpoint xyz), once
    per sample."""
    if placed[g]:
        return
    for m in range(group[g, 2], group[g, 3]):
        b = group_bodies[m, 0]
        j = body_ints[b, 0]
        points[b, 0], points[b, 1], points[b, 2] = _transform(poses, j, body_floats[b, 0], body_floats[b, 1],
                                                              body_floats[b, 2])
        points[b, 3], points[b, 4], points[b, 5] = _transform(poses, j, body_floats[b, 3], body_floats[b, 4],
                                                              body_floats[b, 5])
        points[b, 6] = (points[b, 0] + points[b, 3]) / 2.0
        points[b, 7] = (points[b, 1] + points[b, 4]) / 2.0
        points[b, 8] = (points[b, 2] + points[b, 5]) / 2.0
    placed[g] = True


@_inline
def _write_row(row, kind, index, zone, time, points, b, distance, allowance, slot):  # pragma: no cover - compiled
    row[0] = kind
    row[1] = index
    row[2] = zone
    row[3] = time
    row[4] = points[b, 0]
    row[5] = points[b, 1]
    row[6] = points[b, 2]
    row[7] = distance
    row[8] = allowance
    row[9] = slot


@_inline
def _outside_box(points, b, radius, boxes, row):  # pragma: no cover - compiled
    """Whether body b's capsule (`points[b]`: p0 xyz, p1 xyz) with `radius` leaves the box
    `boxes[row]` (the numpy pass: its bounds not inside the box)."""
    for a in range(3):
        low = min(points[b, a], points[b, 3 + a]) - radius
        high = max(points[b, a], points[b, 3 + a]) + radius
        if not (low >= boxes[row, a]) or not (high <= boxes[row, 3 + a]):
            return True
    return False


@_inline
def _boxes_apart(points, ia, ib, allowance):  # pragma: no cover - compiled
    """Whether the bounds of bodies ia's and ib's segments, grown by `allowance`, miss each
    other: then the segments are farther apart than it."""
    for a in range(3):
        if (min(points[ia, a], points[ia, 3 + a]) - allowance > max(points[ib, a], points[ib, 3 + a])
                or min(points[ib, a], points[ib, 3 + a]) - allowance > max(points[ia, a], points[ia, 3 + a])):
            return True
    return False


@_inline
def _bounds_overlap(points, b, radius, boxes, row):  # pragma: no cover - compiled
    for a in range(3):
        low = min(points[b, a], points[b, 3 + a]) - radius
        high = max(points[b, a], points[b, 3 + a]) + radius
        if not (low <= boxes[row, 3 + a]) or not (high >= boxes[row, a]):
            return False
    return True


# ---------------------------------------------------------------------------------------- findings
# Findings are keyed as `Envelope` keys its violations: by body *name* (several fitted capsules of
# one link share their link's name) with the workspace or with a zone, and by the pair of names.
# Per key the earliest finding is kept — within a pass the first sample that has one (at it, the
# lowest body or pair index); across passes, a later pass replaces it only with a strictly
# earlier one — as `Envelope` merges its passes' findings.
#
# state: (found (S,), time (S,), rows (S, HIT_COLUMNS), n_found (1,)) over the key slots: workspace
# per name [0, K), keep-out per name and zone [K, K + K·Z), self-collision per name pair after.


@_inner
def _new_state(n_keys, n_zones, n_pair_keys):  # pragma: no cover - compiled
    slots = n_keys * (1 + n_zones) + n_pair_keys
    return (np.zeros(slots, dtype=np.bool_), np.empty(slots), np.empty((slots, HIT_COLUMNS)),
            np.zeros(1, dtype=np.int64))


@_inner
def _improves(state, slot, time):  # pragma: no cover - compiled
    """Whether a finding at `time` would be kept for `slot` (none yet, or a later one)."""
    return not state[0][slot] or time < state[1][slot]


@_inner
def _offer(state, slot, kind, index, zone, time, points, b, distance, allowance):  # pragma: no cover - compiled
    found, times, rows, n_found = state
    if found[slot] and not time < times[slot]:
        return
    if not found[slot]:
        found[slot] = True
        n_found[0] += 1
    times[slot] = time
    _write_row(rows[slot], kind, index, zone, time, points, b, distance, allowance, float(slot))


@_inner
def _output(state, hits, ints):  # pragma: no cover - compiled
    """The kept findings into `hits` in the order they are reported (time, then `_I_RANK`); their count."""
    found, times, rows, _ = state
    rank = _int_table(ints, _I_RANK)
    order = np.empty(found.shape[0], dtype=np.int64)
    count = 0
    for slot in range(found.shape[0]):
        if not found[slot]:
            continue
        at = count  # insertion sort: few findings
        while at > 0 and (times[order[at - 1]] > times[slot]
                          or (times[order[at - 1]] == times[slot] and rank[order[at - 1], 0] > rank[slot, 0])):
            order[at] = order[at - 1]
            at -= 1
        order[at] = slot
        count += 1
    for n in range(count):
        hits[n] = rows[order[n]]
    return count


# ---------------------------------------------------------------------------------------- one sample
@_inner
def _evaluate(ints, floats, q, time, sample, body_inflation, group_bound, pair_group_bound,
              pair_inflation_row, lazy, n_pass, tcp, has_previous, mode, poses, points, placed,
              scratch, state, tau, gap, coherence):  # pragma: no cover - compiled
    """Every check of one sample. `body_inflation` (B+1,), group and group-pair inflation
    bounds, the pair inflations from `pair_inflation_row` (P,), or its one value for every pair
    when it holds one, or, when it is empty, from the path (`lazy`, see `_lazy_pair_inflation`).
    `tcp` (2, 3): row 1 receives this sample's TCP, row 0 holds the previous sample's (used when
    `has_previous`). `scratch` (1+G, 8). `tau`, `gap`, `coherence`: the sample's path parameter,
    half the larger target gap next to it, and (skip_lo, skip_hi, skip_gap, pair_rate (P,): the
    pairs' skip intervals and their relative-motion rates per unit of path parameter, -1 until
    computed; rates (nq,): `_joint_rates`), empty arrays: no path. Returns _CLEAR or _HIT, or
    NON_FINITE (nothing else done)."""
    node_ints = _int_table(ints, _I_NODE)
    node_floats = _float_table(ints, floats, _F_NODE)
    if not fk_into(q, node_ints, node_floats, poses):
        return NON_FINITE
    pair_cum, pair_valid, steps, pair_reach, k, alpha, at_end = lazy
    body_ints = _int_table(ints, _I_BODY)
    group = _int_table(ints, _I_GROUP)
    group_bodies = _int_table(ints, _I_GROUP_BODIES)
    body_floats = _float_table(ints, floats, _F_BODY)
    group_floats = _float_table(ints, floats, _F_GROUP)
    boxes = _float_table(ints, floats, _F_BOX)
    n_keys, _ = _key_counts(ints)
    n_bodies = body_ints.shape[0]
    tcp_body = n_bodies - 1
    n_groups = group.shape[0]
    n_zones = boxes.shape[0] - 1
    record = mode != _FLAG
    knots = scratch[0]
    skip_settled = mode == _LAST  # keys whose finding this sample cannot improve
    flagged = False
    # floats: numba gives int constants literal types, and a specialisation of `_write_row` each
    workspace, keep_out, self_collision, no_zone = float(KIND_WORKSPACE), float(KIND_KEEP_OUT), float(KIND_SELF), -1.0

    # the TCP point (body B) and the group spheres' centres
    x, y, z = _transform(poses, body_ints[tcp_body, 0], body_floats[tcp_body, 0], body_floats[tcp_body, 1],
                         body_floats[tcp_body, 2])
    points[tcp_body, 0] = points[tcp_body, 3] = tcp[1, 0] = x
    points[tcp_body, 1] = points[tcp_body, 4] = tcp[1, 1] = y
    points[tcp_body, 2] = points[tcp_body, 5] = tcp[1, 2] = z
    # the group spheres' centres: scratch rows 1..G (row 0 is the knots' scratch)
    for g in range(n_groups):
        placed[g] = False
        scratch[1 + g, 0], scratch[1 + g, 1], scratch[1 + g, 2] = _transform(
            poses, group[g, 0], group_floats[g, 0], group_floats[g, 1], group_floats[g, 2])

    # ---- workspace (boxes row 0): every moving capsule and the TCP entirely inside the box
    for g in range(n_groups + 1):
        if g < n_groups:
            if group[g, 1] == 0:
                continue
            grown = group_floats[g, 4] + group_bound[g] + CULL_EPS
            inside = True
            for a in range(3):
                if not (scratch[1 + g, a] - grown >= boxes[0, a]) or not (scratch[1 + g, a] + grown <= boxes[0, 3 + a]):
                    inside = False
            if inside:
                continue
            _place_group(g, group, group_bodies, body_ints, body_floats, poses, points, placed)
            first, end = group[g, 2], group[g, 3]
        else:
            first, end = -1, 0  # the TCP alone
        for m in range(first, end):
            b = group_bodies[m, 0] if m >= 0 else tcp_body
            slot = body_ints[b, 3]
            if skip_settled and not _improves(state, slot, time):
                continue
            radius = body_inflation[b] + body_floats[b, 6]
            if not _outside_box(points, b, radius, boxes, 0):
                continue
            flagged = True
            if not record:
                return _HIT
            _offer(state, slot, workspace, b, no_zone, time, points, b, 0.0, radius)

    # ---- keep-out zones: bounds that overlap a zone, confirmed exactly
    for zone in range(n_zones):
        row = 1 + zone  # of boxes
        for g in range(n_groups + 1):
            if g < n_groups:
                if group[g, 1] == 0:
                    continue
                grown = group_floats[g, 4] + group_bound[g] + CULL_EPS
                apart = False
                for a in range(3):
                    if scratch[1 + g, a] + grown < boxes[row, a] or scratch[1 + g, a] - grown > boxes[row, 3 + a]:
                        apart = True
                if apart:
                    continue
                _place_group(g, group, group_bodies, body_ints, body_floats, poses, points, placed)
                first, end = group[g, 2], group[g, 3]
            else:
                first, end = -1, 0
            for m in range(first, end):
                b = group_bodies[m, 0] if m >= 0 else tcp_body
                slot = n_keys + body_ints[b, 3] * n_zones + zone
                if skip_settled and not _improves(state, slot, time):
                    continue
                radius = body_inflation[b] + body_floats[b, 6]
                overlap = _bounds_overlap(points, b, radius, boxes, row)
                segment = b == tcp_body and has_previous
                if segment and not overlap:  # the TCP's straight segment from the previous sample
                    overlap = True
                    for a in range(3):
                        low = min(tcp[0, a], tcp[1, a]) - radius
                        high = max(tcp[0, a], tcp[1, a]) + radius
                        if not (low <= boxes[row, 3 + a]) or not (high >= boxes[row, a]):
                            overlap = False
                if not overlap:
                    continue
                distance = _segment_box_distance(points[b, 0], points[b, 1], points[b, 2], points[b, 3], points[b, 4],
                                                 points[b, 5], boxes, row, knots)
                hit = distance <= radius
                if not hit and segment:
                    hit = _segment_hits_box(tcp, boxes, row, radius)
                if not hit:
                    continue
                flagged = True
                if not record:
                    return _HIT
                _offer(state, slot, keep_out, b, float(zone), time, points, b, distance, radius)

    # ---- self-collision: capsule pairs closer than their summed radii plus inflation
    pairs = _int_table(ints, _I_PAIR)
    group_pair = _int_table(ints, _I_GROUP_PAIR)
    group_pair_pairs = _int_table(ints, _I_GROUP_PAIR_PAIRS)
    pair_floats = _float_table(ints, floats, _F_PAIR)
    group_pair_floats = _float_table(ints, floats, _F_GROUP_PAIR)
    pair_slots = n_keys * (1 + n_zones)
    skip_lo, skip_hi, skip_gap, pair_rate, rates = coherence
    skipping = skip_lo.shape[0] > 0
    for gp in range(group_pair.shape[0]):
        ga = group_pair[gp, 0]
        gb = group_pair[gp, 1]
        dx = scratch[1 + ga, 0] - scratch[1 + gb, 0]
        dy = scratch[1 + ga, 1] - scratch[1 + gb, 1]
        dz = scratch[1 + ga, 2] - scratch[1 + gb, 2]
        reach = group_floats[ga, 3] + group_floats[gb, 3] + group_pair_floats[gp, 0] + pair_group_bound[gp] + CULL_EPS
        if dx * dx + dy * dy + dz * dz >= reach * reach:
            continue
        bound = pair_group_bound[gp] + CULL_EPS
        both_placed = False
        for m in range(group_pair[gp, 2], group_pair[gp, 3]):
            p = group_pair_pairs[m, 0]
            if skipping and skip_lo[p] <= tau <= skip_hi[p] and gap <= skip_gap[p]:
                continue
            if not both_placed:  # (a helper's array arguments cost reference counting: once per group pair)
                _place_group(ga, group, group_bodies, body_ints, body_floats, poses, points, placed)
                _place_group(gb, group, group_bodies, body_ints, body_floats, poses, points, placed)
                both_placed = True
            ia = pairs[p, 0]
            ib = pairs[p, 1]
            # the numpy pass's broad phase: bounding spheres (centre, half length + radius + inflation),
            # first with the group pair's inflation bound (the pair's own is computed only if that passes)
            gx = points[ia, 6] - points[ib, 6]
            gy = points[ia, 7] - points[ib, 7]
            gz = points[ia, 8] - points[ib, 8]
            rate = 0.0
            if skipping:  # the pair's own inflation bound: its rate times the gap (cached per path)
                rate = pair_rate[p]
                if rate < 0.0:
                    rate = 0.0
                    for i in range(rates.shape[0]):
                        rate += rates[i] * pair_reach[p, i]
                    pair_rate[p] = rate
                reach_bound = pair_floats[p, 1] + rate * gap + CULL_EPS
            else:
                reach_bound = pair_floats[p, 1] + bound
            if gx * gx + gy * gy + gz * gz >= reach_bound * reach_bound:
                if skipping:  # apart by `margin`: the centres cannot close it within margin / rate of path
                    margin = math.sqrt(gx * gx + gy * gy + gz * gz) - reach_bound
                    width = margin / rate if rate > 0.0 else np.inf
                    skip_lo[p] = tau - width
                    skip_hi[p] = tau + width
                    skip_gap[p] = gap
                continue
            slot = pair_slots + pairs[p, 2]
            if skip_settled and not _improves(state, slot, time):
                continue
            centre_distance = math.sqrt(gx * gx + gy * gy + gz * gz)
            if skipping:
                # on a path, the allowance is bounded before it is known: far enough apart by the
                # bound, the pair is not touching whatever its own inflation (and stays so a while)
                allowance = pair_floats[p, 0] + rate * gap + CULL_EPS
                if _boxes_apart(points, ia, ib, allowance):
                    continue
                distance = _segment_segment_distance(points, ia, ib)
                if distance >= allowance:
                    width = (distance - allowance) / rate if rate > 0.0 else np.inf
                    skip_lo[p] = tau - width
                    skip_hi[p] = tau + width
                    skip_gap[p] = gap
                    continue
                if pair_inflation_row.shape[0] == 1:  # one value for every pair (a still sample's: none)
                    inflation = pair_inflation_row[0]
                else:
                    inflation = _lazy_pair_inflation(pair_cum, pair_valid, steps, pair_reach, k, alpha, at_end,
                                                     n_pass, sample, p)
            else:
                inflation = pair_inflation_row[p] if pair_inflation_row.shape[0] > 1 else pair_inflation_row[0]
                if _boxes_apart(points, ia, ib, pair_floats[p, 0] + inflation):
                    continue
                distance = _segment_segment_distance(points, ia, ib)
            # the numpy pass's own tests, with the pair's own inflation
            if not (centre_distance < pair_floats[p, 1] + inflation):
                continue
            allowance = pair_floats[p, 0] + inflation
            if not (distance < allowance):
                continue
            flagged = True
            if not record:
                return _HIT
            _offer(state, slot, self_collision, p, no_zone, time, points, ia, distance, allowance)
    return _HIT if flagged else _CLEAR


# ---------------------------------------------------------------------------------------- the path
@_inline
def _pair_at(pair_cum, pair_valid, steps, pair_reach, k, alpha, at_end, n, p):  # pragma: no cover - compiled
    """`at(path.pairs)[n, p]`, extending pair p's cumulative bound (cumsum of steps @ pair_reach)."""
    last = pair_cum.shape[0] - 1
    row = last if at_end[n] else k[n] + 1
    valid = pair_valid[p]
    while valid < row:
        bound = 0.0
        for i in range(steps.shape[1]):
            bound += steps[valid, i] * pair_reach[p, i]
        pair_cum[valid + 1, p] = pair_cum[valid, p] + bound
        valid += 1
    pair_valid[p] = valid
    if at_end[n]:
        return pair_cum[last, p]
    start = pair_cum[k[n], p]
    return start + alpha[n] * (pair_cum[k[n] + 1, p] - start)


@_inner
def _lazy_pair_inflation(pair_cum, pair_valid, steps, pair_reach, k, alpha, at_end, n_pass, n, p):  # pragma: no cover - compiled
    """Pair p's inflation at sample n of the current pass, as `_half_neighbour_bound(at(path.pairs))`
    gives it, computing the cumulative relative-motion bound of pair p only as far as needed:
    pair_cum (K, P) with pair_valid (P,) rows computed, from steps (K-1, nq) and pair_reach (P, nq);
    the pass's samples at k (N,), alpha (N,), at_end (N,)."""
    if n_pass == 1:
        return 0.0
    first = n - 1 if n > 0 else 0
    end = n + 1 if n < n_pass - 1 else n_pass - 1
    last = pair_cum.shape[0] - 1
    row = last if at_end[end] else k[end] + 1  # the samples are in path order: the last one needs the most rows
    valid = pair_valid[p]
    while valid < row:
        bound = 0.0
        for i in range(steps.shape[1]):
            bound += steps[valid, i] * pair_reach[p, i]
        pair_cum[valid + 1, p] = pair_cum[valid, p] + bound
        valid += 1
    pair_valid[p] = valid
    v0 = 0.0
    v1 = 0.0
    v2 = 0.0
    for j in range(first, end + 1):
        if at_end[j]:
            value = pair_cum[last, p]
        else:
            start = pair_cum[k[j], p]
            value = start + alpha[j] * (pair_cum[k[j] + 1, p] - start)
        if j == first:
            v0 = value
        elif j == first + 1:
            v1 = value
        else:
            v2 = value
    if n == 0 or n == n_pass - 1:  # the edges: the one interval next to them, twice
        return max(v1 - v0, v1 - v0) / 2.0
    return max(v1 - v0, v2 - v1) / 2.0


@_inner
def _unit_targets(start, end, spacing):  # pragma: no cover - compiled
    """`envelope._unit_targets` (numpy's linspace, operation for operation)."""
    n_intervals = max(1, math.ceil((end - start) / spacing - 1e-12)) if end > start else 1
    out = np.empty(n_intervals + 1)
    delta = end - start
    step = delta / n_intervals
    for i in range(n_intervals + 1):
        if step == 0.0:
            out[i] = (float(i) / n_intervals) * delta + start
        else:
            out[i] = float(i) * step + start
    out[n_intervals] = end
    return out


@_inner
def _search_left(cum, target):  # pragma: no cover - compiled
    """`np.searchsorted(cum, target, side="left")` for a non-decreasing `cum`."""
    lo = 0
    hi = cum.shape[0]
    while lo < hi:
        mid = (lo + hi) // 2
        if cum[mid] < target:
            lo = mid + 1
        else:
            hi = mid
    return lo


@_inline
def _half_neighbour(values, n, column):  # pragma: no cover - compiled
    """`_half_neighbour_bound` of `values` (N, C) at row n, column `column`."""
    count = values.shape[0]
    if count == 1:
        return 0.0
    before = values[n, column] - values[n - 1, column] if n > 0 else values[1, column] - values[0, column]
    after = values[n + 1, column] - values[n, column] if n < count - 1 else values[count - 1, column] - values[count - 2, column]
    return max(before, after) / 2.0


@_inner
def _joint_rates(steps, cost):  # pragma: no cover - compiled
    """Per joint, the largest |Δq| per unit of path parameter over the segments: any motion
    bound accumulated at rate Σ_i reach_i · |Δq_i| / cost grows at most Σ_i rate_i · reach_i per unit."""
    rates = np.zeros(steps.shape[1])
    for s in range(steps.shape[0]):
        if cost[s] > 0.0:
            for i in range(steps.shape[1]):
                rates[i] = max(rates[i], steps[s, i] / cost[s])
    return rates


@_inline
def _interpolate(times, positions, k, alpha, at_end, n, q):  # pragma: no cover - compiled
    """Sample n's configuration into q and its time (`at(path.positions)`, `at(path.times)`)."""
    last = positions.shape[0] - 1
    kn = k[n]
    if at_end[n]:
        for i in range(q.shape[0]):
            q[i] = positions[last, i]
        return times[last]
    for i in range(q.shape[0]):
        q[i] = positions[kn, i] + alpha[n] * (positions[kn + 1, i] - positions[kn, i])
    return times[kn] + alpha[n] * (times[kn + 1] - times[kn])


@_inner
def _check_path(times, positions, seg_bound, first_only, ints, floats):  # pragma: no cover - compiled
    """`Envelope._check_geometry` from the waypoints `positions` (K, nq) at `times` and the
    per-segment body motion bounds `seg_bound` (K-1, B+1) = |Δq| @ reach (numpy's product, so
    the samples are numpy's to the bit). Returns (state, samples checked or NON_FINITE, the
    first pass's TCP positions)."""
    n_way = positions.shape[0]
    nq = positions.shape[1]
    n_bodies = seg_bound.shape[1]
    params = _float_table(ints, floats, _F_PARAMS)[0]
    sweep = params[0]
    check_res = params[1]
    n_levels = int(params[3])
    group = _int_table(ints, _I_GROUP)
    group_pair = _int_table(ints, _I_GROUP_PAIR)
    pair_reach = _float_table(ints, floats, _F_PAIR_REACH)
    group_reach = _float_table(ints, floats, _F_GROUP_REACH)
    group_pair_reach = _float_table(ints, floats, _F_GROUP_PAIR_REACH)
    boxes = _float_table(ints, floats, _F_BOX)
    n_pairs = pair_reach.shape[0]
    n_groups = group.shape[0]
    n_group_pairs = group_pair.shape[0]
    n_keys, n_pair_keys = _key_counts(ints)
    state = _new_state(n_keys, boxes.shape[0] - 1, n_pair_keys)
    n_found = state[3]

    # ---- the path parameter (`Envelope._path_parameter`)
    steps = np.empty((n_way - 1, nq))
    cost = np.empty(n_way - 1)
    cum = np.empty(n_way)
    body_cum = np.empty((n_way, n_bodies))
    cum[0] = 0.0
    for b in range(n_bodies):
        body_cum[0, b] = 0.0
    for s in range(n_way - 1):
        largest_step = -np.inf
        for i in range(nq):
            steps[s, i] = abs(positions[s + 1, i] - positions[s, i])
            largest_step = max(largest_step, steps[s, i])
        largest_bound = -np.inf
        for b in range(n_bodies):
            largest_bound = max(largest_bound, seg_bound[s, b])
            body_cum[s + 1, b] = body_cum[s, b] + seg_bound[s, b]
        cost[s] = max(largest_bound / sweep, largest_step / check_res)
        cum[s + 1] = cum[s] + cost[s]
    total = cum[n_way - 1]
    if not math.isfinite(total):
        return state, NON_FINITE, np.empty((0, 3))
    pair_cum = np.empty((n_way, n_pairs))
    pair_cum[0, :] = 0.0
    pair_valid = np.zeros(n_pairs, dtype=np.int64)

    # inflation bounds per unit of path parameter, for the broad phases
    rates = _joint_rates(steps, cost)
    group_rate = np.zeros(n_groups)
    for g in range(n_groups):
        for i in range(nq):
            group_rate[g] += rates[i] * group_reach[g, i]
        group_rate[g] = min(group_rate[g], sweep)
    group_pair_rate = np.zeros(n_group_pairs)
    for gp in range(n_group_pairs):
        for i in range(nq):
            group_pair_rate[gp] += rates[i] * group_pair_reach[gp, i]

    # ---- scratch
    poses = np.empty((_int_table(ints, _I_NODE).shape[0], 4, 4))
    points = np.empty((n_bodies, 9))
    placed = np.zeros(n_groups, dtype=np.bool_)
    still_rows = np.zeros(1)  # one value: every pair's inflation, none
    still_bodies = np.zeros(n_bodies)
    still_groups = np.zeros(n_groups)
    still_group_pairs = np.zeros(n_group_pairs)
    no_rows = np.empty(0)
    group_bound = np.empty(n_groups)
    pair_group_bound = np.empty(n_group_pairs)
    tcp = np.empty((2, 3))
    q = np.empty(nq)
    scratch = np.empty((1 + n_groups, 8))
    first_tcp = np.empty((0, 3))
    still_mode = np.int64(_STILL)  # not a literal (see `_inline`)
    no_previous = still_mode < 0  # False, not a literal (see `_inline`): a still sample has no segment
    # pairs found apart by a margin need no test while the path cannot have closed it (`_evaluate`)
    skip_hi = np.empty(n_pairs)
    skip_hi[:] = -np.inf
    pair_rate = np.empty(n_pairs)
    pair_rate[:] = -1.0
    coherence = (np.zeros(n_pairs), skip_hi, np.zeros(n_pairs), pair_rate, rates)
    checked = 0

    # ranges to check, depth first: (level, start, end); the whole path at level 0 first
    stack_level = np.empty(16, dtype=np.int64)
    stack_start = np.empty(16)
    stack_end = np.empty(16)
    stack_level[0] = 0
    stack_start[0] = 0.0
    stack_end[0] = total
    depth = 1
    while depth > 0:
        depth -= 1
        level = stack_level[depth]
        targets = _unit_targets(stack_start[depth], stack_end[depth], params[4 + level])
        n_pass = targets.shape[0]
        last_level = level == n_levels - 1
        # the samples (`Envelope._samples_at`)
        k = np.empty(n_pass, dtype=np.int64)
        alpha = np.empty(n_pass)
        at_end = np.empty(n_pass, dtype=np.bool_)
        body_at = np.empty((n_pass, n_bodies))
        for n in range(n_pass):
            kn = min(max(_search_left(cum, targets[n]) - 1, 0), n_way - 2)
            span = cum[kn + 1] - cum[kn]
            a = _clip01((targets[n] - cum[kn]) / span) if span > 0 else 0.0
            k[n] = kn
            alpha[n] = a
            at_end[n] = targets[n] >= cum[n_way - 1]
            for b in range(n_bodies):
                if at_end[n]:
                    body_at[n, b] = body_cum[n_way - 1, b]
                else:
                    body_at[n, b] = body_cum[kn, b] + a * (body_cum[kn + 1, b] - body_cum[kn, b])
        lazy = (pair_cum, pair_valid, steps, pair_reach, k, alpha, at_end)
        body_inflation = np.empty(n_bodies)
        flagged = np.zeros(n_pass, dtype=np.bool_)
        if level == 0:
            first_tcp = np.empty((n_pass, 3))
        mode = np.int64(_LAST) if last_level else np.int64(_FLAG)
        checked += n_pass
        for n in range(n_pass):
            time = _interpolate(times, positions, k, alpha, at_end, n, q)
            for b in range(n_bodies):
                body_inflation[b] = _half_neighbour(body_at, n, b)
            if n_pass == 1:
                gap = 0.0
            else:
                before = targets[n] - targets[n - 1] if n > 0 else targets[1] - targets[0]
                after = targets[n + 1] - targets[n] if n < n_pass - 1 else before
                gap = max(before, after) / 2.0
            for g in range(n_groups):
                group_bound[g] = group_rate[g] * gap
            for gp in range(n_group_pairs):
                pair_group_bound[gp] = group_pair_rate[gp] * gap
            for a in range(3):
                tcp[0, a] = tcp[1, a]
            outcome = _evaluate(ints, floats, q, time, n, body_inflation, group_bound, pair_group_bound, no_rows,
                                lazy, n_pass, tcp, n > 0, mode, poses, points, placed, scratch, state, targets[n],
                                gap, coherence)
            if outcome == NON_FINITE:
                return state, NON_FINITE, first_tcp
            if level == 0:
                for a in range(3):
                    first_tcp[n, a] = tcp[1, a]
            flagged[n] = outcome == _HIT
        if last_level:
            if first_only and n_found[0] > 0:
                return state, checked, first_tcp
            continue
        # flagged samples without any allowance: a finding as they stand (`Envelope._refine`)
        certain = np.zeros(n_pass, dtype=np.bool_)
        for n in range(n_pass):
            if not flagged[n]:
                continue
            checked += 1
            time = _interpolate(times, positions, k, alpha, at_end, n, q)
            outcome = _evaluate(ints, floats, q, time, n, still_bodies, still_groups, still_group_pairs, still_rows,
                                lazy, n_pass, tcp, no_previous, still_mode, poses, points, placed, scratch, state, targets[n],
                                0.0, coherence)
            certain[n] = outcome == _HIT
        if first_only and n_found[0] > 0:
            return state, checked, first_tcp
        # ranges around the other flagged samples (`_merged_ranges`), pushed so the first is checked first
        n_ranges = 0
        starts = np.empty(n_pass)
        ends = np.empty(n_pass)
        for n in range(n_pass):
            if not flagged[n] or certain[n]:
                continue
            start = targets[max(n - 1, 0)]
            end = targets[min(n + 1, n_pass - 1)]
            if n_ranges > 0 and start <= ends[n_ranges - 1]:
                ends[n_ranges - 1] = max(ends[n_ranges - 1], end)
            else:
                starts[n_ranges] = start
                ends[n_ranges] = end
                n_ranges += 1
        if depth + n_ranges > stack_level.shape[0]:
            size = 2 * (depth + n_ranges)
            grown_level = np.empty(size, dtype=np.int64)
            grown_start = np.empty(size)
            grown_end = np.empty(size)
            grown_level[:depth] = stack_level[:depth]
            grown_start[:depth] = stack_start[:depth]
            grown_end[:depth] = stack_end[:depth]
            stack_level, stack_start, stack_end = grown_level, grown_start, grown_end
        for r in range(n_ranges - 1, -1, -1):
            stack_level[depth] = level + 1
            stack_start[depth] = starts[r]
            stack_end[depth] = ends[r]
            depth += 1
    return state, checked, first_tcp


@_inner
def _limit_status(positions, ints, floats):  # pragma: no cover - compiled
    """0: every waypoint inside the joint limits and their margin; 1: some within the margin only
    (a soft finding); 2: some outside a limit (`waypoints.check_joint_limits` says which)."""
    limits = _float_table(ints, floats, _F_LIMITS)
    margin = _float_table(ints, floats, _F_PARAMS)[0, 2]
    status = 0
    for k in range(positions.shape[0]):
        for j in range(positions.shape[1]):
            value = positions[k, j]
            if value < limits[0, j] or value > limits[1, j]:
                return 2
            if margin > 0 and (value < limits[0, j] + margin or value > limits[1, j] - margin):
                status = 1
    return status


@_inline
def _key_counts(ints):  # pragma: no cover - compiled
    counts = _int_table(ints, _I_COUNTS)
    return counts[0, 0], counts[0, 1]


# ---------------------------------------------------------------------------------------- entry points
def _check_path_entry(times, positions, seg_bound, first_only, ints, floats, hits):  # pragma: no cover - compiled
    """(joint-limit status, findings count or NON_FINITE, samples checked, first pass's TCP
    positions). With `first_only`, geometry is not checked when a waypoint is outside a limit."""
    status = _limit_status(positions, ints, floats)
    if first_only and status == 2:
        return status, 0, 0, np.empty((0, 3))
    state, checked, tcp = _check_path(times, positions, seg_bound, first_only, ints, floats)
    if checked == NON_FINITE:
        return status, NON_FINITE, 0, tcp
    return status, _output(state, hits, ints), checked, tcp


def _check_samples_entry(times, positions, inflation, pair_inflation, segments, ints, floats, flags, tcp_out,
                         hits):  # pragma: no cover - compiled
    """One pass over given samples (`Envelope._geometry_pass`): every sample's flag into `flags`,
    its TCP into `tcp_out`, the findings into `hits`. Returns their count or NON_FINITE.
    `segments`: the TCP's straight segment from the sample before counts too."""
    n_samples = positions.shape[0]
    n_bodies = inflation.shape[1]
    group = _int_table(ints, _I_GROUP)
    group_bodies = _int_table(ints, _I_GROUP_BODIES)
    group_pair = _int_table(ints, _I_GROUP_PAIR)
    group_pair_pairs = _int_table(ints, _I_GROUP_PAIR_PAIRS)
    boxes = _float_table(ints, floats, _F_BOX)
    n_groups = group.shape[0]
    n_group_pairs = group_pair.shape[0]
    poses = np.empty((_int_table(ints, _I_NODE).shape[0], 4, 4))
    points = np.empty((n_bodies, 9))
    placed = np.zeros(n_groups, dtype=np.bool_)
    n_keys, n_pair_keys = _key_counts(ints)
    state = _new_state(n_keys, boxes.shape[0] - 1, n_pair_keys)
    group_bound = np.empty(n_groups)
    pair_group_bound = np.empty(n_group_pairs)
    tcp = np.empty((2, 3))
    scratch = np.empty((1 + n_groups, 8))
    index = np.empty(0, dtype=np.int64)
    unused_lazy = (points, index, points, points, index, tcp[0], placed)  # pair inflations are given: not read
    nothing = np.empty(0)
    no_coherence = (nothing, nothing, nothing, nothing, nothing)
    mode = np.int64(_FULL)  # not a literal (see `_inline`)
    for n in range(n_samples):
        for g in range(n_groups):
            largest = 0.0
            for m in range(group[g, 2], group[g, 3]):
                largest = max(largest, inflation[n, group_bodies[m, 0]])
            group_bound[g] = largest
        for gp in range(n_group_pairs):
            largest = 0.0
            for m in range(group_pair[gp, 2], group_pair[gp, 3]):
                largest = max(largest, pair_inflation[n, group_pair_pairs[m, 0]])
            pair_group_bound[gp] = largest
        for a in range(3):
            tcp[0, a] = tcp[1, a]
        row = pair_inflation[n] if pair_inflation.shape[1] > 1 else pair_inflation[n, :1]
        outcome = _evaluate(ints, floats, positions[n], times[n], n, inflation[n], group_bound, pair_group_bound,
                            row, unused_lazy, n_samples, tcp, segments and n > 0, mode, poses, points, placed, scratch,
                            state, times[n], 0.0, no_coherence)
        if outcome == NON_FINITE:
            return NON_FINITE
        flags[n] = outcome == _HIT
        for a in range(3):
            tcp_out[n, a] = tcp[1, a]
    return _output(state, hits, ints)


def _check_configuration_entry(q, allowance, first_only, ints, floats, hits):  # pragma: no cover - compiled
    """Joint-limit status (as `_limit_status`) × 2**32 + findings count for one configuration,
    every body grown by `allowance` (pairs by nothing); NON_FINITE when q holds a non-finite
    value. With `first_only`: no geometry past a limit."""
    single = q.reshape((1, q.shape[0]))
    status = _limit_status(single, ints, floats)
    if first_only and status == 2:
        return status << 32
    body_ints = _int_table(ints, _I_BODY)
    group = _int_table(ints, _I_GROUP)
    group_pair = _int_table(ints, _I_GROUP_PAIR)
    boxes = _float_table(ints, floats, _F_BOX)
    n_bodies = body_ints.shape[0]
    n_groups = group.shape[0]
    poses = np.empty((_int_table(ints, _I_NODE).shape[0], 4, 4))
    points = np.empty((n_bodies, 9))
    placed = np.zeros(n_groups, dtype=np.bool_)
    n_keys, n_pair_keys = _key_counts(ints)
    state = _new_state(n_keys, boxes.shape[0] - 1, n_pair_keys)
    body_inflation = np.full(n_bodies, allowance)
    group_bound = np.full(n_groups, allowance)
    pair_group_bound = np.zeros(group_pair.shape[0])
    pair_inflation = np.zeros(1)  # one value: every pair's
    tcp = np.empty((2, 3))
    scratch = np.empty((1 + n_groups, 8))
    index = np.empty(0, dtype=np.int64)
    unused_lazy = (points, index, points, points, index, tcp[0], placed)  # pair inflations are given: not read
    nothing = np.empty(0)
    no_coherence = (nothing, nothing, nothing, nothing, nothing)
    mode = np.int64(_FULL)  # every finding, first_only or not: as a path that stays at q (not a literal: see `_inline`)
    time, sample, n_pass = 0.0, np.int64(0), np.int64(1)  # not literals (see `_inline`)
    has_previous = sample > 0  # False, not a literal
    outcome = _evaluate(ints, floats, q, time, sample, body_inflation, group_bound, pair_group_bound, pair_inflation,
                        unused_lazy, n_pass, tcp, has_previous, mode, poses, points, placed, scratch, state, time,
                        time, no_coherence)
    if outcome == NON_FINITE:
        return NON_FINITE
    return (status << 32) + _output(state, hits, ints)


_F1 = numba.float64[::1]
_F2 = numba.float64[:, ::1]
_I2 = numba.int64[:, ::1]
_PATH = numba.types.Tuple((numba.int64, numba.int64, numba.int64, _F2))(_F1, _F2, _F2, numba.boolean, _I2, _F2, _F2)
_SAMPLES = numba.int64(_F1, _F2, _F2, _F2, numba.boolean, _I2, _F2, numba.boolean[::1], _F2, _F2)
_CONFIGURATION = numba.int64(_F1, numba.float64, numba.boolean, _I2, _F2, _F2)

#: compiled `_check_path_entry(times, positions, seg_bound, first_only, ints, floats, hits)`
check_path, _path_cached = _compile(_check_path_entry, _PATH)
#: compiled `_check_samples_entry(times, positions, inflation, pair_inflation, segments, ints, floats, flags, tcp, hits)`
check_samples, _samples_cached = _compile(_check_samples_entry, _SAMPLES)
#: compiled `_check_configuration_entry(q, allowance, first_only, ints, floats, hits)`
check_configuration, _configuration_cached = _compile(_check_configuration_entry, _CONFIGURATION)


def kernel_array(values: np.ndarray) -> np.ndarray:
    """`values` as the kernels' signatures take it (C-contiguous, writable float64): itself when it
    is one already (checked in ~0.2 µs), else a copy (a trajectory's arrays are read-only)."""
    if type(values) is np.ndarray and values.dtype == np.float64 and values.flags.c_contiguous and values.flags.writeable:
        return values
    return np.require(values, dtype=np.float64, requirements=["C", "W"])


def kernels_cached() -> bool:
    """Whether the kernels use numba's on-disk cache (False: compiled in memory at start-up)."""
    return _path_cached and _samples_cached and _configuration_cached
