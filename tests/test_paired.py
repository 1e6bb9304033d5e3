"""odolab/running/paired.py: paired differences of per-step error, their intervals and verdicts."""

from __future__ import annotations

import numpy as np
import pytest

from odolab.core.geometry import planar_to_transform
from odolab.core.stats import MeanCI, verdict
from odolab.core.types import Action
from odolab.running.paired import default_pairs, paired_differences, paired_verdicts
from odolab.running.runner import SequenceResult


def _result(odometer: str, sequence: str, errors: np.ndarray, actions: np.ndarray) -> SequenceResult:
    """A result whose planar estimates are the truth (0.25 m forward) plus ``errors`` (N, 3)."""
    n = len(errors)
    truth = np.stack([planar_to_transform(0.0, 0.25, 0.0)] * n)
    est = np.stack([planar_to_transform(*(np.array([0.0, 0.25, 0.0]) + e)) for e in errors])
    return SequenceResult(
        odometer=odometer,
        sequence=sequence,
        oracle=False,
        estimates=est,
        truth=truth,
        poses=np.tile(np.eye(4), (n + 1, 1, 1)),
        gt_poses=np.tile(np.eye(4), (n + 1, 1, 1)),
        actions=actions,
        valid=np.ones(n, bool),
        step_seconds=np.zeros(n),
    )


ACTIONS = np.array([Action.MOVE_FORWARD.value] * 6 + [Action.TURN_LEFT.value] * 4, np.int8)


def _results(better: float, seeds=(0, 1, 2, 3, 4)) -> list[SequenceResult]:
    """'base' with errors around 1e-2 per component, 'fixed(base)' with ``better`` x them, 5 sequences."""
    out = []
    for s in seeds:
        e = np.random.default_rng(s).uniform(0.5e-2, 1.5e-2, (len(ACTIONS), 3))
        out += [_result("base", f"seq-{s}", e, ACTIONS), _result("fixed(base)", f"seq-{s}", better * e, ACTIONS)]
    return out


def test_default_pairs_are_each_composite_against_its_inputs_that_ran():
    names = ["icp", "denoised(icp)", "fused(icp,open3d-rgbd)", "corrected(robust-vo)"]
    assert default_pairs(names) == [("denoised(icp)", "icp"), ("fused(icp,open3d-rgbd)", "icp")]


def test_a_composite_that_halves_every_error_is_lower_on_every_component_and_action():
    rows = paired_differences(_results(0.5), [("fixed(base)", "base")])
    assert [(r.action, r.component) for r in rows[:3]] == [("all", "dx"), ("all", "dz"), ("all", "dyaw")]
    assert {r.action for r in rows} == {"all", "move_forward", "turn_left"}  # no turn_right step
    for r in rows:
        assert r.verdict == "lower" and r.high < 0 and r.low < r.diff < r.high and r.sequences == 5
    assert next(r for r in rows if r.action == "turn_left").steps == 20
    # the difference is x 1e-2: half of errors of about 1e-2 is about -0.5
    assert -0.6 < rows[0].diff < -0.4


def test_an_unchanged_odometer_is_undecided_and_one_sequence_gives_no_interval():
    same = paired_differences(_results(1.0), [("fixed(base)", "base")])
    assert all(r.diff == 0 and r.verdict == "undecided" for r in same)
    one = paired_differences(_results(0.5, seeds=(0,)), [("fixed(base)", "base")])
    assert all(np.isnan(r.low) and r.verdict == "undecided" for r in one)  # one sequence: no interval


def test_a_worse_composite_is_higher_and_the_console_line_says_so():
    rows = paired_differences(_results(2.0), [("fixed(base)", "base")])
    assert all(r.verdict == "higher" for r in rows)
    (line,) = paired_verdicts(rows)
    assert line.startswith("fixed(base) against base, paired on 50 steps, x 1e-2: dx +")
    assert line.count("higher") == 3


def test_two_odometers_that_saw_other_steps_are_not_paired():
    results = _results(0.5)
    results[1] = _result("fixed(base)", "seq-0", np.zeros((len(ACTIONS), 3)), ACTIONS[::-1].copy())
    with pytest.raises(ValueError, match="saw different steps on seq-0"):
        paired_differences(results, [("fixed(base)", "base")])


def test_verdict_needs_the_whole_interval_on_one_side_of_zero():
    assert verdict(MeanCI(-1.0, -2.0, -0.1, 5)) == "lower"
    assert verdict(MeanCI(1.0, 0.1, 2.0, 5)) == "higher"
    assert verdict(MeanCI(-1.0, -2.0, 0.0, 5)) == "undecided"
    assert verdict(MeanCI(-1.0, float("nan"), float("nan"), 1)) == "undecided"
