"""How far is the learned odometer's training budget from where it would cross the classical ones?
Validation error per action and component against samples seen and training hours, for one or more
robust-VO training runs, with the classical odometers' test errors as horizontal lines.

    python -m studies.robust_vo.scaling [--runs reports/robust-vo/shipped reports/robust-vo/shipped-341]
        [--classical reports/compare-val-20x100/table_per_action.csv] [--out reports/robust-vo/scaling]

Reads only committed reports: each run's ``curves.csv`` (written by ``python -m
odolab.learned.robust_vo.train``) and a comparison's ``table_per_action.csv`` (``python -m odolab.compare``).
A panel's samples seen count the training pairs of the stages that train its action (a stage trains
the actions it validates), up to that validation, in the order the stages ran, after those of the
model the run started from (its ``init``, as its ``training.json`` records it; that model's stages
are matched to actions through its own ``curves.csv`` beside it, else counted for every action); a
warm-started run's start is drawn as a dotted line. Hours are the training epochs' wall-clock of
every stage (pairs / pairs per second), validation left out. The curves are validation-split
errors; the lines are the comparison's errors as used, on the split its trajectories name (give a
validation-split comparison to set validation against validation). Writes ``scaling.png`` and
``scaling.csv`` (the plotted points).
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

ACTIONS = ("move_forward", "turn_left", "turn_right")
COMPONENTS = ("dx", "dz", "dyaw")
UNITS = {"dx": "m", "dz": "m", "dyaw": "rad"}
CLASSICAL = ("action-prior", "icp", "feature-essential", "open3d-rgbd")


@dataclass(frozen=True)
class Point:
    """One validation result of a run: after ``pairs`` training samples and ``hours`` of training."""

    run: str
    stage: str
    epoch: int
    pairs: int
    hours: float
    action: str
    component: str
    mae: float
    prior_mae: float
    start: int = 0  # samples of this action the model the run started from had seen (0: a fresh start)
    start_hours: float = 0.0  # that model's training hours
    start_from: str = ""  # that model's run (its folder's name), "" for a fresh start


def _read_csv(path: Path) -> list[dict[str, str]]:
    """The rows of CSV file ``path``; ``ValueError`` naming it when it cannot be read as text."""
    if path.is_dir():
        raise ValueError(f"{path}: is a folder, not a CSV file")
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text file (not UTF-8)") from None
    try:
        return list(csv.DictReader(io.StringIO(text)))
    except csv.Error as exc:
        raise ValueError(f"{path}: not a CSV file ({exc})") from None


def _count_field(r: dict[str, str], name: str) -> int:
    value = int(r[name])
    if value < 0:
        raise ValueError(name)
    return value


def _finite_field(r: dict[str, str], name: str, positive: bool = False) -> float:
    value = float(r[name])
    if not math.isfinite(value) or value < 0 or (positive and value == 0):
        raise ValueError(name)
    return value


def curves_file(run: Path) -> Path:
    """A run's ``curves.csv``: ``run`` is its report folder, or the file itself."""
    return run if run.name == "curves.csv" and run.is_file() else run / "curves.csv"


def stage_actions(rows: list[dict[str, str]]) -> dict[str, set[str]]:
    """Stage -> the actions it validates (and so trains), from a ``curves.csv``'s val rows."""
    out: dict[str, set[str]] = {}
    for r in rows:
        if r.get("split") == "val" and r.get("action") in ACTIONS:
            out.setdefault(r.get("stage", ""), set()).add(r["action"])
    return out


