"""The findings one check keeps, per key, as `Envelope` keeps its violations, and how they are
written out in the order `Envelope` reports them."""

from __future__ import annotations

import numpy as np

from armwarden.safety.kernel.jit import helper, inlined
from armwarden.safety.kernel.tables import HIT_COLUMNS, I_RANK, int_table


@inlined
def write_row(row, kind, index, zone, time, points, b, distance, allowance, slot):  # pragma: no cover - compiled
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



# Findings are keyed as `Envelope` keys its violations: by body *name* (several fitted capsules of
# one link share their link's name) with the workspace or with a zone, and by the pair of names.
# Per key the earliest finding is kept — within a pass the first sample that has one (at it, the
# lowest body or pair index); across passes, a later pass replaces it only with a strictly
# earlier one — as `Envelope` merges its passes' findings.
#
# state: (found (S,), time (S,), rows (S, HIT_COLUMNS), n_found (1,)) over the key slots: workspace
# per name [0, K), keep-out per name and zone [K, K + K·Z), self-collision per name pair after.


@helper
def new_state(n_keys, n_zones, n_pair_keys):  # pragma: no cover - compiled
    slots = n_keys * (1 + n_zones) + n_pair_keys
    return (np.zeros(slots, dtype=np.bool_), np.empty(slots), np.empty((slots, HIT_COLUMNS)),
            np.zeros(1, dtype=np.int64))


@helper
def improves(state, slot, time):  # pragma: no cover - compiled
    """Whether a finding at `time` would be kept for `slot` (none yet, or a later one)."""
    return not state[0][slot] or time < state[1][slot]


@helper
def offer(state, slot, kind, index, zone, time, points, b, distance, allowance):  # pragma: no cover - compiled
    found, times, rows, n_found = state
    if found[slot] and not time < times[slot]:
        return
    if not found[slot]:
        found[slot] = True
        n_found[0] += 1
    times[slot] = time
    write_row(rows[slot], kind, index, zone, time, points, b, distance, allowance, float(slot))


@helper
def write_hits(state, hits, ints):  # pragma: no cover - compiled
    """The kept findings into `hits` in the order they are reported (time, then `I_RANK`); their count."""
    found, times, rows, _ = state
    rank = int_table(ints, I_RANK)
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

