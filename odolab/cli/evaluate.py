"""Evaluate estimated trajectories against ground truth: ATE, RPE and KITTI drift.

Command line::

    python -m odolab.evaluate GT EST [EST ...] [--format kitti|tum] [--align none|se3|sim3]
        [--delta 1 --delta-unit f|m] [--t-max-diff 0.01] [--json] [--plot FILE.png]
        [--min-coverage X]

Without ``--format`` the format is told from the files' column count (8: TUM, 12: KITTI; a file
whose extension, ``.tum`` or ``.kitti``, says otherwise, or files of both formats, are refused).
KITTI files pair line by line (unequal lengths are an error); TUM files pair by nearest timestamp
exactly as ``evo`` does (:func:`odolab.io.tum.associate`). The estimate is aligned to the ground
truth once (``--align``, default ``se3``: rigid Umeyama, as ``evo_ape -a``); ATE, RPE and the
KITTI errors are then computed on the aligned estimate (a rigid alignment changes neither RPE nor
the KITTI errors; ``sim3`` rescales them). Definitions: :mod:`odolab.core.metrics`. Every figure is
printed with its pairing, the poses used and dropped, the alignment and the coverage.
This module parses, calls :mod:`odolab.running.scoring` (the library: pairing, metrics, JSON summary)
and prints.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Sequence

import numpy as np

from odolab.cli.args import (
    ArgumentParser,
    UsageError,
    add_setting,
    check_output_file,
    exit_process,
    file_arg,
    run_cli,
    setting_type,
)
from odolab.config import range_text
from odolab.core import metrics
from odolab.core.trajectory import Trajectory
from odolab.io.errors import FileFormatError
from odolab.reporting.trajectory_plot import IMAGE_SUFFIXES
from odolab.running.scoring import (
    Evaluation,
    ScoringSettings,
    evaluate_trajectory,
    evaluation_to_dict,
    pair_trajectories,
)

__all__ = ["main"]

FORMATS = ("kitti", "tum")


# ----------------------------------------------------------------------------- command line


def _parser() -> argparse.ArgumentParser:
    ap = ArgumentParser(
        prog="python -m odolab.evaluate",
        description="ATE, RPE and KITTI drift of estimated trajectories against ground truth.",
    )
    ap.add_argument("gt", help="ground-truth trajectory file")
    ap.add_argument("est", nargs="+", help="estimated trajectory file(s)")
    ap.add_argument(
        "--format",
        default=None,
        choices=FORMATS,
        help="file format of all files (default: told from their column count, 8 TUM, 12 KITTI)",
    )
    ap.add_argument(
        "--align",
        default="se3",
        choices=metrics.ALIGNMENTS,
        help="Umeyama alignment of each estimate to the ground truth (default se3)",
    )
    add_setting(ap, "--delta", ScoringSettings, "delta", metavar="D")
    ap.add_argument("--delta-unit", default="f", choices=("f", "m"), help="frames or metres (default f)")
    add_setting(ap, "--t-max-diff", ScoringSettings, "t_max_diff", metavar="S")
    ap.add_argument("--json", action="store_true", help="print JSON instead of a table")
    ap.add_argument(
        "--plot",
        metavar="FILE.png",
        type=file_arg("--plot"),
        help=f"draw trajectories and errors into this image ({', '.join(IMAGE_SUFFIXES)})",
    )
    ap.add_argument(
        "--min-coverage",
        type=setting_type("--min-coverage", ScoringSettings, "min_coverage"),
        default=None,
        metavar="X",
        help=f"fail (exit 2) if an estimate's coverage is below X, {range_text(ScoringSettings, 'min_coverage')} "
        "(default: none, never fails). Coverage: the share of "
        "ground-truth poses with an estimate within reach (half the estimate's median "
        "interval, at least --t-max-diff), so a complete estimate at half the rate covers 1",
    )
    return ap


def _format(paths: list[str]) -> str:
    """The one format of all ``paths``, told from their column counts; :class:`UsageError` naming
    the file that cannot be told, or two files of different formats."""
    from odolab.io.textfiles import infer_format

    found: dict[str, str] = {}
    for path in paths:
        try:
            found[path] = infer_format(path)
        except FileFormatError as exc:
            raise UsageError(str(exc)) from None
        first = paths[0]
        if found[path] != found[first]:
            raise UsageError(
                f"{path} is a {found[path].upper()} file but {first} a {found[first].upper()} file; "
                "give files of one format"
            )
    return found[paths[0]]


def _kitti_note(path: str, ev: Evaluation) -> str | None:
    """Why the KITTI errors of ``path`` are ``-`` (no segment), or None when there are some."""
    if ev.kitti.n_segments:
        return None
    length = float(metrics.path_lengths(ev.gt_poses[:, :3, 3])[-1]) if len(ev.gt_poses) else 0.0
    lo, hi = metrics.KITTI_LENGTHS[0], metrics.KITTI_LENGTHS[-1]
    return (
        f"note: {path}: t_rel and r_rel are '-': the KITTI errors need a segment of {lo:g}-{hi:g} m of the "
        f"ground truth, and its paired poses span a path of {length:.4g} m"
    )


def _read(path: str, fmt: str, duplicates: dict[str, int]) -> Trajectory:
    """Read ``path``; TUM duplicate timestamps dropped (first kept) are counted in ``duplicates``."""
    from odolab.io.kitti import read_kitti_poses
    from odolab.io.tum import read_tum_file

    try:
        if fmt == "kitti":
            return read_kitti_poses(path)
        traj, duplicates[path] = read_tum_file(path)
        return traj
    except FileFormatError as exc:
        raise UsageError(str(exc)) from None


def _table(gt_path: str, fmt: str, args: argparse.Namespace, rows: list[tuple[str, Evaluation]]) -> str:
    pairing = "by index" if fmt == "kitti" else f"by timestamp, max diff {args.t_max_diff:g} s"
    dropped = [f"{n} in {p}" for p, n in args.duplicates.items() if n]
    if dropped:
        pairing += f" (repeated timestamps dropped, first kept: {', '.join(dropped)})"
    unit = "frames" if args.delta_unit == "f" else "m"
    head = [
        (
            f"ground truth: {gt_path} ({rows[0][1].pairing.n_gt} poses, {fmt}); pairing {pairing}; "
            f"align {args.align}; RPE delta {args.delta:g} {unit}, consecutive pairs (evo_rpe defaults); "
            "figures are RMSEs"
        ),
    ]
    cols = [
        "estimate",
        "pairs",
        "dropped gt/est",
        "coverage",
        "scale",
        f"ATE m ({args.align})",
        "RPE m",
        "RPE deg",
        "t_rel %",
        "r_rel deg/100m",
        "segments",
    ]

    from odolab.running.summary import fmt as f
    from odolab.running.summary import text_table

    body = []
    for path, ev in rows:
        p = ev.pairing
        body.append(
            [
                path,
                str(len(p.idx_gt)),
                f"{p.n_gt - p.used('gt')}/{p.n_est - p.used('est')}",
                f"{p.coverage:.3f}",
                f(ev.ate.scale, ".4f"),
                f(ev.ate.rmse, ".4f"),
                f(ev.rpe.trans.rmse, ".4f"),
                f(ev.rpe.rot.rmse, ".4f"),
                f(ev.kitti.t_rel, ".4f"),
                f(ev.kitti.r_rel, ".4f"),
                str(ev.kitti.n_segments),
            ]
        )
    return "\n".join(head + [text_table(cols, body)])


def _same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether paths ``a`` and ``b`` name one file: the same real path (links resolved), or, both
    existing, the same file by device and inode (hard links)."""
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet)
        return False


