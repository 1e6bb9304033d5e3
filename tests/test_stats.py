"""odolab/core/stats.py: the paired tests the studies' verdicts rest on, checked against scipy.stats'
reference implementations and by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import binomtest, ttest_rel

from odolab.core.stats import holm, mcnemar, paired_t


def test_mcnemar_is_the_exact_binomial_test_of_the_discordant_episodes():
    rng = np.random.default_rng(0)
    for _ in range(20):
        a, b = rng.random(50) < 0.6, rng.random(50) < 0.4
        a_only, b_only, p = mcnemar(a, b)
        assert (a_only, b_only) == (int(np.sum(a & ~b)), int(np.sum(b & ~a)))
        assert p == pytest.approx(binomtest(a_only, a_only + b_only, 0.5).pvalue, rel=1e-9)
    assert mcnemar(np.ones(5), np.ones(5)) == (0, 0, 1.0)  # nothing discordant: no evidence either way
    with pytest.raises(ValueError, match="one shape"):
        mcnemar(np.ones(3), np.ones(4))


def test_paired_t_matches_scipy_and_says_what_it_cannot_test():
    rng = np.random.default_rng(1)
    x = rng.normal(size=30)
    y = x + rng.normal(0.4, 1.0, size=30)
    mean, p = paired_t(x - y)
    assert mean == pytest.approx(np.mean(x - y)) and p == pytest.approx(ttest_rel(x, y).pvalue, rel=1e-9)
    assert math.isnan(paired_t(np.array([0.3]))[1]) and paired_t(np.zeros(4)) == (0.0, 1.0)
    assert paired_t(np.full(4, 0.2)) == (pytest.approx(0.2), 0.0)


def test_holm_multiplies_the_smallest_p_by_the_family_size_and_keeps_the_order():
    assert holm([0.01, 0.04, 0.03, float("nan"), 0.005]) == pytest.approx(
        [0.03, 0.06, 0.06, float("nan"), 0.02], nan_ok=True
    )
    assert holm([0.9, 0.3]) == [0.9, 0.6] and holm([0.9, 0.8]) == [1.0, 1.0] and holm([]) == []
