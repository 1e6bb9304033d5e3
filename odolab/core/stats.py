"""Means with confidence intervals, and the verdict they allow: the statistics every table's
claims rest on (pure: numpy and scipy only)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special  # lighter to import than scipy.stats (its quantile functions)

__all__ = ["MeanCI", "holm", "mcnemar", "mean_ci", "paired_t", "verdict"]


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


def mcnemar(a: np.ndarray, b: np.ndarray) -> tuple[int, int, float]:
    """McNemar's exact test of two 0/1 outcomes on the same trials (success of rows A and B on the
    same episodes): ``(a_only, b_only, p)``, the discordant counts (A succeeded where B failed, and the
    other way round) and the two-sided p-value of the binomial test of ``a_only`` among the discordant
    trials at probability 1/2 (1.0 when none are discordant)."""
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    if a.shape != b.shape:
        raise ValueError(f"paired outcomes need one shape, got {a.shape} and {b.shape}")
    a_only, b_only = int(np.sum(a & ~b)), int(np.sum(~a & b))
    n = a_only + b_only
    p = 1.0 if n == 0 else float(min(1.0, 2.0 * special.bdtr(min(a_only, b_only), n, 0.5)))
    return a_only, b_only, p


def paired_t(differences: np.ndarray) -> tuple[float, float]:
    """Student's paired t test of per-trial differences A - B (same episodes): ``(mean difference,
    two-sided p)``; p is NaN below two trials, 1.0 when every difference is 0 and 0.0 when they are
    all one non-zero value."""
    d = np.asarray(differences, np.float64)
    n = len(d)
    if n < 2:
        return (float(d.mean()) if n else float("nan")), float("nan")
    m, sd = float(d.mean()), float(d.std(ddof=1))
    if sd == 0.0:
        return m, 1.0 if m == 0.0 else 0.0
    t = m / (sd / np.sqrt(n))
    return m, float(2.0 * special.stdtr(n - 1, -abs(t)))


def holm(p_values: list[float]) -> list[float]:
    """Holm's step-down adjustment of a family of p-values (controls the family-wise error rate):
    each adjusted p is compared with the level itself. NaN p-values stay NaN and are not counted."""
    p = np.asarray(p_values, np.float64)
    out = np.full(len(p), np.nan)
    idx = [i for i in np.argsort(p, kind="stable") if np.isfinite(p[i])]
    m, running = len(idx), 0.0
    for rank, i in enumerate(idx):
        running = max(running, min(1.0, (m - rank) * p[i]))
        out[i] = running
    return [float(v) for v in out]
