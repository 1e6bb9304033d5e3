"""odolab/navigation/report.py: each composite against its inputs on the same episodes."""

from __future__ import annotations

from odolab.navigation.report import paired_markdown, paired_rows


def _row(odometer: str, episode: int, success: bool, spl: float, belief: float) -> dict:
    return {"odometer": odometer, "split": "test", "seed": 0, "episode": episode, "success": success} | {
        "spl": spl,
        "belief_error": belief,
    }


def test_a_composite_is_judged_against_each_input_on_the_episodes_both_ran():
    rows = [_row("icp", k, k < 2, 0.1, 1.0 + 0.01 * k) for k in range(20)]
    rows += [_row("denoised(icp)", k, k < 14, 0.5, 0.2 + 0.01 * (k % 3)) for k in range(19)]  # one episode fewer
    rows += [_row("open3d-rgbd", k, True, 0.6, 0.3) for k in range(20)]
    (pair,) = paired_rows(rows, ["icp", "denoised(icp)", "open3d-rgbd"])
    assert (pair["composite"], pair["input"], pair["episodes"]) == ("denoised(icp)", "icp", 19)
    assert (pair["composite_only"], pair["input_only"], pair["success"]) == (12, 0, "higher")
    assert pair["spl"] == "higher" and pair["belief"] == "lower" and abs(pair["spl_diff"] - 0.4) < 1e-9
    even = paired_rows([_row("a", 0, True, 0.5, 0.1), _row("manhattan(a)", 0, False, 0.0, 0.1)], ["a", "manhattan(a)"])
    assert even[0]["success"] == "undecided" and even[0]["spl"] == "undecided"  # one episode: no interval
    assert "| denoised(icp) - icp | 19 | 12 / 0 (p = " in paired_markdown([pair]) and paired_markdown([]) == ""