def _check_plot_is_no_input(plot: str | os.PathLike, gt: str, estimates: Sequence[str]) -> None:
    """:class:`UsageError` when ``--plot`` names the ground truth or an estimate (directly or
    through a link), which the figure would replace; checked before any work."""
    for role, path in [("the ground truth", gt), *(("an estimate", p) for p in estimates)]:
        if _same_file(plot, path):
            raise UsageError(
                f"--plot {plot}: expected a new image file, found {role} ({path}), which the figure would "
                "replace; give --plot another path"
            )


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; see the module docstring."""
    args = _parser().parse_args(argv)
    if args.plot:
        _check_plot_is_no_input(args.plot, args.gt, args.est)
        check_output_file(args.plot, "--plot", IMAGE_SUFFIXES)
    if args.delta_unit == "f" and args.delta != int(args.delta):
        raise UsageError(
            f"--delta must be a whole number of frames with --delta-unit f (the default), got {args.delta:g}; "
            "for metres give --delta-unit m"
        )

    from odolab.io.inputs import check_regular_file

    for path in [args.gt, *args.est]:  # a pipe or device (e.g. a link to /dev/zero) would never end
        try:
            check_regular_file(path)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    if args.format is None:
        args.format = _format([args.gt, *args.est])
    args.duplicates = {}
    gt = _read(args.gt, args.format, args.duplicates)
    method = "index" if args.format == "kitti" else "timestamp"
    rows: list[tuple[str, Evaluation]] = []
    for path in args.est:
        est = _read(path, args.format, args.duplicates)
        try:
            pairing = pair_trajectories(gt, est, method, args.t_max_diff)
        except ValueError as exc:
            raise UsageError(f"{path} vs {args.gt}: {exc}") from None
        if args.min_coverage is not None and pairing.coverage < args.min_coverage:
            raise UsageError(
                f"{path}: coverage {pairing.coverage:.3f} is below --min-coverage {args.min_coverage:g} "
                f"(share of the {pairing.n_gt} ground-truth poses with an estimate within reach)"
            )
        try:
            with np.errstate(over="ignore", invalid="ignore"):  # coordinates near 1e308: "-" in the table, no warning
                ev = evaluate_trajectory(gt, est, pairing, args.align, args.delta, args.delta_unit)
        except ValueError as exc:
            hint = (
                "; --align none evaluates without aligning" if args.align != "none" and "alignment" in str(exc) else ""
            )
            raise UsageError(f"{path}: {exc}{hint}") from None
        rows.append((path, ev))

    if args.json:
        doc = {
            "gt": {"path": args.gt, "format": args.format, "poses": len(gt)},
            "estimates": [{"path": p, **evaluation_to_dict(ev)} for p, ev in rows],
        }
        json.dump(doc, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(_table(args.gt, args.format, args, rows))
        for path, ev in rows:
            note = _kitti_note(path, ev)
            if note:
                print(note)
    if args.plot:  # after the table: a failing figure never loses it
        from odolab.reporting.trajectory_plot import plot_evaluations

        try:
            plot_evaluations(args.plot, [(os.path.basename(p), ev) for p, ev in rows])
        except (OSError, ValueError) as exc:
            raise UsageError(f"--plot {args.plot}: the figure could not be written ({exc})") from None
        print(f"plot written to {args.plot}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    exit_process(run_cli(main, "python -m odolab.evaluate"))
