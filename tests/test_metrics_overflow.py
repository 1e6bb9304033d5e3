"""odolab/core/metrics.py: errors near 1e300 m give finite statistics, and usual ones are unchanged to the bit."""

from __future__ import annotations

import numpy as np
import pytest

from odolab.core import metrics


def test_huge_errors_give_finite_statistics():
    stats = metrics.ErrorStats.of(np.array([1e300, 2e300, 3.0]))
    assert stats.rmse == pytest.approx(np.sqrt(5 / 3) * 1e300) and stats.mean == pytest.approx(1e300)
    assert stats.std == pytest.approx(np.sqrt(2 / 3) * 1e300) and stats.max == 2e300


def test_usual_errors_are_computed_as_before():
    e = np.random.default_rng(0).random(50)
    stats = metrics.ErrorStats.of(e)
    assert stats.rmse == float(np.sqrt(np.mean(e * e))) and stats.std == float(np.std(e))
    assert np.isinf(metrics.ErrorStats.of(np.array([1.0, np.inf])).rmse)  # a non-finite error stays so


def test_ate_and_rpe_of_a_trajectory_gone_to_1e300_are_finite():
    gt = np.tile(np.eye(4), (4, 1, 1))
    est = gt.copy()
    est[2:, 0, 3] = 1e300
    assert metrics.ate(gt, est).rmse == pytest.approx(np.sqrt(0.5) * 1e300)
    assert np.isfinite(metrics.rpe(gt, est, 1).trans.rmse)
    v = np.array([[3.0, 4.0, 0.0], [3e300, 4e300, 0.0], [np.nan, 0.0, 0.0]])
    norms = metrics.row_norms(v)
    assert norms[0] == 5.0 and norms[1] == pytest.approx(5e300) and np.isnan(norms[2])
