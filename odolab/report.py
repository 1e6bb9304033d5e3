"""Write a comparison to a folder: CSV tables, figures, an HTML page and every trajectory.

Layout of ``DIR``::

    table.csv              one row per odometer (columns: odolab.summary.Row)
    table_per_action.csv   per-step error per odometer and action (simulator runs), and on the
                           forward steps a collision blocked ("move_forward_collided")
    errors.png             per-step error bars per odometer and action (simulator runs)
    report.html            all of the above on one page, with the definitions and a gallery
    trajectories/<sequence>/top-down.png            true vs estimated trajectories, top-down
    trajectories/<sequence>/<odometer>.{tum,kitti}  every estimate, and groundtruth.{tum,kitti}
    manifest.txt           the files this run wrote (one per line)

``groundtruth.*`` holds the true poses; the ``ground-truth`` row integrates exactly these, so it
has no file of its own. A run removes the files that ``manifest.txt`` says the previous run into
the same folder wrote and it did not rewrite, and nothing else. Tables are written first: a
figure that fails is reported on the page and on stderr and costs nothing else.
"""
from __future__ import annotations

import csv
import html
import io
import re
import sys
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Callable

import numpy as np

from odolab.geometry import invert
from odolab.io.atomic import save_figure_atomic, write_text_atomic
from odolab.io.kitti import write_kitti_poses
from odolab.io.tum import write_tum_trajectory
from odolab.runner import SequenceResult
from odolab.summary import ActionRow, Row, fmt, text_table
from odolab.trajectory import Trajectory

_ACTION_COLORS = {"move_forward": "#4C72B0", "turn_left": "#DD8452", "turn_right": "#55A868",
                  "move_forward_collided": "#8C8C8C"}
MANIFEST = "manifest.txt"
#: Metres of floor plan shown around the trajectories in each top-down figure (with a plan).
ZOOM_MARGIN = 1.5
GROUND_TRUTH_FILE = "groundtruth"


def _safe(name: str) -> str:
    """A portable file name for an odometer or sequence name ("module:Class" -> "module_Class")."""
    return re.sub(r"[^A-Za-z0-9_.+-]", "_", name)


class OutputFolder:
    """The files one run writes under ``root``, listed in ``manifest.txt`` as they are written.

    On creation the files the previous run's manifest lists are removed (only those: never a file
    the manifest does not name, nothing outside ``root``), so the folder never mixes two runs; each
    :meth:`path` records its file in the manifest before the file is written, so an interrupted run
    leaves a manifest naming everything it wrote and the next run cleans it up.
    """

    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self.written: list[str] = []
        self.removed = self._remove_previous()

    def path(self, relative: str) -> Path:
        """The path of ``relative`` (its folder created), recorded as written by this run."""
        p = self.root / relative
        p.parent.mkdir(parents=True, exist_ok=True)
        if relative not in self.written:
            self.written.append(relative)
            self._write_manifest()
        return p

    def discard(self, relative: str) -> None:
        """Forget ``relative`` (a file that could not be written after all)."""
        if relative in self.written:
            self.written.remove(relative)
            self._write_manifest()

    def _write_manifest(self) -> None:
        write_text_atomic(self.root / MANIFEST, "".join(f"{rel}\n" for rel in sorted(self.written)))

    def _remove_previous(self) -> list[str]:
        try:
            lines = (self.root / MANIFEST).read_text(encoding="utf-8").splitlines()
        except (OSError, UnicodeDecodeError):
            return []
        removed = []
        # only plain relative paths inside the folder: a hostile manifest cannot delete elsewhere
        for rel in lines:
            if not rel or Path(rel).is_absolute() or ".." in Path(rel).parts or rel == MANIFEST:
                continue
            p = self.root / rel
            if p.is_file() and not p.is_symlink():
                p.unlink()
                removed.append(rel)
                for parent in p.parents:  # drop folders the removal emptied, up to the root
                    if parent == self.root or any(parent.iterdir()):
                        break
                    parent.rmdir()
        return removed

    def finish(self) -> list[str]:
        """Write the final manifest; returns what the previous run had and this one removed."""
        self._write_manifest()
        return self.removed


