"""Write a comparison to a folder: CSV tables, figures, an HTML page and every trajectory.

Layout of ``DIR``::

    table.csv              one row per odometer (columns: odolab.summary.Row)
    table_per_action.csv   per-step error per odometer and action
    errors.png             per-step error bars per odometer and action
    trajectories.png       top-down true vs estimated trajectories
    report.html            all of the above on one page, with the definitions
    trajectories/<sequence>/<odometer>.{tum,kitti}   and groundtruth.{tum,kitti}
"""
from __future__ import annotations

import csv
import html
import io
import re
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from odolab.io.atomic import save_figure_atomic, write_text_atomic
from odolab.io.kitti import write_kitti_poses
from odolab.io.tum import write_tum_trajectory
from odolab.runner import SequenceResult
from odolab.summary import ActionRow, Row
from odolab.trajectory import Trajectory

_ACTION_COLORS = {"move_forward": "#4C72B0", "turn_left": "#DD8452", "turn_right": "#55A868"}


def _csv(rows: list, cls) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    names = [f.name for f in fields(cls)]
    w.writerow(names)
    for r in rows:
        d = asdict(r)
        w.writerow([f"{d[n]:.6g}" if isinstance(d[n], float) else d[n] for n in names])
    return buf.getvalue()


def format_table(rows: list[Row], real_data: bool = False) -> str:
    """A fixed-width text table for the terminal."""
    if real_data:
        head = f"{'odometer':<38} {'trans mm':>9} {'rot deg':>8} {'fps':>8} {'failures':>8}"
        lines = [f"{r.odometer + (' (oracle)' if r.oracle else ''):<38} {r.trans_mm:9.2f} {r.rot_deg:8.3f} "
                 f"{r.fps:8.1f} {r.failures:8d}" for r in rows]
    else:
        head = (f"{'odometer':<38} {'dx':>7} {'dz':>7} {'dyaw':>7} {'ATE m':>7} {'drift m':>8} "
                f"{'fps':>8} {'failures':>8}")
        lines = [f"{r.odometer + (' (oracle)' if r.oracle else ''):<38} {r.dx:7.2f} {r.dz:7.2f} {r.dyaw:7.2f} "
                 f"{r.ate_m:7.3f} {r.drift_m:8.3f} {r.fps:8.1f} {r.failures:8d}" for r in rows]
    return "\n".join([head, "-" * len(head), *lines])


