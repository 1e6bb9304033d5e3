"""Write a comparison to a folder: CSV tables, figures, an HTML page and every trajectory.

Layout of ``DIR``::

    table.csv              one row per odometer (columns: odolab.running.summary.Row)
    table_per_action.csv   per-step error per odometer and action (simulator runs), and on the
                           forward steps a collision blocked ("move_forward_collided")
    errors.png             per-step error bars per odometer and action (simulator runs)
    table_paired.csv       each composite against each of its inputs on the same steps: the
                           paired difference of the per-step error, its 95 % interval and verdict
                           (columns: odolab.running.paired.PairedRow; when a composite and an input ran)
    report.html            all of the above on one page, with the definitions and a gallery
    trajectories/<sequence>/top-down.png            true vs estimated trajectories, top-down
    trajectories/<sequence>/<odometer>.{tum,kitti}  every estimate, and groundtruth.{tum,kitti}
    manifest.txt           the files this run wrote (one per line)

``groundtruth.*`` holds the true poses; the ``ground-truth`` row integrates exactly these, so it
has no file of its own. ``<sequence>`` and ``<odometer>`` are :func:`file_stem` of the names: one
file per name (``icp``, ``fused(icp,open3d-rgbd)`` -> ``fused_icp_open3d-rgbd_``; other names carry
a short digest of the name). A run removes the files that ``manifest.txt`` says the previous run into
the same folder wrote and it did not rewrite, and nothing else. Tables are written first: a
figure that fails is reported on the page and on stderr and costs nothing else.
"""

from __future__ import annotations

import csv
import hashlib
import html
import io
import os
import re
import sys
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from odolab.core.geometry import invert
from odolab.core.trajectory import Trajectory
from odolab.io.atomic import save_figure_atomic, write_text_atomic
from odolab.io.kitti import write_kitti_poses
from odolab.io.owned import UnsafeOutputError, check_owned_folder, check_owned_path, owned_path, remove_owned
from odolab.io.tum import write_tum_trajectory
from odolab.running.paired import COMPONENTS, PairedRow
from odolab.running.runner import SequenceResult
from odolab.running.summary import REFERENCE_ODOMETERS, ActionRow, Row, fmt, text_table

_ACTION_COLORS = {
    "move_forward": "#4C72B0",
    "turn_left": "#DD8452",
    "turn_right": "#55A868",
    "move_forward_collided": "#8C8C8C",
}
MANIFEST = "manifest.txt"
#: Metres of floor plan shown around the trajectories in each top-down figure (with a plan).
ZOOM_MARGIN = 1.5
GROUND_TRUTH_FILE = "groundtruth"


#: Names kept as they are: lower case, digits and ``_.+-``, starting with a letter or digit, at most
#: :data:`_READABLE_CHARS` long, not ending in ``_`` (a flat composite's form) nor in ``-`` and 8 hex
#: digits (a digest form).
_PLAIN = re.compile(r"(?![a-z0-9_.+-]*(_|-[0-9a-f]{8})$)[a-z0-9][a-z0-9_.+-]*")
#: A flat composite of plain names without ``_``, ``fused(icp,open3d-rgbd)``, kept readable as
#: ``fused_icp_open3d-rgbd_`` (the names split back at each ``_``: no two give one file name).
_FLAT = re.compile(r"[a-z0-9][a-z0-9.+-]*\([a-z0-9][a-z0-9.+-]*(,[a-z0-9][a-z0-9.+-]*)*\)")
#: Characters of a name kept readable in a file name; a longer one is cut and carries a digest.
_READABLE_CHARS = 100


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """``n`` and ``noun``, in the plural (``noun`` + s unless given) unless ``n`` is 1:
    ``counted(1, "test episode")`` -> ``1 test episode``, ``counted(5, "test episode")`` -> ``5 test episodes``."""
    return f"{n} {noun if n == 1 else plural or noun + 's'}"


def file_stem(name: str) -> str:
    """A portable file name (no suffix) for an odometer or sequence name, one per name by
    construction, also on a file system that ignores case: a plain lower-case name is kept as it is
    (``icp``), a flat composite reads as before (``fused(icp,open3d-rgbd)`` ->
    ``fused_icp_open3d-rgbd_``); any other name (``/a/c 1/x.py:Odo``, ``ICP``, ``groundtruth``, the
    true poses' file) is made portable, cut to :data:`_READABLE_CHARS` characters, and carries
    ``-`` and 8 hex digits of its SHA-1, as ``odolab.navigation`` names its folders. The three forms
    never meet: a plain name ends in neither ``_`` nor a digest, a composite's form ends in ``_``."""
    if len(name) <= _READABLE_CHARS and name != GROUND_TRUTH_FILE:
        if _PLAIN.fullmatch(name):
            return name
        if _FLAT.fullmatch(name):
            return re.sub(r"[(),]", "_", name)
    clean = re.sub(r"[^A-Za-z0-9_.+-]", "_", name)[:_READABLE_CHARS].lstrip(".") or "_"
    return f"{clean}-{hashlib.sha1(name.encode()).hexdigest()[:8]}"


#: The names compare writes (and its cleanup may remove), relative to its folder.
COMPARE_NAMES = re.compile(
    r"(table\.csv|table_per_action\.csv|table_paired\.csv|errors\.png|report\.html"
    r"|trajectories/[^/]+/[^/]+\.(tum|kitti|png))"
)


