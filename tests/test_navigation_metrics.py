"""Navigation metrics on hand-made paths with known answers (habitat-lab's definitions)."""

from __future__ import annotations

import numpy as np
import pytest

from odolab.core.stats import mean_ci
from odolab.navigation.metrics import SUCCESS_DISTANCE, EpisodeOutcome, path_length


def test_spl_and_soft_spl_on_known_paths():
    # a straight 4 m corridor walked exactly, stopping 0.1 m short: success, SPL = 4 / 4 = 1
    walk = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.9, 0.0]])
    assert np.isclose(path_length(walk), 3.9)
    e = EpisodeOutcome(d0=4.0, d_end=0.1, path=path_length(walk), stopped=True)
    assert e.success == 1.0 and e.spl == 1.0 and np.isclose(e.soft_spl, 1 - 0.1 / 4)
    # a detour twice as long: SPL halves
    e = EpisodeOutcome(d0=4.0, d_end=0.0, path=8.0, stopped=True)
    assert e.spl == 0.5 and e.soft_spl == 0.5
    # no STOP: no success, no SPL, but SoftSPL counts the progress
    e = EpisodeOutcome(d0=4.0, d_end=1.0, path=3.0, stopped=False)
    assert e.success == 0.0 and e.spl == 0.0 and np.isclose(e.soft_spl, 0.75)
    # stopped just outside the radius (habitat-lab: strictly less than 0.36 m)
    assert EpisodeOutcome(d0=4.0, d_end=SUCCESS_DISTANCE, path=4.0, stopped=True).success == 0.0
    # moving away: SoftSPL is clipped at 0
    assert EpisodeOutcome(d0=2.0, d_end=3.0, path=1.0, stopped=False).soft_spl == 0.0
    with pytest.raises(ValueError, match="d0"):
        EpisodeOutcome(d0=0.0, d_end=0.0, path=0.0, stopped=True)


def test_confidence_intervals():
    ci = mean_ci(np.array([1.0] * 95 + [0.0] * 5), binary=True)
    assert ci.mean == 0.95 and 0.88 < ci.low < 0.90 and 0.97 < ci.high < 0.99  # Wilson
    all_ok = mean_ci(np.ones(20), binary=True)
    assert all_ok.high == pytest.approx(1.0) and all_ok.low < 0.9  # not degenerate at 100 %
    for n in range(1, 301):  # 0 or n of n: the bounds contain the mean exactly (error bars >= 0)
        none, every = mean_ci(np.zeros(n), binary=True), mean_ci(np.ones(n), binary=True)
        assert none.low <= none.mean == 0.0 < none.high and every.low < every.mean == 1.0 <= every.high
    spl = mean_ci(np.array([0.5, 0.7, 0.9, 0.6]))
    assert spl.low < 0.675 < spl.high and spl.n == 4
    assert np.isnan(mean_ci(np.array([])).mean)
    zeros = mean_ci(np.zeros(5))  # SPL of five failures: no spread, not a Bernoulli interval
    assert zeros.low == zeros.high == 0.0
    with pytest.raises(ValueError, match="0 or 1"):
        mean_ci(np.array([0.5]), binary=True)


def test_the_final_belief_error_is_the_distance_between_the_last_true_and_believed_positions():
    from odolab.navigation.metrics import belief_error
    from odolab.navigation.report import summarize

    row = {
        "odometer": "x",
        "true_xy": [[0, 0], [1, 0], [2, 0]],
        "believed_xy": [[0, 0], [1, 0.5], [2, 3.0]],
        "success": 1,
        "spl": 0.5,
        "soft_spl": 0.5,
        "d_end": 0.1,
        "steps": 2,
        "collisions": 0,
        "failed_steps": 0,
        "path": 2.0,
        "stopped": True,
    }
    assert belief_error(row) == 3.0
    other = {**row, "believed_xy": [[0, 0], [1, 0], [6, 3.0]]}  # 3-4-5
    short = {**row, "path": 0.5, "stopped": False, "success": 0}  # too short for the drift per metre
    table = summarize([row, other, short], ["x"])
    assert abs(table[0]["belief_error"] - 11 / 3) < 1e-12 and table[0]["belief_error_low"] >= 0.0
    assert table[0]["drift_per_m"] == 2.0  # the median of 3 m / 2 m and 5 m / 2 m
    assert (table[0]["stopped_elsewhere"], table[0]["ran_out"]) == (0, 1)
