"""The Wilson score interval for a success fraction (no SciPy: it is one formula)."""

from __future__ import annotations

import math

#: the normal quantile for a two-sided 95 % interval
Z_95 = 1.959963984540054


def wilson_interval(successes: int, trials: int, z: float = Z_95) -> tuple[float, float]:
    """Wilson's interval for `successes` of `trials`: unlike the normal approximation it stays in
    [0, 1] and is not degenerate at 0 or 100 %, which is where a safety figure usually sits."""
    if trials <= 0:
        return 0.0, 1.0
    p = successes / trials
    denominator = 1 + z * z / trials
    centre = (p + z * z / (2 * trials)) / denominator
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / denominator
    return max(0.0, centre - half), min(1.0, centre + half)