class ManifestError(ValueError):
    """A folder whose manifest another command, or no odolab run, wrote (the message says which)."""


class OutputFolder:
    """The files one run writes under ``root``, listed in ``manifest.txt`` as they are written.

    The manifest's first line names the command that owns the folder (``# odolab compare``);
    ``names`` matches every file that command writes: the cleanup removes nothing else, whatever a
    manifest lists, and :meth:`check` refuses a folder another command (or no odolab run) wrote.

    On creation the files the previous run's manifest lists are removed (only those: never a file
    the manifest does not name, nothing outside ``root``, never through a symbolic link), so the
    folder never mixes two runs; each :meth:`path` records its file in the manifest before the
    file is written, so an interrupted run leaves a manifest naming everything it wrote and the
    next run cleans it up. Every path is checked by :func:`odolab.io.owned.owned_path`: a link or a
    file where a folder belongs raises :class:`~odolab.io.owned.UnsafeOutputError`, which
    :meth:`check` finds before any work. A removal that cannot be done is listed in
    :attr:`not_removed`, never raised: cleaning up never costs a computed result.
    """

    def __init__(self, root: Path, owner: str = "compare", names: re.Pattern = COMPARE_NAMES) -> None:
        self.root, self.owner, self.names = Path(root), owner, names
        self.written: list[str] = []
        self.not_removed: list[str] = []
        self.root.mkdir(parents=True, exist_ok=True)
        self.removed = self._remove_previous()

    @staticmethod
    def check(
        root: Path,
        files: tuple[str, ...] = (),
        folders: tuple[str, ...] = (),
        owner: str = "compare",
        names: re.Pattern = COMPARE_NAMES,
    ) -> None:
        """Raise :class:`~odolab.io.owned.UnsafeOutputError` unless a run can write ``root``: the
        folders of every path its manifest names and each of ``folders`` are folders (or nothing),
        each of ``files`` a regular file (or nothing), all inside ``root`` with no symbolic link on
        the way (a manifest line naming a folder or a link is only left alone by the cleanup);
        :class:`ManifestError` when the manifest is another command's, or names a file ``owner``
        never writes (a manifest without an owner line is read as ``owner``'s)."""
        root = Path(root)
        if not root.exists():
            return
        if not root.is_dir():
            raise UnsafeOutputError(root, "a folder", "a file")
        manifest = root / MANIFEST
        if manifest.is_file() and not manifest.is_symlink():
            try:
                manifest.read_text(encoding="utf-8")
            except (OSError, UnicodeDecodeError) as exc:
                raise ManifestError(
                    f"{root}: its {MANIFEST} cannot be read ({type(exc).__name__}), so what the last run "
                    "wrote is unknown; delete the folder's old results or choose another folder"
                ) from None
        said = manifest_owner(root)
        if said is not None and said != owner:
            raise ManifestError(
                f"{root}: holds the results of odolab {said} (its {MANIFEST} says so), not of "
                f"odolab {owner}; choose another folder"
            )
        for rel in _manifest_lines(root):
            if len(Path(rel).parts) > 1 and names.fullmatch(rel):  # other lines: refused below, by name
                check_owned_folder(root, Path(rel).parent)
        for rel in files:
            check_owned_path(root, rel)
        for rel in folders:
            check_owned_folder(root, rel)
        foreign = [rel for rel in _manifest_lines(root) if not names.fullmatch(rel)]
        if foreign:
            raise ManifestError(
                f"{root}: its {MANIFEST} lists {foreign[0]!r}, which odolab {owner} never writes "
                "(not a manifest of this command); choose another folder"
            )

    def path(self, relative: str) -> Path:
        """The path of ``relative`` (its folder created), recorded as written by this run."""
        p = owned_path(self.root, relative)
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
        write_text_atomic(
            owned_path(self.root, MANIFEST),
            f"{_OWNER_LINE}{self.owner}\n" + "".join(f"{rel}\n" for rel in sorted(self.written)),
        )

    def _remove_previous(self) -> list[str]:
        removed = []
        for rel in _manifest_lines(self.root):
            if not self.names.fullmatch(rel):  # never this command's: left alone, and said
                if os.path.lexists(self.root / rel):
                    self.not_removed.append(rel)
            elif remove_owned(self.root, rel):
                removed.append(rel)
            elif os.path.lexists(self.root / rel):  # through a link, or not removable: left, and said
                self.not_removed.append(rel)
        return removed

    def finish(self) -> list[str]:
        """Write the final manifest; returns what the previous run had and this one removed."""
        self._write_manifest()
        return self.removed


_OWNER_LINE = "# odolab "


def manifest_owner(root: Path) -> str | None:
    """The command a manifest's first line names (``# odolab compare``), or None."""
    try:
        if not Path(root, MANIFEST).is_file():  # a pipe named so would block the read
            return None
        with open(Path(root, MANIFEST), encoding="utf-8") as f:
            first = f.readline(200).strip()
    except (OSError, UnicodeDecodeError):
        return None
    return first[len(_OWNER_LINE) :].strip() or None if first.startswith(_OWNER_LINE) else None


