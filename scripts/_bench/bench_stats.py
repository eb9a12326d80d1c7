"""Percentile summaries shared by the benchmark sections in scripts/_bench/."""

from __future__ import annotations

import numpy as np


def percentiles(values: list[float], quantiles: tuple[int, ...] = (50, 95)) -> dict[str, float]:
    """{"n", "p<q>" for each quantile, "max"}; NaN figures when there are no values."""
    if not values:
        return {"n": 0, **{f"p{q}": float("nan") for q in quantiles}, "max": float("nan")}
    array = np.asarray(values, dtype=float)
    return {"n": len(values), **{f"p{q}": float(np.percentile(array, q)) for q in quantiles}, "max": float(array.max())}
