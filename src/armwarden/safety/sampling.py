"""Where the envelope samples a path: the path parameter (sampling cost along the waypoint
polyline, in units of one fine interval) and the samples at chosen values of it, each with the
sweep allowance its bodies and pairs are checked with (`safety.envelope`'s module docstring says
why that allowance makes the sampling a guarantee). The compiled kernels place their samples by
the same arithmetic (`safety.kernel.passes`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PathParameter:
    times: np.ndarray
    positions: np.ndarray
    cost: np.ndarray  # (K,) cumulative sampling cost at each waypoint
    body: np.ndarray  # (K, B+1) cumulative per-body motion bound [m]
    pairs: np.ndarray  # (K, P) cumulative relative-motion bound of each self-collision pair [m]

    @property
    def total(self) -> float:
        return float(self.cost[-1])


@dataclass(frozen=True)
class Samples:
    times: np.ndarray  # (N,)
    positions: np.ndarray  # (N, n)
    inflation: np.ndarray  # (N, B+1) per body [m], the TCP point last
    pair_inflation: np.ndarray  # (N, P) per self-collision pair [m]


def path_parameter(times: np.ndarray, positions: np.ndarray, reach: np.ndarray, pair_reach: np.ndarray,
                   sweep_resolution_m: float, check_resolution_rad: float) -> PathParameter:
    """Cumulative sampling cost along the waypoint polyline, in units of one fine interval.

    A segment's cost is its point-motion bound against `sweep_resolution_m` or its largest
    joint step against `check_resolution_rad`, whichever is larger; samples one unit apart
    satisfy both. `body` holds the cumulative per-body motion bound [m] (TCP last), from the
    bodies' `reach` (n, B+1); `pairs` the pairs' relative one, from `pair_reach` (n, P).
    """
    steps = np.abs(np.diff(positions, axis=0))
    seg_bound = steps @ reach  # (K-1, B+1)
    cost = np.maximum(
        np.max(seg_bound, axis=1) / sweep_resolution_m,
        np.max(steps, axis=1) / check_resolution_rad,
    )
    pair_bound = steps @ pair_reach  # (K-1, P)
    return PathParameter(
        times=times,
        positions=positions,
        cost=np.concatenate([[0.0], np.cumsum(cost)]),
        body=np.vstack([np.zeros((1, seg_bound.shape[1])), np.cumsum(seg_bound, axis=0)]),
        pairs=np.vstack([np.zeros((1, pair_bound.shape[1])), np.cumsum(pair_bound, axis=0)]),
    )


def samples_at(path: PathParameter, targets: np.ndarray) -> Samples:
    """Times, configurations and inflations of samples at path-parameter `targets`.

    The inflation of a sample is half the larger motion bound of the intervals next to it
    (within this run of samples): per body, and per self-collision pair (relative motion).
    """
    cum = path.cost
    k = np.clip(np.searchsorted(cum, targets, side="left") - 1, 0, len(cum) - 2)
    span = cum[k + 1] - cum[k]
    alpha = np.clip(np.where(span > 0, (targets - cum[k]) / np.where(span > 0, span, 1.0), 0.0), 0.0, 1.0)
    at_end = targets >= cum[-1]

    def at(values: np.ndarray) -> np.ndarray:
        sampled = values[k] + (alpha[:, None] if values.ndim == 2 else alpha) * (values[k + 1] - values[k])
        sampled[at_end] = values[-1]
        return sampled

    return Samples(
        times=at(path.times),
        positions=at(path.positions),
        inflation=half_neighbour_bound(at(path.body)),
        pair_inflation=half_neighbour_bound(at(path.pairs)),
    )


def half_neighbour_bound(cumulative: np.ndarray) -> np.ndarray:
    """Per sample: half the larger of the bounds of the two intervals next to it."""
    interval = np.diff(cumulative, axis=0)
    if not len(interval):
        return np.zeros_like(cumulative)
    return np.maximum(np.vstack([interval[:1], interval]), np.vstack([interval, interval[-1:]])) / 2.0


def unit_targets(start: float, end: float, spacing: float = 1.0) -> np.ndarray:
    """Evenly spaced path-parameter targets from `start` to `end`, at most `spacing` apart."""
    n_intervals = max(1, int(np.ceil((end - start) / spacing - 1e-12))) if end > start else 1
    return np.linspace(start, end, n_intervals + 1)


def merged_ranges(targets: np.ndarray, flagged: np.ndarray) -> list[tuple[float, float]]:
    """Path ranges [target[k-1], target[k+1]] around every flagged sample k, overlaps merged."""
    ranges: list[tuple[float, float]] = []
    for k in flagged:
        start, end = float(targets[max(k - 1, 0)]), float(targets[min(k + 1, len(targets) - 1)])
        if ranges and start <= ranges[-1][1]:
            ranges[-1] = (ranges[-1][0], max(ranges[-1][1], end))
        else:
            ranges.append((start, end))
    return ranges