def _manifest_lines(root: Path) -> list[str]:
    """The paths ``root``'s manifest names (none when it is missing or unreadable), without the
    manifest itself and lines that are not plain relative paths a file system can hold."""
    try:
        if not Path(root, MANIFEST).is_file() or Path(root, MANIFEST).is_symlink():
            return []
        lines = Path(root, MANIFEST).read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError):
        return []
    return [
        rel
        for rel in lines
        if rel
        and rel != MANIFEST
        and not rel.startswith("#")
        and not Path(rel).is_absolute()
        and ".." not in Path(rel).parts
        and "\x00" not in rel
        and len(rel.encode()) < 4096
        and all(len(part.encode()) <= 255 for part in Path(rel).parts)
    ]  # names no file system holds: none


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


def summary_columns(rows: list[Row], real_data: bool, spread: bool = True, bias: bool = False) -> list[Column]:
    """The columns of the summary table; with ``spread``, ``+- std`` over sequences when there
    are several; with ``bias`` (simulator runs), the signed mean error per step."""
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
        if bias:
            cols.append(
                (
                    "bias",
                    "bias: signed mean error (dx, dz, dyaw), x1e-2, as used",
                    lambda r: ", ".join(fmt(v, "+.2f") for v in (r.dx_bias, r.dz_bias, r.dyaw_bias)),
                )
            )
    cols += [
        ("failed %", "failed steps, % (prior used)", lambda r: f"{100 * r.failure_share:.1f}"),
        ("ATE m (no align)", "ATE, m, RMSE, no alignment", lambda r: fmt(r.ate_m, ".3f", sd(r.ate_std))),
    ]
    if not real_data:
        cols.append(("drift m", "final drift, m, no alignment", lambda r: fmt(r.drift_m, ".3f", sd(r.drift_std))))
    cols.append(("steps/s", "steps/s of step()", lambda r: fmt(r.fps, ".1f")))
    return cols


def table_caption(rows: list[Row], real_data: bool, spread: bool = True, bias: bool = False) -> str:
    """What the summary table's figures are: units, pooling, alignment, what "own" means (and the
    bias, when ``bias`` and simulator runs)."""
    many = spread and any(r.sequences > 1 for r in rows)
    what = (
        "Per frame pair: mean translation and rotation error of the relative pose"
        if real_data
        else "Per step: mean absolute error of (dx, dz, dyaw), x1e-2 (m, m, rad), pooled over all steps"
    )
    return (
        f"{what}{'; +- is the standard deviation over sequences' if many else ''}. 'As used' scores a "
        "failed step with the action prior's motion that replaced it; 'own' leaves failed steps out "
        "and must be read with the failure share; table.csv's raw columns score every step as the paper "
        "did, with the odometer's own motion (the unverified one where it refused). "
        + (
            "Bias: the signed mean error per step (estimate minus truth), which integrates into drift. "
            if bias and not real_data
            else ""
        )
        + "ATE: RMSE of the "
        "position error with no alignment (trajectories start at the true pose); python -m "
        "odolab.evaluate aligns by default (SE(3)), use --align none for these figures. '-': does not "
        "apply (reference rows are not timed)."
    )


def format_table(rows: list[Row], real_data: bool = False) -> str:
    """The summary as a fixed-width text table for the terminal: short headers and no spread
    over sequences (the HTML report has both), then the caption wrapped to 100 columns."""
    import textwrap

    cols = summary_columns(rows, real_data, spread=False)
    table = text_table([c[0] for c in cols], [[c[2](r) for c in cols] for r in rows])
    return table + "\n" + textwrap.fill(table_caption(rows, real_data, spread=False), 100)


#: An error panel's axis ends at this multiple of its tallest bar among the actions that are not
#: collisions; a collided bar above it is cut there and its value written on it.
CLIP_HEADROOM = 1.3
COLLIDED = "move_forward_collided"


def _step_counts(action_rows: list[ActionRow], action: str) -> str:
    """``n=...`` steps of ``action`` (one number when every odometer had the same, else a range)."""
    counts = sorted({r.steps for r in action_rows if r.action == action})
    return f"n={counts[0]}" if len(counts) == 1 else f"n={counts[0]}-{counts[-1]}" if counts else "n=0"


def error_axis_top(values: dict[str, list[float]]) -> float | None:
    """The top of an error panel's axis, given each action's bar heights: the tallest bar of the
    actions that are not collisions, with :data:`CLIP_HEADROOM`, when a collided bar is taller than
    that (the few collided steps would otherwise set the scale); None: no bar needs cutting."""
    usual = [v for a, vals in values.items() if a != COLLIDED for v in vals if np.isfinite(v)]
    collided = [v for v in values.get(COLLIDED, []) if np.isfinite(v)]
    if not usual or not collided or max(usual) <= 0:
        return None
    top = CLIP_HEADROOM * max(usual)
    return top if max(collided) > top else None


def _bar_value(row: ActionRow | None, comp: str) -> float:
    """One bar of :func:`plot_errors`: the row's error component, or its failed steps in % ("failed")."""
    if row is None:
        return float("nan")
    if comp == "failed":
        return 100.0 * row.failures / row.steps if row.steps else float("nan")
    return float(getattr(row, comp))


#: Width of ``errors.png`` in inches: about 1230 pixels at the 110 dpi figures are saved with, what
#: the report shows (its page is 1280 px wide), so the figure is shown at its own size.
ERROR_FIGURE_WIDTH = 11.2
#: Smallest font of ``errors.png`` in points: 8.5 pt at 110 dpi are 13 px on the page.
ERROR_FIGURE_FONT = 8.5
#: More odometers than this: the error figure's panels are stacked in one column.
ERROR_FIGURE_TWO_COLUMNS = 10


