"""The kernels' three compiled entry points, what `Envelope` calls: a path, given samples, one
configuration. Each checks the joint limits, runs the geometry and writes the findings."""

from __future__ import annotations

import numba
import numpy as np

from armwarden.safety.kernel.findings import new_state, write_hits
from armwarden.safety.kernel.jit import compile_entry, helper
from armwarden.safety.kernel.passes import check_path_geometry
from armwarden.safety.kernel.sample import HIT, MODE_FULL, evaluate_sample
from armwarden.safety.kernel.tables import (
    F_BOX,
    F_LIMITS,
    F_PARAMS,
    I_BODY,
    I_GROUP,
    I_GROUP_BODIES,
    I_GROUP_PAIR,
    I_GROUP_PAIR_PAIRS,
    I_NODE,
    NON_FINITE,
    float_table,
    int_table,
    key_counts,
)

__all__ = ["check_configuration", "check_path", "check_samples", "kernel_array", "kernels_cached"]

@helper
def _limit_status(positions, ints, floats):  # pragma: no cover - compiled
    """0: every waypoint inside the joint limits and their margin; 1: some within the margin only
    (a soft finding); 2: some outside a limit (`waypoints.check_joint_limits` says which)."""
    limits = float_table(ints, floats, F_LIMITS)
    margin = float_table(ints, floats, F_PARAMS)[0, 2]
    status = 0
    for k in range(positions.shape[0]):
        for j in range(positions.shape[1]):
            value = positions[k, j]
            if value < limits[0, j] or value > limits[1, j]:
                return 2
            if margin > 0 and (value < limits[0, j] + margin or value > limits[1, j] - margin):
                status = 1
    return status



def _check_path_entry(times, positions, seg_bound, first_only, ints, floats, hits):  # pragma: no cover - compiled
    """(joint-limit status, findings count or NON_FINITE, samples checked, first pass's TCP
    positions). With `first_only`, geometry is not checked when a waypoint is outside a limit."""
    status = _limit_status(positions, ints, floats)
    if first_only and status == 2:
        return status, 0, 0, np.empty((0, 3))
    state, checked, tcp = check_path_geometry(times, positions, seg_bound, first_only, ints, floats)
    if checked == NON_FINITE:
        return status, NON_FINITE, 0, tcp
    return status, write_hits(state, hits, ints), checked, tcp


def _check_samples_entry(times, positions, inflation, pair_inflation, segments, ints, floats, flags, tcp_out,
                         hits):  # pragma: no cover - compiled
    """One pass over given samples (`Envelope._geometry_pass`): every sample's flag into `flags`,
    its TCP into `tcp_out`, the findings into `hits`. Returns their count or NON_FINITE.
    `segments`: the TCP's straight segment from the sample before counts too."""
    n_samples = positions.shape[0]
    n_bodies = inflation.shape[1]
    group = int_table(ints, I_GROUP)
    group_bodies = int_table(ints, I_GROUP_BODIES)
    group_pair = int_table(ints, I_GROUP_PAIR)
    group_pair_pairs = int_table(ints, I_GROUP_PAIR_PAIRS)
    boxes = float_table(ints, floats, F_BOX)
    n_groups = group.shape[0]
    n_group_pairs = group_pair.shape[0]
    poses = np.empty((int_table(ints, I_NODE).shape[0], 4, 4))
    points = np.empty((n_bodies, 9))
    placed = np.zeros(n_groups, dtype=np.bool_)
    n_keys, n_pair_keys = key_counts(ints)
    state = new_state(n_keys, boxes.shape[0] - 1, n_pair_keys)
    group_bound = np.empty(n_groups)
    pair_group_bound = np.empty(n_group_pairs)
    tcp = np.empty((2, 3))
    scratch = np.empty((1 + n_groups, 8))
    index = np.empty(0, dtype=np.int64)
    unused_lazy = (points, index, points, points, index, tcp[0], placed)  # pair inflations are given: not read
    nothing = np.empty(0)
    no_coherence = (nothing, nothing, nothing, nothing, nothing)
    mode = np.int64(MODE_FULL)  # not a literal (see `inlined`)
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
        outcome = evaluate_sample(ints, floats, positions[n], times[n], n, inflation[n], group_bound, pair_group_bound,
                            row, unused_lazy, n_samples, tcp, segments and n > 0, mode, poses, points, placed, scratch,
                            state, times[n], 0.0, no_coherence)
        if outcome == NON_FINITE:
            return NON_FINITE
        flags[n] = outcome == HIT
        for a in range(3):
            tcp_out[n, a] = tcp[1, a]
    return write_hits(state, hits, ints)