def _csv(rows: list, cls) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    names = [f.name for f in fields(cls)]
    w.writerow(names)
    for r in rows:
        d = asdict(r)
        w.writerow([f"{d[n]:.6g}" if isinstance(d[n], float) else d[n] for n in names])
    return buf.getvalue()


#: A summary column: short header (terminal), full header with units and alignment (HTML), cell.
Column = tuple[str, str, Callable[[Row], str]]


def summary_columns(rows: list[Row], real_data: bool, spread: bool = True) -> list[Column]:
    """The columns of the summary table; with ``spread``, ``+- std`` over sequences when there
    are several."""
    many = spread and any(r.sequences > 1 for r in rows)

    def sd(x: float) -> float | None:
        return x if many else None

    def name(r: Row) -> str:
        return r.odometer + (" (oracle)" if r.oracle else " (reference)" if r.reference else "")

    cols: list[Column] = [("odometer", "odometer", name)]
    if real_data:
        cols += [
            ("trans mm", "translation error, mm, per frame pair, as used", lambda r: fmt(r.trans_mm, ".2f")),
            ("rot deg", "rotation error, deg, per frame pair, as used", lambda r: fmt(r.rot_deg, ".3f")),
            ("own trans mm", "translation error, mm, on answered steps", lambda r: fmt(r.trans_mm_own, ".2f")),
            ("own rot deg", "rotation error, deg, on answered steps", lambda r: fmt(r.rot_deg_own, ".3f")),
        ]
    else:
        cols += [
            ("dx cm", "dx error, x1e-2 m, as used", lambda r: fmt(r.dx, ".2f", sd(r.dx_std))),
            ("dz cm", "dz error, x1e-2 m, as used", lambda r: fmt(r.dz, ".2f", sd(r.dz_std))),
            ("dyaw 1e-2rad", "dyaw error, x1e-2 rad, as used", lambda r: fmt(r.dyaw, ".2f", sd(r.dyaw_std))),
            ("own dx", "dx error, x1e-2 m, on answered steps", lambda r: fmt(r.dx_own, ".2f")),
            ("own dz", "dz error, x1e-2 m, on answered steps", lambda r: fmt(r.dz_own, ".2f")),
            ("own dyaw", "dyaw error, x1e-2 rad, on answered steps", lambda r: fmt(r.dyaw_own, ".2f")),
        ]
    cols += [
        ("failed %", "failed steps, % (prior used)", lambda r: f"{100 * r.failure_share:.1f}"),
        ("ATE m (no align)", "ATE, m, RMSE, no alignment", lambda r: fmt(r.ate_m, ".3f", sd(r.ate_std))),
    ]
    if not real_data:
        cols.append(("drift m", "final drift, m, no alignment", lambda r: fmt(r.drift_m, ".3f", sd(r.drift_std))))
    cols.append(("steps/s", "steps/s of step()", lambda r: fmt(r.fps, ".1f")))
    return cols


def table_caption(rows: list[Row], real_data: bool, spread: bool = True) -> str:
    """What the summary table's figures are: units, pooling, alignment, what "own" means."""
    many = spread and any(r.sequences > 1 for r in rows)
    what = ("Per frame pair: mean translation and rotation error of the relative pose" if real_data else
            "Per step: mean absolute error of (dx, dz, dyaw), x1e-2 (m, m, rad), pooled over all steps")
    return (f"{what}{'; +- is the standard deviation over sequences' if many else ''}. 'As used' scores a "
            "failed step with the action prior's motion that replaced it; 'own' leaves failed steps out "
            "(as the paper scored raw estimates) and must be read with the failure share. ATE: RMSE of the "
            "position error with no alignment (trajectories start at the true pose); python -m "
            "odolab.evaluate aligns by default (SE(3)), use --align none for these figures. '-': does not "
            "apply (reference rows are not timed).")