def error_panel_odometers(action_rows: list[ActionRow]) -> tuple[list[str], list[str]]:
    """The odometers :func:`plot_errors` draws in its error panels and in its failure panel, in
    order: an odometer whose every error is zero (``ground-truth``) has no bar to draw, and the
    reference rows (:data:`~odolab.running.summary.REFERENCE_ODOMETERS`) never fail."""
    names = list(dict.fromkeys(r.odometer for r in action_rows))
    errors = [
        n
        for n in names
        if any(v != 0 for r in action_rows if r.odometer == n for v in (r.dx, r.dz, r.dyaw) if np.isfinite(v))
    ]
    return errors, [n for n in names if n not in REFERENCE_ODOMETERS]


def _left_out_note(names: list[str], errors: list[str], failing: list[str]) -> str:
    """What :func:`plot_errors` leaves out, and why ("" when nothing)."""
    zero = [n for n in names if n not in errors]
    references = [n for n in names if n not in failing]
    parts = [f"{' and '.join(zero)} (zero error everywhere)"] if zero else []
    parts += [f"from the failures, {' and '.join(references)} (references: they never fail)"] if references else []
    return f"Not drawn: {'; '.join(parts)}." if parts else ""


def plot_errors(action_rows: list[ActionRow], path: Path) -> None:
    """Grouped bars in a grid of panels about as wide as the report shows it
    (:data:`ERROR_FIGURE_WIDTH`, fonts of at least :data:`ERROR_FIGURE_FONT` pt): per-step error as
    used (x 1e-2) of each odometer, one bar per action (its step count in the legend), one panel
    per axis (dx, dz m; dyaw rad), and the failed steps (% of the action's steps). Odometers with no
    bar to draw are left out and named (:func:`error_panel_odometers`); an odometer that never
    failed reads "0 %". Collided forward steps are few, and their large dz error would squash every
    other bar: a panel's axis is cut above the other actions' bars (see :func:`error_axis_top`), a
    cut bar carries a break mark and its value is written above the axis."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(dict.fromkeys(r.odometer for r in action_rows))
    actions = list(dict.fromkeys(r.action for r in action_rows))
    errors, failing = error_panel_odometers(action_rows)
    two = max(len(errors), len(failing)) <= ERROR_FIGURE_TWO_COLUMNS
    rows_n, cols_n = (2, 2) if two else (4, 1)
    band = 1.1  # inches above the panels: the title, what is left out, the legend
    height = (3.9 if two else 3.4) * rows_n + band
    fig, grid = plt.subplots(rows_n, cols_n, figsize=(ERROR_FIGURE_WIDTH, height), squeeze=False, layout="constrained")
    fig.get_layout_engine().set(rect=(0, 0, 1, 1 - band / height), h_pad=0.12)
    axes = list(grid.flat)
    font = ERROR_FIGURE_FONT
    panels = [
        ("dx", "mean |error| of dx, as used (x1e-2 m)", "dx error per step, as used", errors),
        ("dz", "mean |error| of dz, as used (x1e-2 m)", "dz error per step, as used", errors),
        ("dyaw", "mean |error| of dyaw, as used (x1e-2 rad)", "dyaw error per step, as used", errors),
        ("failed", "failed steps (% of the action's steps)", "failures (prior used instead)", failing),
    ]
    for ax, (comp, ylabel, title, shown) in zip(axes, panels):
        top = _error_panel(ax, action_rows, actions, shown, comp, font)
        ax.set_ylabel(ylabel, fontsize=font + 1)
        if top is not None:
            title += f" (axis cut at {top:.1f}:\na taller bar's value stands above it)"
        ax.set_title(title, fontsize=font + 2, pad=14 if top is not None else 6)
    note = _left_out_note(names, errors, failing)
    fig.text(
        0.5,
        1 - 0.08 / height,
        "Per-step error by odometer and action; as used: a failed step is scored with the action prior "
        "that replaced it" + (f"\n{note}" if note else ""),
        ha="center",
        va="top",
        fontsize=font + 2,
    )
    handles = [plt.Rectangle((0, 0), 1, 1, color=_ACTION_COLORS.get(a)) for a in actions]
    axes[0].legend(
        handles,
        [f"{a} ({_step_counts(action_rows, a)})" for a in actions],
        title="action (steps per odometer)",
        fontsize=font + 0.5,
        title_fontsize=font + 0.5,
        ncol=len(actions),
        loc="lower center",
        bbox_to_anchor=(0.5, 1 - band / height),
        bbox_transform=fig.transFigure,
        frameon=False,
    ).set_in_layout(False)
    save_figure_atomic(fig, path)
    plt.close(fig)


def _error_panel(
    ax: Any, action_rows: list[ActionRow], actions: list[str], names: list[str], comp: str, font: float
) -> float | None:
    """One panel of :func:`plot_errors`: ``comp``'s bars of ``names`` (one group per odometer, one
    bar per action); returns where the axis was cut above the usual bars because a collided one
    would squash them (None: not cut)."""
    if not names:
        ax.text(0.5, 0.5, "no odometer to show", ha="center", va="center", fontsize=font + 1, transform=ax.transAxes)
        ax.set_xticks([])
        ax.set_yticks([])
        return None
    x = np.arange(len(names))
    width = 0.8 / max(len(actions), 1)
    values: dict[str, list[float]] = {}
    for a in actions:
        rows = [next((r for r in action_rows if r.odometer == n and r.action == a), None) for n in names]
        values[a] = [_bar_value(row, comp) for row in rows]
    top = None if comp == "failed" else error_axis_top(values)
    for k, a in enumerate(actions):
        xs = x + (k - (len(actions) - 1) / 2) * width
        ax.bar(xs, values[a], width, color=_ACTION_COLORS.get(a))
        for xi, v in zip(xs, values[a]):
            if top is not None and np.isfinite(v) and v > top:  # cut at the axis: a break, the value above
                ax.plot([xi - width / 2, xi + width / 2], [0.93 * top, 0.96 * top], color="white", lw=2.5)
                ax.text(xi, top, f"{v:.1f}", ha="center", va="bottom", fontsize=font, clip_on=False)
    if comp == "failed":
        for xi, n in zip(x, names):
            if all(v == 0 for a in actions for v, m in zip(values[a], names) if m == n):
                ax.text(xi, 0, "0 %", ha="center", va="bottom", fontsize=font, color="0.3")
    if top is not None:
        ax.set_ylim(0, top)
    pad = max(0.5, (4 - len(names)) / 2 + 0.5)  # a few odometers: narrow groups, centred
    ax.set_xlim(-pad, len(names) - 1 + pad)
    tilt = len(names) > 3 or max((len(n) for n in names), default=0) > 14  # long names side by side would overlap
    # tilted down to the right from each tick: no name reaches left past the axis into the y label
    ax.set_xticks(x, names, rotation=-30 if tilt else 0, ha="left" if tilt else "center", rotation_mode="anchor")
    ax.tick_params(labelsize=font + 0.5)
    ax.grid(True, axis="y", alpha=0.3)
    return top


@dataclass(frozen=True)
class FloorPlan:
    """A top-down occupancy image to draw under trajectories: ``free`` (rows, cols) bool, cell
    (r, c) at world x = origin[0] + c * resolution, y = origin[1] + r * resolution (metres)."""

    free: np.ndarray
    origin: tuple[float, float]
    resolution: float
    goal: tuple[float, float] | None = None  # the episode's PointGoal (world x, y m), when known


#: Grey level (0 black, 1 white) of obstacles in top-down figures; free floor is white.
OBSTACLE_SHADE = 0.75
#: Colours of the odometers' trajectories over a floor plan: Paul Tol's "bright" qualitative scheme,
#: told apart with the common colour-vision deficiencies and on white, none of them grey or black
#: (obstacles are grey, ground truth black); after these, the colours repeat with another line style.
TRAJECTORY_COLORS = ("#4477AA", "#EE6677", "#228833", "#CCBB44", "#66CCEE", "#AA3377")
#: Markers along each trajectory, one more than the colours (no colour and marker pair repeats
#: before 42 odometers); none of the start (circle), end (square) or goal (star) markers.
TRAJECTORY_MARKERS = ("^", "v", "D", "P", "X", "<", ">")
_LINE_STYLES = ("-", "--", ":", "-.")


def trajectory_style(index: int) -> tuple[str, str]:
    """The colour and matplotlib format (marker and line style, ``"^-"``) of the ``index``-th
    odometer in top-down figures."""
    colors = len(TRAJECTORY_COLORS)
    marker = TRAJECTORY_MARKERS[index % len(TRAJECTORY_MARKERS)]
    return TRAJECTORY_COLORS[index % colors], marker + _LINE_STYLES[(index // colors) % len(_LINE_STYLES)]


#: Markers drawn along a trajectory in a top-down figure (about; every step for short ones).
TRAJECTORY_MARKS = 12


def plot_sequence(mine: list[SequenceResult], path: Path, names: list[str], plan: FloorPlan | None = None) -> None:
    """Top-down (world X, Y in metres) true vs integrated trajectories of one sequence, over its
    floor plan when given (free = white, obstacles = grey), with the shared start (circle), each
    trajectory's end (square, in its colour) and the plan's goal (star; an arrow at the edge when it
    lies outside the view); the legend sits below the axes so it never hides the map. ``names``
    fixes each odometer's colour (:func:`trajectory_style`) across figures."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    gt = mine[0].gt_poses[:, :3, 3]
    drawn = [n for n in names if n != "ground-truth"]  # drawn as the black ground truth: no colour of its own
    fig, ax = plt.subplots(figsize=(5.6, 6.0))
    if plan is not None:
        draw_floor_plan(ax, plan)
    ax.plot(gt[:, 0], gt[:, 1], "k-", lw=2.5, label="ground truth")
    ax.plot(gt[-1, 0], gt[-1, 1], "ks", ms=7, zorder=4)
    for r in mine:
        if r.odometer == "ground-truth":
            continue
        p = r.poses[:, :3, 3]
        color, style = trajectory_style(drawn.index(r.odometer))
        every = max(1, len(p) // TRAJECTORY_MARKS)
        ax.plot(p[:, 0], p[:, 1], style, lw=1.4, ms=5, markevery=every, color=color, label=r.odometer)
        ax.plot(p[-1, 0], p[-1, 1], "s", ms=6, color=color, markeredgecolor="k", markeredgewidth=0.6, zorder=4)
    ax.plot(gt[0, 0], gt[0, 1], "o", ms=8, color="w", markeredgecolor="k", markeredgewidth=1.5, zorder=5)
    everything = np.concatenate([gt[:, :2]] + [r.poses[:, :2, 3] for r in mine])
    centre = (everything.min(axis=0) + everything.max(axis=0)) / 2
    extent = float(np.ptp(everything, axis=0).max())
    margin = ZOOM_MARGIN if plan is not None else max(0.1 * extent, 0.02)  # real data: no map to show
    half = extent / 2 + margin  # a square view: equal axes, no warning
    ax.set_xlim(centre[0] - half, centre[0] + half)  # the trajectories, not the whole plan, fill it
    ax.set_ylim(centre[1] - half, centre[1] + half)
    markers = [
        Line2D([], [], ls="none", marker="o", ms=7, color="w", markeredgecolor="k", label="start"),
        Line2D(
            [],
            [],
            ls="none",
            marker="s",
            ms=6,
            color="0.3",
            markeredgecolor="k",
            label="end (each trajectory's colour)",
        ),
    ]
    if plan is not None and plan.goal is not None:
        markers.append(_draw_goal(ax, np.asarray(plan.goal, dtype=float), centre, half, gt[-1, :2]))
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("world x (m)")
    ax.set_ylabel("world y (m)")
    ax.set_title(f"{mine[0].sequence}: {counted(len(gt) - 1, 'step')}", fontsize=10)
    ax.grid(True, alpha=0.3)
    handles, _ = ax.get_legend_handles_labels()
    ax.legend(
        handles=handles + markers, fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=2, frameon=False
    )
    fig.tight_layout()
    save_figure_atomic(fig, path)
    plt.close(fig)


def draw_floor_plan(ax: Any, plan: FloorPlan, aspect: str | None = None) -> None:
    """Draw ``plan`` under a top-down figure's paths: free cells white, the rest grey
    (:data:`OBSTACLE_SHADE`), at their world x, y (m); ``aspect`` as :meth:`~matplotlib.axes.Axes.imshow`'s."""
    h, w = plan.free.shape
    extent = (
        plan.origin[0],
        plan.origin[0] + w * plan.resolution,
        plan.origin[1],
        plan.origin[1] + h * plan.resolution,
    )
    ax.imshow(np.where(plan.free, 1.0, OBSTACLE_SHADE), cmap="gray", vmin=0, vmax=1, origin="lower", extent=extent,
              interpolation="nearest", aspect=aspect)  # fmt: skip


def _draw_goal(ax: Any, goal: np.ndarray, centre: np.ndarray, half: float, end: np.ndarray) -> Any:
    """Draw the goal as a star inside the view ``centre`` +- ``half`` (m), or, outside it, as an arrow
    near the view's edge pointing to it, labelled with its distance from the true ``end``; returns
    the legend's handle for it."""
    from matplotlib.lines import Line2D

    style = {"marker": "*", "ms": 13, "color": "gold", "markeredgecolor": "k", "markeredgewidth": 0.8}
    offset = goal - centre
    if np.all(np.abs(offset) <= half):
        ax.plot(goal[0], goal[1], ls="none", zorder=6, **style)
        return Line2D([], [], ls="none", label="goal", **style)
    edge = centre + offset * (0.88 * half / np.abs(offset).max())  # on the way to the goal, inside the view
    tail = centre + offset * (0.62 * half / np.abs(offset).max())
    ax.annotate(
        f"goal {np.linalg.norm(goal - end):.1f} m\nfrom the end",
        xy=edge,
        xytext=tail,
        fontsize=7,
        ha="center",
        va="center",
        zorder=6,
        arrowprops={"arrowstyle": "-|>", "color": "k", "lw": 1.2},
        bbox={"boxstyle": "round,pad=0.2", "fc": "gold", "ec": "k", "lw": 0.6},
    )
    return Line2D([], [], ls="none", label="goal (off view: arrow)", **style)


def write_trajectories(results: list[SequenceResult], out: OutputFolder) -> None:
    """Every estimated trajectory and each ground truth (``groundtruth.*``), in TUM and KITTI
    formats, named by :func:`file_stem`; the ``ground-truth`` row is not written (it integrates
    exactly the ground truth). Two names that would share a file raise ``ValueError`` before any
    is written (only two SHA-1 digests that agree in 8 hex digits could)."""
    _check_unique({r.sequence: file_stem(r.sequence) for r in results}, "sequences")
    for seq in dict.fromkeys(r.sequence for r in results):
        mine = {
            r.odometer: file_stem(r.odometer) for r in results if r.sequence == seq and r.odometer != "ground-truth"
        }
        _check_unique({"the true poses": GROUND_TRUTH_FILE, **mine}, f"trajectories of {seq!r}")
    done_gt: set[str] = set()
    for r in results:
        folder = f"trajectories/{file_stem(r.sequence)}"
        stamps = r.timestamps if r.timestamps is not None else np.arange(len(r.poses), dtype=float)
        todo = [] if r.odometer == "ground-truth" else [(file_stem(r.odometer), r.poses)]
        if r.gt_poses is not None and r.sequence not in done_gt:
            todo.append((GROUND_TRUTH_FILE, r.gt_poses))
            done_gt.add(r.sequence)
        for name, poses in todo:
            write_tum_trajectory(out.path(f"{folder}/{name}.tum"), Trajectory(stamps, poses))
            # KITTI: poses relative to the first camera (camera i -> camera 0)
            write_kitti_poses(out.path(f"{folder}/{name}.kitti"), Trajectory(None, invert(poses[0]) @ poses))


def _check_unique(stems: dict[str, str], what: str) -> None:
    """``ValueError`` when two names of ``stems`` (name -> file stem) would share a file, on a file
    system that ignores case too."""
    seen: dict[str, str] = {}
    for name, stem in stems.items():
        other = seen.setdefault(stem.lower(), name)
        if other != name:
            raise ValueError(f"{what}: {other!r} and {name!r} would share the file name {stem!r}")


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
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(c).replace(' +- ', ' &plusmn; ')}</td>" for c in r) + "</tr>\n"
        for r in rows
    )
    cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
    return f"<table>{cap}<thead><tr>{head}</tr></thead>\n<tbody>{body}</tbody></table>"


