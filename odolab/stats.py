"""Means with confidence intervals, and the verdict they allow: the statistics every table's
claims rest on (pure: numpy and scipy only)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special  # lighter to import than scipy.stats (its quantile functions)

__all__ = ["MeanCI", "mean_ci", "verdict"]


@dataclass(frozen=True)
class MeanCI:
    """A mean and its 95 % confidence interval (Student t; for 0/1 values, Wilson's score interval)."""

    mean: float
    low: float
    high: float
    n: int


def mean_ci(values: np.ndarray, binary: bool = False, confidence: float = 0.95) -> MeanCI:
    """Mean and interval of ``values``; ``binary`` (0/1 outcomes such as success) gets Wilson's score
    interval, which stays inside [0, 1] and is not degenerate at 0 or 100 %; others Student's t."""
    v = np.asarray(values, np.float64)
    n = len(v)
    if n == 0:
        return MeanCI(float("nan"), float("nan"), float("nan"), 0)
    m = float(v.mean())
    z = float(special.ndtri(0.5 + confidence / 2))  # the normal quantile
    if binary:
        if not np.isin(v, (0.0, 1.0)).all():
            raise ValueError("binary=True needs values that are all 0 or 1")
        centre = (m + z * z / (2 * n)) / (1 + z * z / n)
        half = z * np.sqrt(m * (1 - m) / n + z * z / (4 * n * n)) / (1 + z * z / n)
        # Wilson's bounds contain the mean exactly; rounding can put them 1e-18 beyond it at 0 or n of n
        return MeanCI(m, float(min(centre - half, m)), float(max(centre + half, m)), n)
    if n == 1:
        return MeanCI(m, float("nan"), float("nan"), 1)
    half = float(special.stdtrit(n - 1, 0.5 + confidence / 2) * v.std(ddof=1) / np.sqrt(n))  # Student's t quantile
    return MeanCI(m, m - half, m + half, n)


def verdict(ci: MeanCI) -> str:
    """What a paired difference's interval allows one to say: ``"lower"`` (the whole interval below
    zero), ``"higher"`` (above) or ``"undecided"`` (it holds zero, or there is no interval)."""
    if not (np.isfinite(ci.low) and np.isfinite(ci.high)):
        return "undecided"
    return "lower" if ci.high < 0 else "higher" if ci.low > 0 else "undecided"
