"""Every check of one sample (`evaluate_sample`): forward kinematics, the broad phases, the
workspace, keep-out and self-collision tests, and the pairs' inflation computed from the path only
where a pair comes close."""

from __future__ import annotations

import math

import numpy as np

from armwarden.robot.batch_fk import fk_into
from armwarden.safety.kernel.findings import improves, offer
from armwarden.safety.kernel.jit import helper
from armwarden.safety.kernel.predicates import (
    bounds_overlap,
    boxes_apart,
    outside_box,
    place_group,
    segment_box_distance,
    segment_hits_box,
    segment_segment_distance,
    transform,
)
from armwarden.safety.kernel.tables import (
    CULL_EPS,
    F_BODY,
    F_BOX,
    F_GROUP,
    F_GROUP_PAIR,
    F_NODE,
    F_PAIR,
    I_BODY,
    I_GROUP,
    I_GROUP_BODIES,
    I_GROUP_PAIR,
    I_GROUP_PAIR_PAIRS,
    I_NODE,
    I_PAIR,
    KIND_KEEP_OUT,
    KIND_SELF,
    KIND_WORKSPACE,
    NON_FINITE,
    float_table,
    int_table,
    key_counts,
)

# evaluation modes of one sample
MODE_FLAG = 0  # is anything hit? stop at the first hit (a pass whose findings are not reported)
MODE_STILL = 1  # a flagged sample without inflation: record findings, and test everything (its flag says "certain")
MODE_LAST = 2  # the densest level: record findings; keys that cannot get an earlier finding are not tested
MODE_FULL = 3  # record findings, test everything (flags exact: the pass-level API)
# what `evaluate_sample` returns
CLEAR = 0
HIT = 1