def init_offset(status: Path) -> tuple[dict[str, int], float, str]:
    """The samples seen per action and the training hours of the model a run started from
    (``init``), as its ``training.json`` records them (every stage of that model's own training; a
    stage counts for the actions its run's ``curves.csv`` beside the model validates, for every
    action where that file is not there), and that run's folder name; ({}, 0.0, "") for a run that
    started afresh or a folder without the file. ``ValueError`` names the file and field."""
    if not status.is_file():
        return {}, 0.0, ""
    try:
        doc = json.loads(status.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ValueError(f"{status}: not a readable training status ({exc})") from None
    init = doc.get("init", {}) if isinstance(doc, dict) else {}
    stages = init.get("stages", {}) if isinstance(init, dict) else {}
    try:
        seen = {name: _count_field({"n": s["pairs_seen"]}, "n") for name, s in stages.items()}
        hours = sum(_finite_field({"h": s["hours"]}, "h") for s in stages.values())
    except (AttributeError, KeyError, TypeError, ValueError):
        raise ValueError(
            f"{status}: init.stages: expected stage -> {{pairs_seen: whole number >= 0, hours: number >= 0}}"
        ) from None
    if not seen:
        return {}, hours, ""
    model = Path(str(init.get("path", "")))
    trains: dict[str, set[str]] = {}
    if (model.parent / "curves.csv").is_file():
        try:
            trains = stage_actions(_read_csv(model.parent / "curves.csv"))
        except ValueError:
            trains = {}
    per_action = {a: sum(n for name, n in seen.items() if a in trains.get(name, set(ACTIONS))) for a in ACTIONS}
    return per_action, hours, model.parent.name


def read_curves(folder: Path, name: str | None = None) -> list[Point]:
    """The validation points of the run whose reports are in ``folder`` (its ``curves.csv``; the
    file itself may be given), each with the samples seen and training hours up to it, labelled
    ``name`` (default: the folder's name). A run that started from a trained model (``init`` in
    its ``training.json``) counts that model's samples and hours first. ``ValueError`` names the
    file, row and field."""
    path = curves_file(folder)
    if path.parent.is_file() or (path.parent.exists() and not path.parent.is_dir()):
        raise ValueError(f"{folder}: is a file; expected a training report folder holding a curves.csv")
    name = name or path.parent.name
    rows = _read_csv(path)
    wanted = {"epoch", "split", "stage", "pairs", "pairs_per_s", "action", "component", "mae", "prior_mae"}
    if not rows or not wanted <= set(rows[0]):
        raise ValueError(
            f"{path}: expected a training curves file (python -m odolab.learned.robust_vo.train) with a header and "
            f"rows, columns {', '.join(sorted(wanted))}"
        )
    points = []
    start, init_hours, start_from = init_offset(path.parent / "training.json")
    hours = init_hours
    pairs = {a: start.get(a, 0) for a in ACTIONS}
    trains = stage_actions(rows)
    for k, r in enumerate(rows):
        try:
            if r["split"] == "train":
                seen = _count_field(r, "pairs")
                for a in trains.get(r["stage"], set(ACTIONS)):  # a stage that validates nothing: every action
                    pairs[a] += seen
                hours += seen / _finite_field(r, "pairs_per_s", positive=True) / 3600
            elif r["split"] == "val":
                points.append(
                    Point(
                        name,
                        r["stage"],
                        _count_field(r, "epoch"),
                        pairs.get(r["action"], 0),
                        hours,
                        r["action"],
                        r["component"],
                        _finite_field(r, "mae"),
                        _finite_field(r, "prior_mae"),
                        start.get(r["action"], 0),
                        init_hours,
                        start_from,
                    )
                )
        except (TypeError, ValueError):
            raise ValueError(
                f"{path}: row {k + 2}: expected whole numbers >= 0 in epoch and pairs, a number > 0 in pairs_per_s "
                "and numbers >= 0 in mae and prior_mae (no NaN or infinity)"
            ) from None
    if not points:
        raise ValueError(f"{path}: no validation rows (split = val): nothing to plot")
    return points


def read_classical(path: Path, odometers: tuple[str, ...] = CLASSICAL) -> dict[tuple[str, str, str], float]:
    """(odometer, action, component) -> test error in metres or radians, from ``table_per_action.csv``
    (which holds x 1e-2)."""
    rows = _read_csv(path)
    if not rows or not {"odometer", "action", *COMPONENTS} <= set(rows[0]):
        raise ValueError(f"{path}: expected a compare table_per_action.csv (odometer, action, dx, dz, dyaw)")
    out = {}
    for k, r in enumerate(rows):
        if r["odometer"] in odometers and r["action"] in ACTIONS:
            for c in COMPONENTS:
                try:
                    out[(r["odometer"], r["action"], c)] = _finite_field(r, c) * 1e-2
                except (TypeError, ValueError):
                    raise ValueError(f"{path}: row {k + 2}: {c}: expected a number >= 0, got {r[c]!r:.40}") from None
    return out


def classical_split(path: Path) -> str:
    """The split of the comparison whose ``table_per_action.csv`` is ``path``, as the names of its
    ``trajectories/<split>-s<seed>-e<index>`` folders say; "" when they do not (one split or none)."""
    folder = path.parent / "trajectories"
    try:
        names = {p.name.split("-")[0] for p in folder.iterdir()} if folder.is_dir() else set()
    except OSError:  # unreadable: the split is not known
        names = set()
    return names.pop() if len(names) == 1 and names <= {"train", "val", "test"} else ""


def draw(
    points: list[Point], classical: dict[tuple[str, str, str], float], path: Path, x: str = "pairs", split: str = ""
) -> None:
    """A 3 x 3 grid (actions x components) of validation error against ``x``: samples seen of the
    panel's action (``"pairs"``) or training hours (``"hours"``); a warm-started run's start as a
    dotted line from where its model's training ended; the classical rows' errors on ``split``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import ticker

    runs = list(dict.fromkeys(p.run for p in points))
    odometers = list(dict.fromkeys(k[0] for k in classical))
    fig, axes = plt.subplots(3, 3, figsize=(13, 10.5), sharex="row" if x == "pairs" else True)
    colours = plt.get_cmap("tab10")
    for i, action in enumerate(ACTIONS):
        for j, comp in enumerate(COMPONENTS):
            ax = axes[i, j]
            for r, run in enumerate(runs):
                mine = sorted(
                    (p for p in points if (p.run, p.action, p.component) == (run, action, comp)), key=lambda p: p.pairs
                )
                if mine:
                    warm = f", warm start from {mine[0].start_from}" if mine[0].start_from else ""
                    ax.plot(
                        [getattr(p, x) for p in mine],
                        [p.mae * 100 for p in mine],
                        "o-",
                        ms=3,
                        color=colours(r),
                        label=f"robust-vo {run} (val{warm})",
                    )
                    if mine[0].start_from:
                        begin = mine[0].start if x == "pairs" else mine[0].start_hours
                        ax.axvline(begin, ls=":", lw=1.2, color=colours(r))
            for k, odo in enumerate(odometers):
                if (odo, action, comp) in classical:
                    ax.axhline(
                        classical[(odo, action, comp)] * 100,
                        ls="--",
                        lw=1,
                        color=colours(len(runs) + k),
                        label=f"{odo} ({split or 'a comparison'})",
                    )
            ax.set_title(f"{action}: {comp}")
            ax.set_ylabel(f"mean abs. error ({UNITS[comp]} x 1e-2)")
            if x == "pairs":
                ax.set_xscale("log")
                ax.xaxis.set_major_formatter(ticker.FuncFormatter(_count))
                ax.xaxis.set_minor_formatter(ticker.NullFormatter())
            ax.grid(alpha=0.3)
            if x == "pairs" or i == 2:  # samples of the row's own action: each row its own axis
                ax.set_xlabel(
                    f"training samples of {'forward steps' if action == 'move_forward' else 'turns'} seen"
                    if x == "pairs"
                    else "training hours (2-core CPU)"
                )
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 4), frameon=False)
    what = "samples seen" if x == "pairs" else "training hours"
    lines = f"the classical rows' {split} errors" if split else "a comparison's errors"
    fig.suptitle(
        f"robust-vo validation error against {what}; {lines} as dashed lines; dotted: a warm-started run's start"
    )
    fig.tight_layout(rect=(0, 0.08, 1, 0.97))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _count(v: float, _pos: int) -> str:
    return f"{v / 1e6:g}M" if v >= 1e6 else f"{v / 1e3:g}k"


def write_points(points: list[Point], path: Path) -> None:
    from odolab.io.atomic import write_text_atomic

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["run", "stage", "epoch", "pairs_seen", "hours", "action", "component", "mae", "prior_mae"])
    for p in points:
        w.writerow(
            [
                p.run,
                p.stage,
                p.epoch,
                p.pairs,
                f"{p.hours:.3f}",
                p.action,
                p.component,
                f"{p.mae:.6g}",
                f"{p.prior_mae:.6g}",
            ]
        )
    write_text_atomic(path, buf.getvalue())


def run(args) -> int:
    """The study as its command line (:mod:`odolab.cli.study`) asks."""
    from odolab.cli import UsageError, check_report_dir

    if args.out.exists() and not args.out.is_dir():
        check_report_dir(args.out, "--out", manifest="scaling.csv")  # its one-line refusal
    files = [curves_file(folder).resolve() for folder in args.runs]
    twice = next((r for r, f in zip(args.runs, files) if files.count(f) > 1), None)
    if twice is not None:
        raise UsageError(f"--runs {twice}: given twice")
    names = [curves_file(folder).parent.name for folder in args.runs]
    if len(set(names)) < len(names):  # two folders of one name: their curves must not merge
        names = [str(curves_file(folder).parent) for folder in args.runs]
    try:
        points = [p for folder, name in zip(args.runs, names) for p in read_curves(folder, name)]
    except ValueError as exc:
        raise UsageError(f"--runs: {exc}") from None
    try:
        classical = read_classical(args.classical)
    except ValueError as exc:
        raise UsageError(f"--classical: {exc}") from None
    check_report_dir(args.out, "--out", manifest="scaling.csv")  # inputs read first: nothing made on a typo
    split = classical_split(args.classical)
    draw(points, classical, args.out / "scaling.png", "pairs", split)
    draw(points, classical, args.out / "scaling-hours.png", "hours", split)
    write_points(points, args.out / "scaling.csv")
    print(f"{len(points)} validation points of {len(args.runs)} runs -> {args.out}")
    return 0


if __name__ == "__main__":  # python -m studies.robust_vo.scaling: the command line is odolab.cli.study's
    import importlib

    study = importlib.import_module("odolab.cli.study")
    study.exit_process(study.command("robust-vo-scaling"))