def plot_errors(action_rows: list[ActionRow], path: Path) -> None:
    """Grouped bars: per-step error (x 1e-2) of each odometer, one bar per action, one panel per axis."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(dict.fromkeys(r.odometer for r in action_rows))
    actions = list(dict.fromkeys(r.action for r in action_rows))
    fig, axes = plt.subplots(1, 4, figsize=(max(12, 2.6 * len(names)), 4.4))
    x = np.arange(len(names))
    width = 0.8 / max(len(actions), 1)
    panels = [("dx", "mean |error| of dx (x1e-2 m)", "per-step error: dx"),
              ("dz", "mean |error| of dz (x1e-2 m)", "per-step error: dz"),
              ("dyaw", "mean |error| of dyaw (x1e-2 rad)", "per-step error: dyaw"),
              ("failed", "failed steps (% of the action's steps)", "failures (prior used instead)")]
    for ax, (comp, ylabel, title) in zip(axes, panels):
        for k, a in enumerate(actions):
            vals = []
            for n in names:
                row = next((r for r in action_rows if r.odometer == n and r.action == a), None)
                vals.append(np.nan if row is None else
                            100.0 * row.failures / row.steps if comp == "failed" else getattr(row, comp))
            ax.bar(x + (k - (len(actions) - 1) / 2) * width, vals, width, label=a,
                   color=_ACTION_COLORS.get(a))
        ax.set_xticks(x, names, rotation=30, ha="right", fontsize=8)
        ax.set_ylabel(ylabel)
        ax.set_title(title)
        ax.grid(True, axis="y", alpha=0.3)
    axes[0].legend(title="action", fontsize=8)
    fig.tight_layout()
    save_figure_atomic(fig, path)
    plt.close(fig)


@dataclass(frozen=True)
class FloorPlan:
    """A top-down occupancy image to draw under trajectories: ``free`` (rows, cols) bool, cell
    (r, c) at world x = origin[0] + c * resolution, y = origin[1] + r * resolution (metres)."""

    free: np.ndarray
    origin: tuple[float, float]
    resolution: float


def plot_trajectories(results: list[SequenceResult], path: Path, max_sequences: int = 4,
                      plans: dict[str, FloorPlan] | None = None) -> None:
    """Top-down (world X, Y in metres) true vs integrated trajectories of the first sequences,
    over the floor plan of each sequence when ``plans`` has one (free = white, obstacles = grey)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    seqs = list(dict.fromkeys(r.sequence for r in results if r.gt_poses is not None))[:max_sequences]
    if not seqs:
        return
    cols = min(2, len(seqs))
    rows = int(np.ceil(len(seqs) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(6.0 * cols, 5.2 * rows), squeeze=False)
    cmap = plt.get_cmap("tab10")
    names = list(dict.fromkeys(r.odometer for r in results))
    for ax, seq in zip(axes.flat, seqs):
        mine = [r for r in results if r.sequence == seq]
        gt = mine[0].gt_poses[:, :3, 3]
        plan = (plans or {}).get(seq)
        if plan is not None:
            h, w = plan.free.shape
            extent = (plan.origin[0], plan.origin[0] + w * plan.resolution,
                      plan.origin[1], plan.origin[1] + h * plan.resolution)
            ax.imshow(np.where(plan.free, 1.0, 0.75), cmap="gray", vmin=0, vmax=1, origin="lower",
                      extent=extent, interpolation="nearest")
        ax.plot(gt[:, 0], gt[:, 1], "k-", lw=2.5, label="ground truth")
        ax.plot(gt[0, 0], gt[0, 1], "ko", ms=7)
        for r in mine:
            if r.odometer == "ground-truth":
                continue
            p = r.poses[:, :3, 3]
            ax.plot(p[:, 0], p[:, 1], "-", lw=1.3, color=cmap(names.index(r.odometer) % 10), label=r.odometer)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("world x (m)")
        ax.set_ylabel("world y (m)")
        ax.set_title(f"{seq}: {len(gt) - 1} steps (start = dot)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    for ax in list(axes.flat)[len(seqs):]:
        ax.axis("off")
    fig.tight_layout()
    save_figure_atomic(fig, path)
    plt.close(fig)


def write_trajectories(results: list[SequenceResult], out: Path) -> None:
    """Every estimated trajectory and each ground truth, in TUM and KITTI formats."""
    for r in results:
        d = out / "trajectories" / r.sequence
        d.mkdir(parents=True, exist_ok=True)
        stamps = r.timestamps if r.timestamps is not None else np.arange(len(r.poses), dtype=float)
        todo = [(r.odometer, r.poses)]
        if r.gt_poses is not None:
            todo.append(("groundtruth", r.gt_poses))
        for name, poses in todo:
            name = re.sub(r"[^A-Za-z0-9_.+-]", "_", name)  # "module:Class" names make portable files
            write_tum_trajectory(d / f"{name}.tum", Trajectory(stamps, poses))
            # KITTI: poses relative to the first camera (camera i -> camera 0)
            write_kitti_poses(d / f"{name}.kitti", Trajectory(None, np.linalg.inv(poses[0]) @ poses))


def _html_table(rows: list, cls) -> str:
    names = [f.name for f in fields(cls)]
    head = "".join(f"<th>{html.escape(n)}</th>" for n in names)
    body = ""
    for r in rows:
        d = asdict(r)
        cells = "".join(f"<td>{d[n]:.3f}</td>" if isinstance(d[n], float) else f"<td>{html.escape(str(d[n]))}</td>"
                        for n in names)
        body += f"<tr>{cells}</tr>\n"
    return f"<table><tr>{head}</tr>\n{body}</table>"


def write_report(out: Path, rows: list[Row], action_rows: list[ActionRow], results: list[SequenceResult],
                 title: str, notes: list[str], plans: dict[str, FloorPlan] | None = None) -> None:
    """Write the tables, figures, trajectories and ``report.html`` into ``out``."""
    from odolab.summary import __doc__ as definitions

    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / "table.csv", _csv(rows, Row))
    write_text_atomic(out / "table_per_action.csv", _csv(action_rows, ActionRow))
    figures = []
    if action_rows:
        plot_errors(action_rows, out / "errors.png")
        figures.append(("Per-step error by odometer and action", "errors.png"))
    plot_trajectories(results, out / "trajectories.png", plans=plans)
    if (out / "trajectories.png").exists():
        figures.append(("Top-down trajectories: ground truth vs each odometer", "trajectories.png"))
    write_trajectories(results, out)
    failures = [f"<li>{html.escape(r.odometer)} on {html.escape(r.sequence)}: {html.escape(e)}</li>"
                for r in results for e in r.errors]
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto}} table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:3px 6px;text-align:right}} th{{background:#eee}}</style></head><body>
<h1>{html.escape(title)}</h1>
<ul>{''.join(f'<li>{html.escape(n)}</li>' for n in notes)}</ul>
<h2>Summary</h2>{_html_table(rows, Row)}
<h2>Per action</h2>{_html_table(action_rows, ActionRow)}
{''.join(f'<h2>{html.escape(t)}</h2><img src="{f}" style="max-width:100%">' for t, f in figures)}
<h2>Definitions</h2><pre>{html.escape(definitions or '')}</pre>
<h2>Exceptions raised by odometers (first few)</h2><ul>{''.join(failures) or '<li>none</li>'}</ul>
<p>Trajectories (TUM and KITTI formats) are in <code>trajectories/</code>.</p>
</body></html>
"""
    write_text_atomic(out / "report.html", page)
