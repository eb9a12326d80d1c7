"""What the kernels know of one envelope (`Tables`), packed into two arrays, and the ids and
compiled look-ups by which the kernels read it; the layout of the finding rows they return."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from armwarden.robot.batch_fk import KinematicChain
from armwarden.safety.kernel.jit import inlined

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

# int tables: row ranges of `Tables.ints` (columns beyond a table's own are padding)
I_NODE = 0  # (J, 3) batch_fk node table: parent, kind, q index
I_BODY = 1  # (B+1, 4): FK node, group (-1: the TCP), moving (0/1), name key
I_GROUP = 2  # (G, 4): FK node, moving, first and end index into I_GROUP_BODIES
I_GROUP_BODIES = 3  # (B, 1): body indices, grouped
I_PAIR = 4  # (P, 3): body a, body b, name-pair key
I_GROUP_PAIR = 5  # (GP, 4): group a, group b, first and end index into I_GROUP_PAIR_PAIRS
I_GROUP_PAIR_PAIRS = 6  # (P, 1): pair indices, grouped
I_COUNTS = 7  # (1, 2): number of body names, of name pairs
I_RANK = 8  # (S, 1): each key slot's place in the order findings are reported in (`Tables.build`)
N_INT_TABLES = 9
# float tables: row ranges of `Tables.floats`
F_NODE = 0  # (J, 15) batch_fk node table
F_BODY = 1  # (B+1, 7): p0, p1 in the joint frame, padded radius
F_GROUP = 2  # (G, 5): sphere centre in the joint frame, radius around the segments, around the capsules
F_PAIR = 3  # (P, 2): summed radii, bounding-sphere reach
F_GROUP_PAIR = 4  # (GP, 1): largest summed radii of its pairs
F_BOX = 5  # (1+Z, 6): the workspace box, then every keep-out zone: lo xyz, hi xyz
F_GROUP_REACH = 6  # (G, nq): largest reach of the group's bodies per joint
F_GROUP_PAIR_REACH = 7  # (GP, nq): largest relative reach of the group pair's pairs per joint
F_PAIR_REACH = 8  # (P, nq): relative reach of each pair
F_LIMITS = 9  # (2, nq): lower, upper joint limits
F_PARAMS = 10  # (1, 4 + L): sweep_resolution_m, check_resolution_rad, joint_limit_margin_rad, L, refinement...
N_FLOAT_TABLES = 11


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
        assert len(int_tables) == N_INT_TABLES and len(float_tables) == N_FLOAT_TABLES
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


@inlined
def int_table(ints, index):  # pragma: no cover - compiled
    return ints[ints[index, 0]:ints[index, 1]]


@inlined
def float_table(ints, floats, index):  # pragma: no cover - compiled
    return floats[ints[N_INT_TABLES + index, 0]:ints[N_INT_TABLES + index, 1]]


@inlined
def key_counts(ints):  # pragma: no cover - compiled
    counts = int_table(ints, I_COUNTS)
    return counts[0, 0], counts[0, 1]
