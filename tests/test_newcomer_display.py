"""What a newcomer sees: no Ray notice for a cluster they never started, a progress bar that keeps
its layout and shows each odometer's own rate, and figures whose colours, scales, legends and
labels can be read (issue 42)."""

from __future__ import annotations

import io
import logging
import os
import subprocess
import sys
from pathlib import Path

import matplotlib
import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import to_rgb

matplotlib.use("Agg")

ROOT = Path(__file__).resolve().parents[1]


def _captured_figure(monkeypatch, module) -> list:
    """Make ``module.save_figure_atomic`` keep the figure instead of writing it."""
    figures: list = []
    monkeypatch.setattr(module, "save_figure_atomic", lambda fig, path: figures.append(fig))
    return figures


# -- Ray ---------------------------------------------------------------------------------------


def test_a_local_ray_start_prints_no_token_notice():
    code = (
        "from odolab.parallel import Execution, fan_out\n"
        "def neg(x):\n    return -x\n"
        "assert fan_out(neg, [1, 2], execution=Execution(progress=True)) == [-1, -2]\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("RAY_AUTH_MODE", "RAY_ADDRESS")}
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, env=env, timeout=120, check=False
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Token authentication" not in proc.stdout + proc.stderr


def test_token_notices_are_kept_for_a_users_cluster_and_hidden_for_a_local_one(caplog):
    from odolab.parallel import _TOKEN_NOTICES, _token_notices_hidden

    notices = logging.getLogger(_TOKEN_NOTICES)
    for local, quiet, shown in ((True, False, False), (False, True, False), (False, False, True)):
        caplog.clear()
        with caplog.at_level(logging.WARNING), _token_notices_hidden(local=local, quiet=quiet):
            notices.warning("Token authentication is enabled for this Ray cluster.")
            notices.error("an error always passes")
        messages = [r.getMessage() for r in caplog.records]
        assert ("Token authentication is enabled for this Ray cluster." in messages) is shown
        assert "an error always passes" in messages
    assert not notices.filters


# -- progress bar ------------------------------------------------------------------------------


@pytest.mark.parametrize("total", [1000, None])
def test_the_progress_bar_keeps_its_width_and_shows_each_odometers_own_rate(total):
    from odolab.progress import StepProgressBar

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


# -- figures -----------------------------------------------------------------------------------


def _grey(color) -> bool:
    r, g, b = to_rgb(color)
    return max(r, g, b) - min(r, g, b) < 0.15


def test_top_down_trajectories_never_take_the_obstacles_grey_and_show_start_end_and_goal(monkeypatch):
    from odolab import report
    from odolab.runner import SequenceResult

    obstacle = (report.OBSTACLE_SHADE,) * 3
    for k in range(40):
        color, style = report.trajectory_style(k)
        assert not _grey(color) and to_rgb(color) != obstacle and style
    n = 6
    poses = np.tile(np.eye(4), (n + 1, 1, 1))
    poses[:, 0, 3] = np.linspace(0.0, 1.0, n + 1)
    names = ["ground-truth"] + [f"odometer-{k}" for k in range(13)]

    def result(name: str, shift: float) -> SequenceResult:
        mine = poses.copy()
        mine[:, 1, 3] = shift * np.arange(n + 1)
        return SequenceResult(
            odometer=name,
            sequence="seq",
            oracle=False,
            estimates=np.tile(np.eye(4), (n, 1, 1)),
            truth=None,
            poses=mine,
            gt_poses=poses,
            actions=np.zeros(n, np.int8),
            valid=np.ones(n, bool),
            step_seconds=np.zeros(n),
        )

    plan = report.FloorPlan(np.ones((40, 40), bool), (-1.0, -1.0), 0.1, goal=(20.0, 0.0))
    figures = _captured_figure(monkeypatch, report)
    report.plot_sequence([result(name, 0.01 * k) for k, name in enumerate(names)], Path("x.png"), names, plan)
    (ax,) = figures[0].axes
    drawn = [line.get_color() for line in ax.get_lines() if line.get_label() in names[1:]]
    assert len(drawn) == 13 and not any(_grey(c) for c in drawn)
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "start" in labels and any(t.startswith("end") for t in labels) and any("goal" in t for t in labels)
    assert any("goal 19.0 m" in t.get_text() for t in ax.texts)  # off view: an arrow with its distance


def _action_rows():
    from odolab.summary import ActionRow

    rows = []
    for name, scale in (("action-prior", 1.0), ("icp", 0.4)):
        for action, steps, dz in (
            ("move_forward", 123, 4.4),
            ("turn_left", 43, 1.2),
            ("turn_right", 59, 1.1),
            ("move_forward_collided", 11, 16.7),
        ):
            e = dz * scale
            rows.append(ActionRow(name, action, e, e, e, e, e, e, steps, 0, 0.0, 0.0, 0.0))
    return rows


def test_the_error_bars_are_not_squashed_by_the_few_collided_steps(monkeypatch):
    from odolab import report

    figures = _captured_figure(monkeypatch, report)
    report.plot_errors(_action_rows(), Path("errors.png"))
    axes = figures[0].axes
    for ax in axes[:3]:
        assert "as used" in ax.get_title() and "as used" in ax.get_ylabel()
        top = ax.get_ylim()[1]
        assert 4.4 < top < 16.7 / 2  # the usual bars fill the panel; the collided one is cut
        assert "16.7" in [t.get_text() for t in ax.texts]  # and carries its value
    labels = [t.get_text() for t in axes[0].get_legend().get_texts()]
    assert "move_forward (n=123)" in labels and "move_forward_collided (n=11)" in labels


def test_the_navigation_metrics_legend_hides_no_bar(monkeypatch):
    from odolab.navigation import report as nav_report

    table = []
    for k, name in enumerate(["ground-truth", "icp", "manhattan(fused(open3d-rgbd,robust-vo,planar-depth))"]):
        row = {"odometer": name, "episodes": 100}
        for m in ("success", "spl", "soft_spl"):
            value = 0.95 if k == 2 else 0.5
            row.update({m: value, f"{m}_low": value - 0.05, f"{m}_high": min(value + 0.05, 1.0)})
        table.append(row)
    figures = _captured_figure(monkeypatch, nav_report)
    nav_report.metrics_figure(table, Path("metrics.png"))
    fig = figures[0]
    (ax,) = fig.axes
    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.draw(renderer)
    legend, frame = ax.get_legend().get_window_extent(renderer), ax.get_window_extent(renderer)
    assert not legend.overlaps(frame)


def test_noise_growth_labels_show_small_growth():
    from studies.noise_robustness import growth_label

    assert growth_label(2.25, 2.34) == "+4.0 %"
    assert growth_label(1.15, 1.20) == "+4.3 %"
    assert growth_label(0.55, 0.74) == "+35 %"
    assert growth_label(2.0, 1.96) == "-2.0 %"
    assert growth_label(1.41, 1.41) == "0.0 %"
    assert growth_label(0.0, 1.0) == ""
