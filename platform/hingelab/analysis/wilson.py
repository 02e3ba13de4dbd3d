"""Wilson score intervals for success rates (binomial proportions).

For k successes in n trials, p = k / n and z the normal quantile (1.96 for 95%):

    centre    = (p + z^2 / (2 n)) / (1 + z^2 / n)
    half      = z / (1 + z^2 / n) * sqrt(p (1 - p) / n + z^2 / (4 n^2))
    interval  = [centre - half, centre + half]

Unlike the normal (Wald) interval it stays inside [0, 1] and is not empty at p = 0 or 1,
which matters for the small trial counts of robot evaluations (the paper's 24 trials).
n = 0 gives NaN.
"""

from __future__ import annotations

import numpy as np

Z95 = 1.959963984540054  # two-sided 95% normal quantile


def wilson_interval(successes, trials, z: float = Z95) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) of the Wilson interval; arrays of the broadcast shape of the inputs."""
    k = np.asarray(successes, dtype=np.float64)
    n = np.asarray(trials, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        p = k / n
        denominator = 1.0 + z * z / n
        centre = (p + z * z / (2.0 * n)) / denominator
        half = z / denominator * np.sqrt(p * (1.0 - p) / n + z * z / (4.0 * n * n))
        low, high = centre - half, centre + half
    invalid = ~(n > 0)
    low, high = np.where(invalid, np.nan, np.clip(low, 0.0, 1.0)), np.where(invalid, np.nan, np.clip(high, 0.0, 1.0))
    return low, high


__all__ = ["wilson_interval", "Z95"]