def format_table(rows: list[Row], real_data: bool = False) -> str:
    """The summary as a fixed-width text table for the terminal: short headers and no spread
    over sequences (the HTML report has both), then the caption wrapped to 100 columns."""
    import textwrap

    cols = summary_columns(rows, real_data, spread=False)
    table = text_table([c[0] for c in cols], [[c[2](r) for c in cols] for r in rows])
    return table + "\n" + textwrap.fill(table_caption(rows, real_data, spread=False), 100)


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


def plot_sequence(mine: list[SequenceResult], path: Path, names: list[str], plan: FloorPlan | None = None) -> None:
    """Top-down (world X, Y in metres) true vs integrated trajectories of one sequence, over its
    floor plan when given (free = white, obstacles = grey); the legend sits below the axes so it
    never hides the map. ``names`` fixes each odometer's colour across figures."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cmap = plt.get_cmap("tab10")
    gt = mine[0].gt_poses[:, :3, 3]
    fig, ax = plt.subplots(figsize=(5.6, 6.0))
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
    everything = np.concatenate([gt[:, :2]] + [r.poses[:, :2, 3] for r in mine])
    centre = (everything.min(axis=0) + everything.max(axis=0)) / 2
    extent = float(np.ptp(everything, axis=0).max())
    margin = ZOOM_MARGIN if plan is not None else max(0.1 * extent, 0.02)  # real data: no map to show
    half = extent / 2 + margin  # a square view: equal axes, no warning
    ax.set_xlim(centre[0] - half, centre[0] + half)  # the trajectories, not the whole plan, fill it
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("world x (m)")
    ax.set_ylabel("world y (m)")
    ax.set_title(f"{mine[0].sequence}: {len(gt) - 1} steps (start = dot)", fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=2, frameon=False)
    fig.tight_layout()
    save_figure_atomic(fig, path)
    plt.close(fig)


def write_trajectories(results: list[SequenceResult], out: OutputFolder) -> None:
    """Every estimated trajectory and each ground truth (``groundtruth.*``), in TUM and KITTI
    formats; the ``ground-truth`` row is not written (it integrates exactly the ground truth)."""
    done_gt: set[str] = set()
    for r in results:
        folder = f"trajectories/{_safe(r.sequence)}"
        stamps = r.timestamps if r.timestamps is not None else np.arange(len(r.poses), dtype=float)
        todo = [] if r.odometer == "ground-truth" else [(_safe(r.odometer), r.poses)]
        if r.gt_poses is not None and r.sequence not in done_gt:
            todo.append((GROUND_TRUTH_FILE, r.gt_poses))
            done_gt.add(r.sequence)
        for name, poses in todo:
            write_tum_trajectory(out.path(f"{folder}/{name}.tum"), Trajectory(stamps, poses))
            # KITTI: poses relative to the first camera (camera i -> camera 0)
            write_kitti_poses(out.path(f"{folder}/{name}.kitti"), Trajectory(None, invert(poses[0]) @ poses))


def _inline(text: str) -> str:
    """reST inline markup to HTML: ``code``, :role:`code`, *emphasis* (after escaping)."""
    text = html.escape(text, quote=False)
    text = re.sub(r":\w+:`([^`]+)`", r"<code>\1</code>", text)
    text = re.sub(r"``([^`]+)``", r"<code>\1</code>", text)
    return re.sub(r"(?<![\w*])\*([^*\s][^*]*)\*(?![\w*])", r"<em>\1</em>", text)


def rst_to_html(text: str) -> str:
    """The small reST subset of odolab's docstrings (paragraphs, ``* `` bullet lists, inline
    code and emphasis) as HTML."""
    parts = []
    for block in re.split(r"\n\s*\n", text.strip()):
        lines = [ln.strip() for ln in block.splitlines()]
        if lines and lines[0].startswith("* "):
            items: list[str] = []
            for ln in lines:
                if ln.startswith("* "):
                    items.append(ln[2:])
                else:
                    items[-1] += " " + ln
            parts.append("<ul>" + "".join(f"<li>{_inline(i)}</li>" for i in items) + "</ul>")
        else:
            parts.append(f"<p>{_inline(' '.join(lines))}</p>")
    return "\n".join(parts)


def _html_table(header: list[str], rows: list[list[str]], caption: str = "") -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c).replace(' +- ', ' &plusmn; ')}</td>" for c in r)
                   + "</tr>\n" for r in rows)
    cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
    return f"<table>{cap}<thead><tr>{head}</tr></thead>\n<tbody>{body}</tbody></table>"


def _action_table(action_rows: list[ActionRow]) -> str:
    header = ["odometer", "action", "dx error, x1e-2 m, as used", "dz error, x1e-2 m, as used",
              "dyaw error, x1e-2 rad, as used", "dx error, x1e-2 m, on answered steps",
              "dz error, x1e-2 m, on answered steps", "dyaw error, x1e-2 rad, on answered steps", "steps",
              "failed steps"]
    rows = [[r.odometer, r.action, *(fmt(v, ".2f") for v in (r.dx, r.dz, r.dyaw, r.dx_own, r.dz_own, r.dyaw_own)),
             str(r.steps), str(r.failures)] for r in action_rows]
    return _html_table(header, rows, "Mean absolute error per step of each action (no alignment). "
                       "move_forward_collided: the forward steps that collided (the agent stopped at contact, "
                       "short of the commanded step), also counted in move_forward; shown when some did.")


_STYLE = """body{font-family:system-ui,sans-serif;max-width:1280px;margin:2em auto;padding:0 1em;color:#222;
line-height:1.45} h1{font-size:1.6em} h2{margin-top:1.6em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;margin:.5em 0;font-size:.86em} caption{caption-side:bottom;text-align:left;
color:#555;font-size:.9em;padding-top:.4em;max-width:1100px} td,th{border:1px solid #ccc;padding:3px 6px;
text-align:right;white-space:nowrap} th{white-space:normal;min-width:4.5em} td:first-child,th:first-child{text-align:left;white-space:normal;min-width:9em} th{background:#eef1f5;vertical-align:bottom}
tbody tr:nth-child(even){background:#f8f9fb} code{background:#f2f2f2;padding:0 3px}
.gallery{display:grid;grid-template-columns:repeat(auto-fill,minmax(330px,1fr));gap:12px}
.gallery figure{margin:0;border:1px solid #ddd;padding:4px} .gallery img{width:100%}
.gallery figcaption{font-size:.85em;text-align:center} img.wide{max-width:100%}"""


def write_report(out: Path, rows: list[Row], action_rows: list[ActionRow], results: list[SequenceResult],
                 title: str, notes: list[str], plans: dict[str, FloorPlan] | None = None,
                 configs: dict[str, str] | None = None) -> None:
    """Write the tables, figures, trajectories and ``report.html`` into ``out`` (layout: module
    docstring); files of the previous run into ``out`` that this one did not write are removed."""
    from odolab.summary import __doc__ as summary_doc

    folder = OutputFolder(out)
    real_data = not action_rows
    write_text_atomic(folder.path("table.csv"), _csv(rows, Row))
    if action_rows:
        write_text_atomic(folder.path("table_per_action.csv"), _csv(action_rows, ActionRow))
    write_trajectories(results, folder)

    problems: list[str] = []

    def figure(relative: str, draw: Callable[[Path], None]) -> bool:
        try:
            draw(folder.path(relative))
            return True
        except Exception as exc:  # noqa: BLE001 - a figure must never cost the tables
            folder.discard(relative)
            problems.append(f"{relative}: {type(exc).__name__}: {exc}")
            print(f"odolab: warning: figure {out / relative} could not be drawn ({type(exc).__name__}: {exc})",
                  file=sys.stderr)
            return False

    sections = []
    cols = summary_columns(rows, real_data)
    sections.append("<h2>Summary</h2>" + _html_table([c[1] for c in cols], [[c[2](r) for c in cols] for r in rows],
                                                      table_caption(rows, real_data)))
    if action_rows:
        sections.append("<h2>Per action</h2>" + _action_table(action_rows))
        if figure("errors.png", lambda p: plot_errors(action_rows, p)):
            sections.append('<h2>Per-step error by odometer and action</h2><img class="wide" src="errors.png" '
                            'alt="per-step error bars">')
    names = list(dict.fromkeys(r.odometer for r in results))
    cards = []
    for seq in dict.fromkeys(r.sequence for r in results if r.gt_poses is not None):
        mine = [r for r in results if r.sequence == seq]
        rel = f"trajectories/{_safe(seq)}/top-down.png"
        if figure(rel, lambda p, m=mine: plot_sequence(m, p, names, (plans or {}).get(seq))):
            cards.append(f'<figure><a href="{html.escape(rel)}"><img src="{html.escape(rel)}" loading="lazy" '
                         f'alt="{html.escape(seq)}"></a><figcaption>{html.escape(seq)}</figcaption></figure>')
    if cards:
        sections.append(f"<h2>Trajectories, top-down ({len(cards)} sequence{'s' if len(cards) > 1 else ''})</h2>"
                        "<p>Ground truth (black) and "
                        "each odometer's integrated trajectory, world x/y in metres, over the floor plan where "
                        "known (obstacles grey). Click a figure for full size.</p>"
                        f"<div class=\"gallery\">{''.join(cards)}</div>")
    definitions = summary_doc.split("\n\n", 1)[1] if summary_doc and "\n\n" in summary_doc else (summary_doc or "")
    sections.append("<h2>Definitions</h2>" + rst_to_html(definitions))
    failures = [f"<li>{html.escape(r.odometer)} on {html.escape(r.sequence)}: {html.escape(e)}</li>"
                for r in results for e in r.errors]
    if configs:
        sections.append("<h2>Odometer configurations</h2><details><summary>every setting of each odometer "
                        "(its frozen config)</summary><ul>" + "".join(
                            f"<li><b>{html.escape(n)}</b>: {html.escape(c)}</li>" for n, c in configs.items())
                        + "</ul></details>")
    sections.append("<h2>Exceptions raised by odometers (first few)</h2>"
                    f"<ul>{''.join(failures) or '<li>none</li>'}</ul>")
    if problems:
        sections.append("<h2>Figures that could not be drawn</h2><ul>"
                        + "".join(f"<li>{html.escape(p)}</li>" for p in problems) + "</ul>")
    sections.append("<h2>Files</h2><p><code>table.csv</code> (all columns above, full precision), "
                    "<code>trajectories/&lt;sequence&gt;/&lt;odometer&gt;.tum</code> and <code>.kitti</code> "
                    "(readable by <code>python -m odolab.evaluate</code> and evo); "
                    f"<code>{GROUND_TRUTH_FILE}.tum</code> / <code>.kitti</code> are the true poses (the "
                    "ground-truth row integrates exactly these, so it has no file of its own); "
                    f"<code>{MANIFEST}</code> lists every file this run wrote.</p>")
    page = f"""<!doctype html><html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<meta name="viewport" content="width=device-width, initial-scale=1"><style>{_STYLE}</style></head><body>
<h1>{html.escape(title)}</h1>
<ul>{''.join(f'<li>{html.escape(n)}</li>' for n in notes)}</ul>
{chr(10).join(sections)}
</body></html>
"""
    write_text_atomic(folder.path("report.html"), page)
    folder.finish()
