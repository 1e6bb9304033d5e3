"""odolab/core/progress.py: the step progress bar keeps its width and shows each odometer's own rate."""

from __future__ import annotations

import io

import pytest


@pytest.mark.parametrize("total", [1000, None])
def test_the_progress_bar_keeps_its_width_and_shows_each_odometers_own_rate(total):
    from odolab.core.progress import StepProgressBar

    now = [0.0]
    bar = StepProgressBar(file=io.StringIO(), clock=lambda: now[0])
    bar.start(total)
    widths, texts = set(), []
    for name, steps, seconds in [
        ("feature-essential", 0, 0.0),
        ("feature-essential", 10, 0.862),
        ("icp", 0, 5.0),
        ("icp", 100, 0.775),
        ("fused(icp,open3d-rgbd,robust-vo)", 0, 0.0),
        ("fused(icp,open3d-rgbd,robust-vo)", 4, 2.0),
        ("ground-truth", 100, 1e-4),
        ("feature-essential", 0, 9.0),
        ("feature-essential", 10, 0.862),
    ]:
        now[0] += seconds
        bar.advance(name, steps)
        texts.append(str(bar._bar))
        widths.add(len(texts[-1]))
    assert len(widths) == 1, texts
    assert "11.6 step/s" in texts[1] and "129 step/s" in texts[3] and "2.00 step/s" in texts[5]
    assert "11.6 step/s" in texts[-1]  # the time before it started again (9 s) is not feature-essential's
    assert bar.rate("icp") == pytest.approx(100 / 0.775)
    bar.close()


def test_a_terminal_too_narrow_for_a_bar_gets_a_line_at_the_start_each_quarter_and_the_end(monkeypatch):
    from odolab.core import progress

    class Narrow(io.StringIO):
        def isatty(self):
            return True

        def fileno(self):
            return 2

    monkeypatch.setattr(progress.os, "get_terminal_size", lambda fd: progress.os.terminal_size((0, 24)))
    out, now = Narrow(), [0.0]
    bar = progress.StepProgressBar(file=out, clock=lambda: now[0])
    assert bar.plain and not progress.plain_terminal(io.StringIO())  # a log file keeps tqdm's lines
    bar.start(100)
    for _ in range(10):
        now[0] += 1.0
        bar.advance("icp", 10)
    bar.close()
    assert out.getvalue().splitlines() == [
        "odometry steps: 100 to run",
        "odometry steps: 30/100 (25 %), icp",
        "odometry steps: 50/100 (50 %), icp",
        "odometry steps: 80/100 (75 %), icp",
        "odometry steps: 100 done in 10 s",
    ]