def _action_table(action_rows: list[ActionRow]) -> str:
    header = [
        "odometer",
        "action",
        "dx error, x1e-2 m, as used",
        "dz error, x1e-2 m, as used",
        "dyaw error, x1e-2 rad, as used",
        "dx error, x1e-2 m, on answered steps",
        "dz error, x1e-2 m, on answered steps",
        "dyaw error, x1e-2 rad, on answered steps",
        "steps",
        "failed steps",
    ]
    rows = [
        [
            r.odometer,
            r.action,
            *(fmt(v, ".2f") for v in (r.dx, r.dz, r.dyaw, r.dx_own, r.dz_own, r.dyaw_own)),
            str(r.steps),
            str(r.failures),
        ]
        for r in action_rows
    ]
    return _html_table(
        header,
        rows,
        "Mean absolute error per step of each action (no alignment). "
        "move_forward_collided: the forward steps that collided (the agent stopped at contact, "
        "short of the commanded step), also counted in move_forward; shown when some did.",
    )


def _paired_table(paired_rows: list[PairedRow]) -> str:
    """One line per (odometer, input, group of steps): each component's difference, interval, verdict."""
    lines: dict[tuple[str, str, str], dict[str, PairedRow]] = {}
    for r in paired_rows:
        lines.setdefault((r.odometer, r.against, r.action), {})[r.component] = r

    def cell(r: PairedRow | None) -> str:
        if r is None:
            return "-"
        interval = f" ({fmt(r.low, '+.2f')} to {fmt(r.high, '+.2f')})" if np.isfinite(r.low) else ""
        return f"{fmt(r.diff, '+.2f')}{interval} {r.verdict}"

    header = ["odometer", "against", "steps", "sequences"] + [
        f"{c} difference, x1e-2 {'rad' if c == 'dyaw' else 'm'} (95 % interval), verdict" for c in COMPONENTS
    ]
    rows = []
    for (odometer, against, action), cells in lines.items():
        first = next(iter(cells.values()))
        label = odometer if action == "all" else f"{odometer}: {action}"
        rows.append([label, against, str(first.steps), str(first.sequences), *(cell(cells.get(c)) for c in COMPONENTS)])
    return _html_table(
        header,
        rows,
        "Paired difference of the mean absolute error per step as used (odometer minus the input it is "
        "built on, on the same steps; negative: lower error), mean over sequences with a 95 % Student-t "
        "interval over the per-sequence differences. Verdict: lower or higher when the whole interval "
        "is on one side of zero, else undecided. Also in table_paired.csv.",
    )


