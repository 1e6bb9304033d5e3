"""Evaluate estimated trajectories against ground truth: ATE, RPE and KITTI drift.

Command line::

    python -m odolab.evaluate GT EST [EST ...] --format kitti|tum [--align none|se3|sim3]
        [--delta 1 --delta-unit f|m] [--t-max-diff 0.01] [--json] [--plot FILE.png]
        [--min-coverage X]

KITTI files pair line by line (unequal lengths are an error); TUM files pair by nearest timestamp
exactly as ``evo`` does (:func:`odolab.io.tum.associate`). The estimate is aligned to the ground
truth once (``--align``, default ``se3``: rigid Umeyama, as ``evo_ape -a``); ATE, RPE and the
KITTI errors are then computed on the aligned estimate (a rigid alignment changes neither RPE nor
the KITTI errors; ``sim3`` rescales them). Definitions: :mod:`odolab.metrics`. Every figure is
printed with its pairing, the poses used and dropped, the alignment and the coverage.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from odolab import metrics
from odolab.cli import ArgumentParser, UsageError, check_output_file, number, run_cli
from odolab.io.errors import FileFormatError
from odolab.trajectory import Trajectory
from odolab.trajectory_plot import IMAGE_SUFFIXES

__all__ = ["Pairing", "Evaluation", "pair_trajectories", "evaluate_trajectory", "evaluation_to_dict", "main"]

FORMATS = ("kitti", "tum")
#: Documented ranges of the numeric options.
MAX_DELTA = 1e6
MAX_TIME_DIFF = 60.0


@dataclass(frozen=True)
class Pairing:
    """Which ground-truth pose goes with which estimated pose.

    ``method`` is ``"index"`` (line i with line i) or ``"timestamp"`` (nearest time within
    ``max_diff`` seconds). ``idx_gt``/``idx_est`` (K,) index the two trajectories.
    """

    method: str
    idx_gt: np.ndarray
    idx_est: np.ndarray
    n_gt: int
    n_est: int
    coverage: float
    """Share of ground-truth poses the estimate covers, in [0, 1] (see :func:`pair_trajectories`)."""
    max_diff: float | None = None
    largest_time_diff: float | None = None

    def used(self, which: str) -> int:
        """Number of distinct poses of ``"gt"`` or ``"est"`` that take part in a pair."""
        return len(np.unique(self.idx_gt if which == "gt" else self.idx_est))


@dataclass(frozen=True)
class Evaluation:
    """All metrics of one estimate against the ground truth (units in :mod:`odolab.metrics`)."""

    pairing: Pairing
    ate: metrics.ATEResult
    rpe: metrics.RPEResult
    kitti: metrics.KittiResult
    gt_poses: np.ndarray
    """Paired ground-truth poses (K, 4, 4)."""
    est_poses: np.ndarray
    """Paired estimated poses after the alignment (K, 4, 4), in the ground-truth world frame."""
    times: np.ndarray | None
    """Seconds since the first paired ground-truth pose (K,), or None for index pairing."""


def pair_trajectories(gt: Trajectory, est: Trajectory, method: str, max_diff: float = 0.01) -> Pairing:
    """Pair ``est`` with ``gt`` by ``"index"`` (equal lengths required) or ``"timestamp"``.

    Raises ``ValueError`` (message without file names) if nothing or not everything can pair.
    """
    if method == "index":
        if len(gt) != len(est):
            raise ValueError(
                f"{len(est)} poses but the ground truth has {len(gt)}; "
                "KITTI files pair line by line and must have equal lengths"
            )
        idx = np.arange(len(gt))
        return Pairing("index", idx, idx.copy(), len(gt), len(est), 1.0 if len(gt) else 0.0)
    if method != "timestamp":
        raise ValueError(f"unknown pairing method {method!r}")
    if gt.timestamps is None or est.timestamps is None:
        raise ValueError("pairing by timestamp needs timestamps in both trajectories")
    from odolab.io.tum import associate

    idx_gt, idx_est = associate(gt.timestamps, est.timestamps, max_diff)
    if len(idx_gt) == 0:
        raise ValueError(
            f"no associable poses: no timestamp within {max_diff:g} s of a ground-truth one "
            f"(estimate {est.timestamps[0]:.6f}..{est.timestamps[-1]:.6f} s, "
            f"ground truth {gt.timestamps[0]:.6f}..{gt.timestamps[-1]:.6f} s)"
        )
    largest = float(np.max(np.abs(gt.timestamps[idx_gt] - est.timestamps[idx_est])))
    coverage = time_coverage(gt.timestamps, est.timestamps[idx_est], max_diff)
    return Pairing("timestamp", idx_gt, idx_est, len(gt), len(est), coverage, max_diff, largest)


def time_coverage(t_gt: np.ndarray, t_paired: np.ndarray, max_diff: float) -> float:
    """Share of ground-truth stamps ``t_gt`` within reach of a paired estimate stamp (s).

    Reach is half the estimate's median sampling interval, at least ``max_diff``: a complete
    30 Hz estimate of 100 Hz ground truth covers 1.0, one that lost tracking for the second half
    of the run about 0.5 (plain pairs / ground-truth poses would say 0.3 for both).
    """
    t = np.unique(t_paired)
    if len(t_gt) == 0 or len(t) == 0:
        return 0.0
    reach = max(max_diff, float(np.median(np.diff(t))) / 2 if len(t) > 1 else 0.0) + 1e-9
    k = np.clip(np.searchsorted(t, t_gt), 1, max(len(t) - 1, 1))
    nearest = np.minimum(np.abs(t_gt - t[k - 1]), np.abs(t_gt - t[np.minimum(k, len(t) - 1)]))
    return float(np.mean(nearest <= reach))


def evaluate_trajectory(
    gt: Trajectory,
    est: Trajectory,
    pairing: Pairing,
    align: str = "se3",
    delta: float = 1.0,
    delta_unit: str = "f",
) -> Evaluation:
    """ATE (m), RPE (m, deg) and KITTI errors (%, deg/100 m) of ``est`` on the paired poses.

    The estimate is aligned once (``align``) and every metric uses the aligned poses. Raises
    ``ValueError`` for a degenerate alignment or an RPE ``delta`` that yields no pair.
    """
    G = gt.poses[pairing.idx_gt]
    P = est.poses[pairing.idx_est]
    result = metrics.ate(G, P, align)
    P_aligned = metrics.apply_alignment(P, result.rotation, result.translation, result.scale)
    rpe = metrics.rpe(G, P_aligned, delta, delta_unit)
    kitti = metrics.kitti_relative_errors(G, P_aligned)
    times = None if gt.timestamps is None else gt.timestamps[pairing.idx_gt] - gt.timestamps[pairing.idx_gt[0]]
    return Evaluation(pairing, result, rpe, kitti, G, P_aligned, times)


def _num(x: float) -> float | None:
    """JSON-safe float: NaN becomes null."""
    return None if x is None or not math.isfinite(x) else float(x)


def _stats_dict(s: metrics.ErrorStats) -> dict:
    return {k: (v if k == "n" else _num(v)) for k, v in
            (("rmse", s.rmse), ("mean", s.mean), ("median", s.median), ("std", s.std),
             ("min", s.min), ("max", s.max), ("n", s.n))}


def evaluation_to_dict(ev: Evaluation) -> dict:
    """JSON-ready summary: headline figures (RMSEs, t_rel, r_rel) plus how they were obtained."""
    p = ev.pairing
    unit = "frames" if ev.rpe.delta_unit == "f" else "m"
    return {
        "ate": _num(ev.ate.rmse),
        "rpe_trans": _num(ev.rpe.trans.rmse),
        "rpe_rot": _num(ev.rpe.rot.rmse),
        "t_rel": _num(ev.kitti.t_rel),
        "r_rel": _num(ev.kitti.r_rel),
        "coverage": p.coverage,
        "units": {"ate": "m (RMSE)", "rpe_trans": "m (RMSE)", "rpe_rot": "deg (RMSE)",
                  "t_rel": "%", "r_rel": "deg/100 m", "coverage": "share of ground-truth poses within reach of an estimate"},
        "pairing": {
            "method": "by index" if p.method == "index" else "by timestamp (evo nearest-time rule)",
            "max_diff_s": p.max_diff,
            "largest_time_diff_s": p.largest_time_diff,
            "pairs": int(len(p.idx_gt)),
        },
        "poses": {
            "gt": {"total": p.n_gt, "used": p.used("gt"), "dropped": p.n_gt - p.used("gt")},
            "est": {"total": p.n_est, "used": p.used("est"), "dropped": p.n_est - p.used("est")},
        },
        "alignment": {
            "method": ev.ate.align,
            "scale": ev.ate.scale,
            "rotation": ev.ate.rotation.tolist(),
            "translation_m": ev.ate.translation.tolist(),
        },
        "ate_stats_m": _stats_dict(ev.ate),
        "rpe": {
            "delta": ev.rpe.delta,
            "delta_unit": unit,
            "pairs": "consecutive, chosen on the estimate (evo_rpe defaults)",
            "trans_stats_m": _stats_dict(ev.rpe.trans),
            "rot_stats_deg": _stats_dict(ev.rpe.rot),
        },
        "kitti": {
            "segments": ev.kitti.n_segments,
            "rule": "KITTI devkit: lengths 100..800 m, first frame every 10 frames",
            "per_length": [
                {"length_m": s.length, "segments": s.n, "t_rel": _num(s.t_rel), "r_rel": _num(s.r_rel)}
                for s in ev.kitti.per_length
            ],
        },
    }


# ----------------------------------------------------------------------------- command line


def _parser() -> argparse.ArgumentParser:
    ap = ArgumentParser(
        prog="python -m odolab.evaluate",
        description="ATE, RPE and KITTI drift of estimated trajectories against ground truth.",
    )
    ap.add_argument("gt", help="ground-truth trajectory file")
    ap.add_argument("est", nargs="+", help="estimated trajectory file(s)")
    ap.add_argument("--format", required=True, choices=FORMATS, help="file format of all files")
    ap.add_argument("--align", default="se3", choices=metrics.ALIGNMENTS,
                    help="Umeyama alignment of each estimate to the ground truth (default se3)")
    ap.add_argument("--delta", type=number("--delta", float, 0, MAX_DELTA), default=1.0,
                    help=f"RPE pair distance, > 0 and <= {MAX_DELTA:g} (default 1)")
    ap.add_argument("--delta-unit", default="f", choices=("f", "m"), help="frames or metres (default f)")
    ap.add_argument("--t-max-diff", type=number("--t-max-diff", float, 0, MAX_TIME_DIFF), default=0.01,
                    help=f"TUM: largest timestamp gap (s) of an associated pair, 0-{MAX_TIME_DIFF:g} (default 0.01)")
    ap.add_argument("--json", action="store_true", help="print JSON instead of a table")
    ap.add_argument("--plot", metavar="FILE.png",
                    help=f"draw trajectories and errors into this image ({', '.join(IMAGE_SUFFIXES)})")
    ap.add_argument("--min-coverage", type=number("--min-coverage", float, 0, 1), default=None, metavar="X",
                    help="fail (exit 2) if an estimate's coverage is below X, 0-1. Coverage: the share of "
                         "ground-truth poses with an estimate within reach (half the estimate's median "
                         "interval, at least --t-max-diff), so a complete estimate at half the rate covers 1")
    return ap


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
        f"ground truth: {gt_path} ({rows[0][1].pairing.n_gt} poses, {fmt}); pairing {pairing}; "
        f"align {args.align}; RPE delta {args.delta:g} {unit}, consecutive pairs (evo_rpe defaults); "
        "figures are RMSEs",
    ]
    cols = ["estimate", "pairs", "dropped gt/est", "coverage", "scale", f"ATE m ({args.align})",
            "RPE m", "RPE deg", "t_rel %", "r_rel deg/100m", "segments"]

    def f(x: float, spec: str) -> str:
        return "-" if not math.isfinite(x) else format(x, spec)

    body = []
    for path, ev in rows:
        p = ev.pairing
        body.append([
            path, str(len(p.idx_gt)), f"{p.n_gt - p.used('gt')}/{p.n_est - p.used('est')}",
            f"{p.coverage:.3f}", f"{ev.ate.scale:.4f}", f(ev.ate.rmse, ".4f"), f(ev.rpe.trans.rmse, ".4f"),
            f(ev.rpe.rot.rmse, ".4f"), f(ev.kitti.t_rel, ".4f"), f(ev.kitti.r_rel, ".4f"),
            str(ev.kitti.n_segments),
        ])
    from odolab.summary import text_table

    return "\n".join(head + [text_table(cols, body)])


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; see the module docstring."""
    args = _parser().parse_args(argv)
    if args.plot:
        check_output_file(Path(args.plot), "--plot", IMAGE_SUFFIXES)
    if args.delta <= 0 or (args.delta_unit == "f" and args.delta != int(args.delta)):
        raise UsageError(f"--delta must be positive (a whole number of frames for -u f), got {args.delta:g}")

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
            ev = evaluate_trajectory(gt, est, pairing, args.align, args.delta, args.delta_unit)
        except ValueError as exc:
            raise UsageError(f"{path}: {exc}") from None
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
    if args.plot:  # after the table: a failing figure never loses it
        from odolab.trajectory_plot import plot_evaluations

        try:
            plot_evaluations(args.plot, [(os.path.basename(p), ev) for p, ev in rows])
        except (OSError, ValueError) as exc:
            raise UsageError(f"--plot {args.plot}: the figure could not be written ({exc})") from None
        print(f"plot written to {args.plot}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(run_cli(main, "odolab.evaluate"))
