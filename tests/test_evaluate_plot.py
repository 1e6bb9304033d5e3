"""``python -m odolab.evaluate --plot`` (odolab/cli/evaluate.py, odolab/reporting/trajectory_plot.py): the figure
never replaces an input, its path is checked before work, and its time axis says what the files' stamps
count."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from odolab.cli.args import run_cli
from odolab.core.trajectory import Trajectory
from odolab.evaluate import main
from odolab.io.kitti import write_kitti_poses
from odolab.io.tum import write_tum_trajectory
from odolab.running.scoring import evaluate_trajectory, pair_trajectories, stamps_are_steps
from tests.helpers import TUM_OK, one_line_error

PROG = "python -m odolab.evaluate"


def _poses(n: int, wobble: float = 0.0) -> np.ndarray:
    """A curved planar path of ``n`` poses (m), the estimate's with a small ``wobble``."""
    poses = np.tile(np.eye(4), (n, 1, 1))
    k = np.arange(n)
    poses[:, 0, 3] = np.sin(k / 3.0) + wobble * np.cos(k)
    poses[:, 1, 3] = 0.2 * k
    poses[:, 2, 3] = 0.1 * np.cos(k / 2.0)
    return poses


def _tum_pair(folder: Path, stamps: np.ndarray, names: tuple[str, str] = ("gt.tum", "est.tum")) -> tuple[Path, Path]:
    gt, est = folder / names[0], folder / names[1]
    write_tum_trajectory(gt, Trajectory(stamps, _poses(len(stamps))))
    write_tum_trajectory(est, Trajectory(stamps, _poses(len(stamps), 0.01)))
    return gt, est


@pytest.mark.parametrize("which", ["gt", "est", "est link", "est hard link"])
def test_a_plot_that_would_replace_an_input_is_refused_in_one_line(tmp_path, capsys, which):
    gt, est = _tum_pair(tmp_path, np.arange(12.0), ("gt.png", "est.png"))  # inputs named like images
    plot = {"gt": gt, "est": est, "est link": tmp_path / "link.png", "est hard link": tmp_path / "hard.png"}[which]
    if which == "est link":
        plot.symlink_to(est)
    elif which == "est hard link":
        os.link(est, plot)
    before = gt.read_bytes(), est.read_bytes()
    assert run_cli(main, PROG, [str(gt), str(est), "--plot", str(plot)]) == 2
    captured = capsys.readouterr()
    role = "the ground truth" if which == "gt" else "an estimate"
    assert captured.err.count("\n") == 1 and f"--plot {plot}: expected a new image file, found {role}" in captured.err
    assert captured.out == ""  # refused before any work: no table
    assert (gt.read_bytes(), est.read_bytes()) == before


def test_step_stamps_are_told_from_seconds():
    assert stamps_are_steps(np.arange(5.0))
    assert not stamps_are_steps(np.arange(5.0) + 1305031102.0)  # a real recording's clock
    assert not stamps_are_steps(np.arange(5.0) * 0.1) and not stamps_are_steps(None)
    assert not stamps_are_steps(np.array([0.0]))


@pytest.mark.parametrize(
    "stamps,label",
    [
        (np.arange(12.0), "step (the files' timestamps count steps: 0, 1, 2, ...)"),
        (1305031102.0 + np.arange(12.0) / 30, "time [s]"),
        (None, "pose index (line of the file; KITTI files have no timestamps)"),
    ],
)
def test_the_plots_time_axis_says_what_it_counts(tmp_path, monkeypatch, stamps, label):
    from odolab.reporting import trajectory_plot

    if stamps is None:
        gt, est = tmp_path / "gt.kitti", tmp_path / "est.kitti"
        write_kitti_poses(gt, Trajectory(None, _poses(12)))
        write_kitti_poses(est, Trajectory(None, _poses(12, 0.01)))
    else:
        gt, est = _tum_pair(tmp_path, stamps)
    drawn = []
    monkeypatch.setattr(trajectory_plot, "save_figure_atomic", lambda fig, path: drawn.append(fig))
    assert main([str(gt), str(est), "--plot", str(tmp_path / "p.png")]) == 0
    (fig,) = drawn
    assert [ax.get_xlabel() for ax in fig.axes[1:]] == [label, label]  # ATE and RPE over the same axis


def test_evaluations_record_step_stamps():
    gt = Trajectory(np.arange(8.0), _poses(8))
    est = Trajectory(np.arange(8.0), _poses(8, 0.01))
    ev = evaluate_trajectory(gt, est, pair_trajectories(gt, est, "timestamp"))
    assert ev.step_stamps and np.array_equal(ev.times, np.arange(8.0))
    real_gt, real_est = Trajectory(gt.timestamps + 1e9, gt.poses), Trajectory(est.timestamps + 1e9, est.poses)
    assert not evaluate_trajectory(real_gt, real_est, pair_trajectories(real_gt, real_est, "timestamp")).step_stamps


def test_evaluate_plot_path_is_checked_before_work(tmp_path):
    gt = tmp_path / "gt.txt"
    gt.write_text(TUM_OK)
    one_line_error(
        "odolab.evaluate", gt, gt, "--format", "tum", "--plot", tmp_path / "fig.xyz", words="unknown file type '.xyz'"
    )
    one_line_error("odolab.evaluate", gt, gt, "--format", "tum", "--plot", tmp_path, words="is a folder, not a file")
    one_line_error(
        "odolab.evaluate", gt, gt, "--format", "tum", "--plot", tmp_path / "no" / "f.png", words="does not exist"
    )
    one_line_error("odolab.evaluate", gt, gt, "--format", "tum", "--plot", "/proc/f.png", words="cannot write in /proc")
