"""Figures of trajectory evaluations (matplotlib, Agg backend; imported only when plotting)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from odolab.io.atomic import save_figure_atomic

if TYPE_CHECKING:
    from odolab.running.scoring import Evaluation

__all__ = ["IMAGE_SUFFIXES", "plot_evaluations", "time_axis_label", "top_down_axes"]

#: Image types :func:`plot_evaluations` writes (matplotlib's Agg backend and Pillow), by extension.
IMAGE_SUFFIXES = ("png", "pdf", "svg", "jpg", "jpeg", "eps", "ps", "tif", "tiff", "webp")

_AXIS_NAMES = ("x", "y", "z")


def top_down_axes(positions: np.ndarray) -> tuple[int, int]:
    """The two coordinate axes of largest spread (the flattest one is dropped), in index order.

    KITTI camera-0 frames (y down) give (x, z); TUM motion-capture frames (z up) usually (x, y).
    """
    spread = np.ptp(np.asarray(positions, dtype=np.float64), axis=0)
    a, b = sorted(int(i) for i in np.argsort(spread, kind="stable")[1:])
    return a, b


def time_axis_label(ev: Evaluation) -> str:
    """What the x axis of an error-over-time panel counts: seconds, steps (timestamps 0, 1, 2, ...:
    a simulated episode's), or the pose's line in the file (KITTI files have no timestamps)."""
    if ev.times is None:
        return "pose index (line of the file; KITTI files have no timestamps)"
    if ev.step_stamps:
        return "step (the files' timestamps count steps: 0, 1, 2, ...)"
    return "time [s]"


def plot_evaluations(path: str | os.PathLike, rows: Sequence[tuple[str, Evaluation]]) -> None:
    """Write one figure for ``(label, evaluation)`` rows sharing a ground truth.

    Panels: aligned estimates over the ground truth, top-down (m); position error (m) over time
    (s), step or pose index (:func:`time_axis_label`); KITTI translational drift (%) per segment length, or, when no segment
    fits (short trajectories), the RPE translation (m) over time. The image format follows the
    file extension; the file is replaced atomically.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_traj, ax_ate, ax_rel) = plt.subplots(1, 3, figsize=(17, 5.2), constrained_layout=True)
    gt_pos = rows[0][1].gt_poses[:, :3, 3]
    a, b = top_down_axes(gt_pos)
    ax_traj.plot(gt_pos[:, a], gt_pos[:, b], "k--", lw=1.2, label="ground truth")
    has_segments = any(ev.kitti.n_segments for _, ev in rows)
    xlabel = time_axis_label(rows[0][1])
    for name, ev in rows:
        pos = ev.est_poses[:, :3, 3]
        x = ev.times if ev.times is not None else np.arange(len(pos))
        ax_traj.plot(pos[:, a], pos[:, b], lw=1.0, label=f"{name} (align {ev.ate.align})")
        ax_ate.plot(x, ev.ate.errors, lw=0.8, label=f"{name}: RMSE {ev.ate.rmse:.4f} m")
        if has_segments:
            per = ev.kitti.per_length
            ax_rel.plot(
                [s.length for s in per], [s.t_rel for s in per], "o-", label=f"{name}: t_rel {ev.kitti.t_rel:.3f} %"
            )
        else:
            ax_rel.plot(
                x[ev.rpe.pairs[:, 1]], ev.rpe.trans_errors, lw=0.8, label=f"{name}: RMSE {ev.rpe.trans.rmse:.4f} m"
            )
    ax_traj.set(title="Trajectories, top-down", xlabel=f"{_AXIS_NAMES[a]} [m]", ylabel=f"{_AXIS_NAMES[b]} [m]")
    ax_traj.set_aspect("equal", adjustable="datalim")
    ax_ate.set(title="Absolute position error (ATE)", xlabel=xlabel, ylabel="error [m]")
    if has_segments:
        ax_rel.set(
            title="KITTI translational drift per segment length", xlabel="segment length [m]", ylabel="t_rel [%]"
        )
    else:
        ev0 = rows[0][1]
        unit = "frames" if ev0.rpe.delta_unit == "f" else "m"
        ax_rel.set(title=f"RPE translation (delta {ev0.rpe.delta:g} {unit})", xlabel=xlabel, ylabel="error [m]")
    for ax in (ax_traj, ax_ate, ax_rel):
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    save_figure_atomic(fig, path)
    plt.close(fig)
