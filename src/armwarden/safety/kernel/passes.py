"""A path's check (`check_path_geometry`): the samples placed where `sampling.samples_at` places
them, pass after pass from coarse to fine, refined depth first where a pass flags a sample."""

from __future__ import annotations

import math

import numpy as np

from armwarden.safety.kernel.findings import new_state
from armwarden.safety.kernel.jit import helper, inlined
from armwarden.safety.kernel.predicates import clip01
from armwarden.safety.kernel.sample import HIT, MODE_FLAG, MODE_LAST, MODE_STILL, evaluate_sample
from armwarden.safety.kernel.tables import (
    F_BOX,
    F_GROUP_PAIR_REACH,
    F_GROUP_REACH,
    F_PAIR_REACH,
    F_PARAMS,
    I_GROUP,
    I_GROUP_PAIR,
    I_NODE,
    NON_FINITE,
    float_table,
    int_table,
    key_counts,
)


@helper
def _unit_targets(start, end, spacing):  # pragma: no cover - compiled
    """`sampling.unit_targets` (numpy's linspace, operation for operation)."""
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


@helper
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


@inlined
def _half_neighbour(values, n, column):  # pragma: no cover - compiled
    """`sampling.half_neighbour_bound` of `values` (N, C) at row n, column `column`."""
    count = values.shape[0]
    if count == 1:
        return 0.0
    before = values[n, column] - values[n - 1, column] if n > 0 else values[1, column] - values[0, column]
    after = values[n + 1, column] - values[n, column] if n < count - 1 else values[count - 1, column] - values[count - 2, column]
    return max(before, after) / 2.0


@helper
def joint_rates(steps, cost):  # pragma: no cover - compiled
    """Per joint, the largest |Δq| per unit of path parameter over the segments: any motion
    bound accumulated at rate Σ_i reach_i · |Δq_i| / cost grows at most Σ_i rate_i · reach_i per unit."""
    rates = np.zeros(steps.shape[1])
    for s in range(steps.shape[0]):
        if cost[s] > 0.0:
            for i in range(steps.shape[1]):
                rates[i] = max(rates[i], steps[s, i] / cost[s])
    return rates


@inlined
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


@helper
def check_path_geometry(times, positions, seg_bound, first_only, ints, floats):  # pragma: no cover - compiled
    """`Envelope._check_geometry` from the waypoints `positions` (K, nq) at `times` and the
    per-segment body motion bounds `seg_bound` (K-1, B+1) = |Δq| @ reach (numpy's product, so
    the samples are numpy's to the bit). Returns (state, samples checked or NON_FINITE, the
    first pass's TCP positions)."""
    n_way = positions.shape[0]
    nq = positions.shape[1]
    n_bodies = seg_bound.shape[1]
    params = float_table(ints, floats, F_PARAMS)[0]
    sweep = params[0]
    check_res = params[1]
    n_levels = int(params[3])
    group = int_table(ints, I_GROUP)
    group_pair = int_table(ints, I_GROUP_PAIR)
    pair_reach = float_table(ints, floats, F_PAIR_REACH)
    group_reach = float_table(ints, floats, F_GROUP_REACH)
    group_pair_reach = float_table(ints, floats, F_GROUP_PAIR_REACH)
    boxes = float_table(ints, floats, F_BOX)
    n_pairs = pair_reach.shape[0]
    n_groups = group.shape[0]
    n_group_pairs = group_pair.shape[0]
    n_keys, n_pair_keys = key_counts(ints)
    state = new_state(n_keys, boxes.shape[0] - 1, n_pair_keys)
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
    rates = joint_rates(steps, cost)
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
    poses = np.empty((int_table(ints, I_NODE).shape[0], 4, 4))
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
    still_mode = np.int64(MODE_STILL)  # not a literal (see `inlined`)
    no_previous = still_mode < 0  # False, not a literal (see `inlined`): a still sample has no segment
    # pairs found apart by a margin need no test while the path cannot have closed it (`evaluate_sample`)
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
        # the samples (`sampling.samples_at`)
        k = np.empty(n_pass, dtype=np.int64)
        alpha = np.empty(n_pass)
        at_end = np.empty(n_pass, dtype=np.bool_)
        body_at = np.empty((n_pass, n_bodies))
        for n in range(n_pass):
            kn = min(max(_search_left(cum, targets[n]) - 1, 0), n_way - 2)
            span = cum[kn + 1] - cum[kn]
            a = clip01((targets[n] - cum[kn]) / span) if span > 0 else 0.0
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
        mode = np.int64(MODE_LAST) if last_level else np.int64(MODE_FLAG)
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
            outcome = evaluate_sample(ints, floats, q, time, n, body_inflation, group_bound, pair_group_bound, no_rows,
                                lazy, n_pass, tcp, n > 0, mode, poses, points, placed, scratch, state, targets[n],
                                gap, coherence)
            if outcome == NON_FINITE:
                return state, NON_FINITE, first_tcp
            if level == 0:
                for a in range(3):
                    first_tcp[n, a] = tcp[1, a]
            flagged[n] = outcome == HIT
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
            outcome = evaluate_sample(ints, floats, q, time, n, still_bodies, still_groups, still_group_pairs, still_rows,
                                lazy, n_pass, tcp, no_previous, still_mode, poses, points, placed, scratch, state, targets[n],
                                0.0, coherence)
            certain[n] = outcome == HIT
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