def _check_configuration_entry(q, allowance, first_only, ints, floats, hits):  # pragma: no cover - compiled
    """Joint-limit status (as `_limit_status`) × 2**32 + findings count for one configuration,
    every body grown by `allowance` (pairs by nothing); NON_FINITE when q holds a non-finite
    value. With `first_only`: no geometry past a limit."""
    single = q.reshape((1, q.shape[0]))
    status = _limit_status(single, ints, floats)
    if first_only and status == 2:
        return status << 32
    body_ints = int_table(ints, I_BODY)
    group = int_table(ints, I_GROUP)
    group_pair = int_table(ints, I_GROUP_PAIR)
    boxes = float_table(ints, floats, F_BOX)
    n_bodies = body_ints.shape[0]
    n_groups = group.shape[0]
    poses = np.empty((int_table(ints, I_NODE).shape[0], 4, 4))
    points = np.empty((n_bodies, 9))
    placed = np.zeros(n_groups, dtype=np.bool_)
    n_keys, n_pair_keys = key_counts(ints)
    state = new_state(n_keys, boxes.shape[0] - 1, n_pair_keys)
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
    mode = np.int64(MODE_FULL)  # every finding, first_only or not: as a path that stays at q (not a literal: see `inlined`)
    time, sample, n_pass = 0.0, np.int64(0), np.int64(1)  # not literals (see `inlined`)
    has_previous = sample > 0  # False, not a literal
    outcome = evaluate_sample(ints, floats, q, time, sample, body_inflation, group_bound, pair_group_bound, pair_inflation,
                        unused_lazy, n_pass, tcp, has_previous, mode, poses, points, placed, scratch, state, time,
                        time, no_coherence)
    if outcome == NON_FINITE:
        return NON_FINITE
    return (status << 32) + write_hits(state, hits, ints)


_F1 = numba.float64[::1]
_F2 = numba.float64[:, ::1]
_I2 = numba.int64[:, ::1]
_PATH = numba.types.Tuple((numba.int64, numba.int64, numba.int64, _F2))(_F1, _F2, _F2, numba.boolean, _I2, _F2, _F2)
_SAMPLES = numba.int64(_F1, _F2, _F2, _F2, numba.boolean, _I2, _F2, numba.boolean[::1], _F2, _F2)
_CONFIGURATION = numba.int64(_F1, numba.float64, numba.boolean, _I2, _F2, _F2)

#: compiled `_check_path_entry(times, positions, seg_bound, first_only, ints, floats, hits)`
check_path, _path_cached = compile_entry(_check_path_entry, _PATH)
#: compiled `_check_samples_entry(times, positions, inflation, pair_inflation, segments, ints, floats, flags, tcp, hits)`
check_samples, _samples_cached = compile_entry(_check_samples_entry, _SAMPLES)
#: compiled `_check_configuration_entry(q, allowance, first_only, ints, floats, hits)`
check_configuration, _configuration_cached = compile_entry(_check_configuration_entry, _CONFIGURATION)


def kernel_array(values: np.ndarray) -> np.ndarray:
    """`values` as the kernels' signatures take it (C-contiguous, writable float64): itself when it
    is one already (checked in ~0.2 µs), else a copy (a trajectory's arrays are read-only)."""
    if type(values) is np.ndarray and values.dtype == np.float64 and values.flags.c_contiguous and values.flags.writeable:
        return values
    return np.require(values, dtype=np.float64, requirements=["C", "W"])


def kernels_cached() -> bool:
    """Whether the kernels use numba's on-disk cache (False: compiled in memory at start-up)."""
    return _path_cached and _samples_cached and _configuration_cached
