"""odolab/running/summary.py: zero-step sequences, steps/s of steps never asked, the cell formatter, the bias and the paper's protocol (raw) columns."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

from odolab.running import summary
from odolab.running.runner import SequenceResult


def _result(n: int, odometer: str = "odo", seconds: float = 0.0, asked: bool | None = True) -> SequenceResult:
    """A result of ``n`` steps standing still on a true path that stands still too."""
    return SequenceResult(
        odometer=odometer,
        sequence=f"seq-{n}",
        oracle=False,
        estimates=np.tile(np.eye(4), (n, 1, 1)),
        truth=np.tile(np.eye(4), (n, 1, 1)),
        poses=np.tile(np.eye(4), (n + 1, 1, 1)),
        gt_poses=np.tile(np.eye(4), (n + 1, 1, 1)),
        actions=np.zeros(n, np.int8),
        valid=np.full(n, asked is not False),
        step_seconds=np.full(n, seconds),
        asked=None if asked is None else np.full(n, asked),
    )


def test_a_sequence_of_one_frame_gives_a_row_of_dashes_not_a_traceback():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "mean of empty slice" either
        (row,) = summary.summarize([_result(0)])
    assert row.steps == 0 and row.failures == 0 and row.failure_share == 0.0
    assert all(np.isnan(v) for v in (row.dx, row.dz_std, row.dyaw_own, row.trans_mm, row.fps))
    assert summary.fmt(row.dx, ".2f", row.dx_std) == "-" and summary.summarize_actions([_result(0)]) == []


def test_steps_per_second_count_only_the_steps_asked():
    (never,) = summary.summarize([_result(5, asked=False)])  # reset failed: no step was timed
    assert np.isnan(never.fps) and summary.fmt(never.fps, ".1f") == "-"
    (half,) = summary.summarize([_result(4, seconds=0.5), _result(6, asked=False)])
    assert half.fps == pytest.approx(2.0)  # 4 steps in 2 s, not 10
    (unrecorded,) = summary.summarize([_result(4, seconds=0.25, asked=None)])  # results made elsewhere
    assert unrecorded.fps == pytest.approx(4.0)


@pytest.mark.parametrize(
    "value,std,text",
    [
        (1.23456, None, "1.235"),
        (1.23456, 0.5, "1.235 +- 0.500"),
        (1.0, float("nan"), "1.000"),
        (float("nan"), None, "-"),
        (None, None, "-"),
        (float("inf"), 1.0, "inf"),
        (-float("inf"), None, "-inf"),
        (1e300, None, "1e+300"),
        (2.5e12, 1e10, "2.5e+12 +- 1e+10"),
        (999_999_999.0, None, "999999999.000"),
    ],
)
def test_fmt_says_does_not_apply_overflow_and_huge_apart(value, std, text):
    assert summary.fmt(value, ".3f", std) == text


def test_the_bias_is_the_signed_mean_error_which_cancels_where_the_absolute_error_does_not():
    from odolab.core.geometry import planar_to_transform

    def moved(dz_errors: list[float], name: str) -> SequenceResult:
        r = _result(len(dz_errors), odometer=name)
        est = np.stack([planar_to_transform(0.0, 0.25 + e, -0.01) for e in dz_errors])
        truth = np.stack([planar_to_transform(0.0, 0.25, 0.0)] * len(dz_errors))
        return dataclasses.replace(r, estimates=est, truth=truth, actions=np.ones(len(dz_errors), np.int8))

    steady, alternating = summary.summarize([moved([0.01] * 4, "steady"), moved([0.01, -0.01] * 2, "alternating")])
    assert steady.dz == pytest.approx(1.0) and steady.dz_bias == pytest.approx(1.0)
    assert alternating.dz == pytest.approx(1.0) and alternating.dz_bias == pytest.approx(0.0, abs=1e-9)
    assert steady.dyaw_bias == pytest.approx(-1.0) and steady.dx_bias == pytest.approx(0.0, abs=1e-9)
    (action,) = summary.summarize_actions([moved([0.01] * 4, "steady")])  # every step a forward step
    assert action.dz_bias == pytest.approx(1.0)


def test_the_papers_protocol_scores_a_refused_steps_unverified_motion_and_counts_steps_with_none():
    """Four forward steps: answered (dz off by 1 cm), refused with an unverified motion (off by 3 cm),
    refused with nothing computed, and refused with a motion that is no rigid motion. As used, the
    three refused steps keep the prior's motion (here exact); raw, the second scores its own 3 cm and
    the last two stay with the prior and count in ``raw_missing``."""
    from odolab.core.geometry import planar_to_transform
    from odolab.core.types import Estimate

    truth = planar_to_transform(0.0, 0.25, 0.0)
    off = {k: planar_to_transform(0.0, 0.25 + k * 0.01, 0.0) for k in (1, 3)}
    nan = np.full((4, 4), np.nan)
    answers = (Estimate(off[1]), Estimate.invalid(off[3]), Estimate.invalid(), Estimate.invalid(nan))
    r = dataclasses.replace(
        _result(4),
        estimates=np.stack([off[1], truth, truth, truth]),
        truth=np.stack([truth] * 4),
        actions=np.ones(4, np.int8),
        valid=np.array([True, False, False, False]),
        raw=answers,
    )
    (row,) = summary.summarize([r])
    assert row.dz == pytest.approx(1.0 / 4) and row.dz_own == pytest.approx(1.0)
    assert row.dz_raw == pytest.approx((1.0 + 3.0) / 4) and row.raw_missing == 2
    (action,) = summary.summarize_actions([r])
    assert action.dz_raw == pytest.approx(row.dz_raw) and action.raw_missing == 2
    T, missing = summary.raw_estimates(r)
    assert missing.tolist() == [False, False, True, True] and np.array_equal(T[1], off[3])


def test_a_refused_estimate_keeps_its_own_copy_of_the_unverified_motion():
    from odolab.core.types import Estimate
    from odolab.odometry.odometer import own_copy

    motion = np.eye(4)
    kept = own_copy(Estimate.invalid(motion))
    motion[0, 3] = 5.0  # the odometer reuses its array
    assert kept.unverified[0, 3] == 0.0 and not kept.valid


def test_an_unverified_motion_that_is_no_rigid_motion_counts_as_missing_and_never_raises():
    from odolab.core.types import Estimate

    class Raising:
        def __array__(self, *args, **kwargs):
            raise RuntimeError("boom")

    odd = [
        Raising(),
        np.eye(4) * (1 + 1j),
        np.eye(4, dtype=bool),
        np.eye(3),
        "eye",
        [[1, 0], [0, 1]],
        np.full((4, 4), np.nan),
    ]
    n = len(odd) + 1
    r = dataclasses.replace(
        _result(n), valid=np.zeros(n, bool), raw=(*(Estimate.invalid(u) for u in odd), Estimate.invalid(np.eye(4)))
    )
    T, missing = summary.raw_estimates(r)
    assert missing.tolist() == [True] * len(odd) + [False]  # only the last one, a float 4x4 rigid motion, counts
    assert np.array_equal(T[-1], np.eye(4))
    (row,) = summary.summarize([r])
    assert row.raw_missing == len(odd)