@helper
def evaluate_sample(ints, floats, q, time, sample, body_inflation, group_bound, pair_group_bound,
              pair_inflation_row, lazy, n_pass, tcp, has_previous, mode, poses, points, placed,
              scratch, state, tau, gap, coherence):  # pragma: no cover - compiled
    """Every check of one sample. `body_inflation` (B+1,), group and group-pair inflation
    bounds, the pair inflations from `pair_inflation_row` (P,), or its one value for every pair
    when it holds one, or, when it is empty, from the path (`lazy`, see `_lazy_pair_inflation`).
    `tcp` (2, 3): row 1 receives this sample's TCP, row 0 holds the previous sample's (used when
    `has_previous`). `scratch` (1+G, 8). `tau`, `gap`, `coherence`: the sample's path parameter,
    half the larger target gap next to it, and (skip_lo, skip_hi, skip_gap, pair_rate (P,): the
    pairs' skip intervals and their relative-motion rates per unit of path parameter, -1 until
    computed; rates (nq,): `joint_rates`), empty arrays: no path. Returns CLEAR or HIT, or
    NON_FINITE (nothing else done)."""
    node_ints = int_table(ints, I_NODE)
    node_floats = float_table(ints, floats, F_NODE)
    if not fk_into(q, node_ints, node_floats, poses):
        return NON_FINITE
    pair_cum, pair_valid, steps, pair_reach, k, alpha, at_end = lazy
    body_ints = int_table(ints, I_BODY)
    group = int_table(ints, I_GROUP)
    group_bodies = int_table(ints, I_GROUP_BODIES)
    body_floats = float_table(ints, floats, F_BODY)
    group_floats = float_table(ints, floats, F_GROUP)
    boxes = float_table(ints, floats, F_BOX)
    n_keys, _ = key_counts(ints)
    n_bodies = body_ints.shape[0]
    tcp_body = n_bodies - 1
    n_groups = group.shape[0]
    n_zones = boxes.shape[0] - 1
    record = mode != MODE_FLAG
    knots = scratch[0]
    skip_settled = mode == MODE_LAST  # keys whose finding this sample cannot improve
    flagged = False
    # floats: numba gives int constants literal types, and a specialisation of `write_row` each
    workspace, keep_out, self_collision, no_zone = float(KIND_WORKSPACE), float(KIND_KEEP_OUT), float(KIND_SELF), -1.0

    # the TCP point (body B) and the group spheres' centres
    x, y, z = transform(poses, body_ints[tcp_body, 0], body_floats[tcp_body, 0], body_floats[tcp_body, 1],
                         body_floats[tcp_body, 2])
    points[tcp_body, 0] = points[tcp_body, 3] = tcp[1, 0] = x
    points[tcp_body, 1] = points[tcp_body, 4] = tcp[1, 1] = y
    points[tcp_body, 2] = points[tcp_body, 5] = tcp[1, 2] = z
    # the group spheres' centres: scratch rows 1..G (row 0 is the knots' scratch)
    for g in range(n_groups):
        placed[g] = False
        scratch[1 + g, 0], scratch[1 + g, 1], scratch[1 + g, 2] = transform(
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
            place_group(g, group, group_bodies, body_ints, body_floats, poses, points, placed)
            first, end = group[g, 2], group[g, 3]
        else:
            first, end = -1, 0  # the TCP alone
        for m in range(first, end):
            b = group_bodies[m, 0] if m >= 0 else tcp_body
            slot = body_ints[b, 3]
            if skip_settled and not improves(state, slot, time):
                continue
            radius = body_inflation[b] + body_floats[b, 6]
            if not outside_box(points, b, radius, boxes, 0):
                continue
            flagged = True
            if not record:
                return HIT
            offer(state, slot, workspace, b, no_zone, time, points, b, 0.0, radius)

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
                place_group(g, group, group_bodies, body_ints, body_floats, poses, points, placed)
                first, end = group[g, 2], group[g, 3]
            else:
                first, end = -1, 0
            for m in range(first, end):
                b = group_bodies[m, 0] if m >= 0 else tcp_body
                slot = n_keys + body_ints[b, 3] * n_zones + zone
                if skip_settled and not improves(state, slot, time):
                    continue
                radius = body_inflation[b] + body_floats[b, 6]
                overlap = bounds_overlap(points, b, radius, boxes, row)
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
                distance = segment_box_distance(points[b, 0], points[b, 1], points[b, 2], points[b, 3], points[b, 4],
                                                 points[b, 5], boxes, row, knots)
                hit = distance <= radius
                if not hit and segment:
                    hit = segment_hits_box(tcp, boxes, row, radius)
                if not hit:
                    continue
                flagged = True
                if not record:
                    return HIT
                offer(state, slot, keep_out, b, float(zone), time, points, b, distance, radius)

    # ---- self-collision: capsule pairs closer than their summed radii plus inflation
    pairs = int_table(ints, I_PAIR)
    group_pair = int_table(ints, I_GROUP_PAIR)
    group_pair_pairs = int_table(ints, I_GROUP_PAIR_PAIRS)
    pair_floats = float_table(ints, floats, F_PAIR)
    group_pair_floats = float_table(ints, floats, F_GROUP_PAIR)
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
                place_group(ga, group, group_bodies, body_ints, body_floats, poses, points, placed)
                place_group(gb, group, group_bodies, body_ints, body_floats, poses, points, placed)
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
            if skip_settled and not improves(state, slot, time):
                continue
            centre_distance = math.sqrt(gx * gx + gy * gy + gz * gz)
            if skipping:
                # on a path, the allowance is bounded before it is known: far enough apart by the
                # bound, the pair is not touching whatever its own inflation (and stays so a while)
                allowance = pair_floats[p, 0] + rate * gap + CULL_EPS
                if boxes_apart(points, ia, ib, allowance):
                    continue
                distance = segment_segment_distance(points, ia, ib)
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
                if boxes_apart(points, ia, ib, pair_floats[p, 0] + inflation):
                    continue
                distance = segment_segment_distance(points, ia, ib)
            # the numpy pass's own tests, with the pair's own inflation
            if not (centre_distance < pair_floats[p, 1] + inflation):
                continue
            allowance = pair_floats[p, 0] + inflation
            if not (distance < allowance):
                continue
            flagged = True
            if not record:
                return HIT
            offer(state, slot, self_collision, p, no_zone, time, points, ia, distance, allowance)
    return HIT if flagged else CLEAR



@helper
def _lazy_pair_inflation(pair_cum, pair_valid, steps, pair_reach, k, alpha, at_end, n_pass, n, p):  # pragma: no cover - compiled
    """Pair p's inflation at sample n of the current pass, as `sampling.half_neighbour_bound(at(path.pairs))`
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