_STYLE = """body{font-family:system-ui,sans-serif;max-width:1280px;margin:2em auto;padding:0 1em;color:#222;
line-height:1.45} h1{font-size:1.6em} h2{margin-top:1.6em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;margin:.5em 0;font-size:.86em} caption{caption-side:bottom;text-align:left;
color:#555;font-size:.9em;padding-top:.4em;max-width:1100px} td,th{border:1px solid #ccc;padding:3px 6px;
text-align:right;white-space:nowrap} th{white-space:normal;min-width:4.5em} td:first-child,th:first-child{text-align:left;white-space:normal;min-width:9em} th{background:#eef1f5;vertical-align:bottom}
tbody tr:nth-child(even){background:#f8f9fb} code{background:#f2f2f2;padding:0 3px}
.gallery{display:grid;grid-template-columns:repeat(auto-fill,minmax(330px,1fr));gap:12px}
.gallery figure{margin:0;border:1px solid #ddd;padding:4px} .gallery img{width:100%}
.gallery figcaption{font-size:.85em;text-align:center} img.wide{max-width:100%}"""


def write_report(
    out: Path,
    *,
    rows: list[Row],
    action_rows: list[ActionRow],
    results: list[SequenceResult],
    title: str,
    notes: list[str],
    plans: dict[str, FloorPlan] | None = None,
    configs: dict[str, str] | None = None,
    paired_rows: list[PairedRow] | None = None,
) -> None:
    """Write the tables, figures, trajectories and ``report.html`` into ``out`` (layout: module
    docstring), the fields of a :class:`~odolab.reporting.pipeline.ComparisonResult` given by name; files of the previous run into ``out`` that this one did not write are removed."""
    from odolab.running.summary import __doc__ as summary_doc

    folder = OutputFolder(out)
    for rel in folder.not_removed:
        print(
            f"odolab: warning: {out / rel}: named by the previous run's {MANIFEST} but not removed (a symbolic "
            "link on the way, or not a removable file); left as it is",
            file=sys.stderr,
        )
    real_data = not action_rows
    write_text_atomic(folder.path("table.csv"), _csv(rows, Row))
    if action_rows:
        write_text_atomic(folder.path("table_per_action.csv"), _csv(action_rows, ActionRow))
    if paired_rows:
        write_text_atomic(folder.path("table_paired.csv"), _csv(paired_rows, PairedRow))
    write_trajectories(results, folder)

    problems: list[str] = []

    def figure(relative: str, draw: Callable[[Path], None]) -> bool:
        try:
            draw(folder.path(relative))
            return True
        except Exception as exc:  # noqa: BLE001 - a figure must never cost the tables
            folder.discard(relative)
            problems.append(f"{relative}: {type(exc).__name__}: {exc}")
            print(
                f"odolab: warning: figure {out / relative} could not be drawn ({type(exc).__name__}: {exc})",
                file=sys.stderr,
            )
            return False

    sections = []
    cols = summary_columns(rows, real_data, bias=True)
    sections.append(
        "<h2>Summary</h2>"
        + _html_table(
            [c[1] for c in cols], [[c[2](r) for c in cols] for r in rows], table_caption(rows, real_data, bias=True)
        )
    )
    if action_rows:
        sections.append("<h2>Per action</h2>" + _action_table(action_rows))
        if figure("errors.png", lambda p: plot_errors(action_rows, p)):
            sections.append(
                '<h2>Per-step error by odometer and action</h2><img class="wide" src="errors.png" '
                'alt="per-step error bars">'
            )
    if paired_rows:
        sections.append("<h2>What each composite adds over its input</h2>" + _paired_table(paired_rows))
    names = list(dict.fromkeys(r.odometer for r in results))
    cards = []
    for seq in dict.fromkeys(r.sequence for r in results if r.gt_poses is not None):
        mine = [r for r in results if r.sequence == seq]
        rel = f"trajectories/{file_stem(seq)}/top-down.png"
        if figure(rel, lambda p, m=mine, s=seq: plot_sequence(m, p, names, (plans or {}).get(s))):
            cards.append(
                f'<figure><a href="{html.escape(rel)}"><img src="{html.escape(rel)}" loading="lazy" '
                f'alt="{html.escape(seq)}"></a><figcaption>{html.escape(seq)}</figcaption></figure>'
            )
    if cards:
        sections.append(
            f"<h2>Trajectories, top-down ({counted(len(cards), 'sequence')})</h2>"
            "<p>Ground truth (black) and "
            "each odometer's integrated trajectory, world x/y in metres, over the floor plan where "
            "known (obstacles grey); a circle marks the start, a square each trajectory's end, a "
            "star the goal (an arrow when it lies outside the view). Click a figure for full size.</p>"
            f'<div class="gallery">{"".join(cards)}</div>'
        )
    definitions = summary_doc.split("\n\n", 1)[1] if summary_doc and "\n\n" in summary_doc else (summary_doc or "")
    sections.append("<h2>Definitions</h2>" + rst_to_html(definitions))
    failures = [
        f"<li>{html.escape(r.odometer)} on {html.escape(r.sequence)}: {html.escape(e)}</li>"
        for r in results
        for e in r.errors
    ]
    if configs:
        sections.append(
            "<h2>Odometer configurations</h2><details><summary>every setting of each odometer "
            "(its frozen config)</summary><ul>"
            + "".join(f"<li><b>{html.escape(n)}</b>: {html.escape(c)}</li>" for n, c in configs.items())
            + "</ul></details>"
        )
    sections.append(
        f"<h2>Exceptions raised by odometers (first few)</h2><ul>{''.join(failures) or '<li>none</li>'}</ul>"
    )
    if problems:
        sections.append(
            "<h2>Figures that could not be drawn</h2><ul>"
            + "".join(f"<li>{html.escape(p)}</li>" for p in problems)
            + "</ul>"
        )
    sections.append(
        "<h2>Files</h2><p><code>table.csv</code> (all columns above, full precision), "
        "<code>trajectories/&lt;sequence&gt;/&lt;odometer&gt;.tum</code> and <code>.kitti</code> "
        "(readable by <code>python -m odolab.evaluate</code> and evo; a name a file cannot hold as it is "
        "carries 8 hex digits of its digest, so no two odometers share a file); "
        f"<code>{GROUND_TRUTH_FILE}.tum</code> / <code>.kitti</code> are the true poses (the "
        "ground-truth row integrates exactly these, so it has no file of its own); "
        f"<code>{MANIFEST}</code> lists every file this run wrote.</p>"
    )
    page = f"""<!doctype html><html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<meta name="viewport" content="width=device-width, initial-scale=1"><style>{_STYLE}</style></head><body>
<h1>{html.escape(title)}</h1>
<ul>{"".join(f"<li>{html.escape(n)}</li>" for n in notes)}</ul>
{chr(10).join(sections)}
</body></html>
"""
    write_text_atomic(folder.path("report.html"), page)
    folder.finish()
