"""Evaluate one estimated trajectory against ground truth: pairing, alignment, ATE, RPE, KITTI drift.

The library behind ``python -m odolab.evaluate`` (a study, a notebook or a test calls these
directly). KITTI files pair line by line; TUM files pair by nearest timestamp exactly as ``evo``
does (:func:`odolab.io.tum.associate`). The estimate is aligned to the ground truth once; ATE, RPE
and the KITTI errors are computed on the aligned estimate. Definitions: :mod:`odolab.core.metrics`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from odolab.config import check, setting
from odolab.core import metrics
from odolab.core.trajectory import Trajectory

__all__ = [
    "Evaluation",
    "Pairing",
    "evaluate_trajectory",
    "evaluation_to_dict",
    "pair_trajectories",
    "stamps_are_steps",
    "time_coverage",
]


#: Largest RPE pair distance (frames or m) a user may ask for.
MAX_DELTA = 1e6


@dataclass(frozen=True)
class ScoringSettings:
    """How estimates are scored: RPE pairs ``delta`` apart (frames or metres), timestamps paired within
    ``t_max_diff`` seconds (:func:`pair_trajectories`), an estimate refused when its coverage is
    below ``min_coverage`` (None: never)."""

    delta: float = setting(1.0, range=(0.0, MAX_DELTA), open_low=True, doc="RPE pair distance")
    t_max_diff: float = setting(0.01, range=(0.0, 60.0), doc="TUM: largest timestamp gap (s) of an associated pair")
    min_coverage: float | None = setting(None, range=(0.0, 1.0), doc="least coverage of an estimate")

    def __post_init__(self) -> None:
        check(self)


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
    """All metrics of one estimate against the ground truth (units in :mod:`odolab.core.metrics`)."""

    pairing: Pairing
    ate: metrics.ATEResult
    rpe: metrics.RPEResult
    kitti: metrics.KittiResult
    gt_poses: np.ndarray
    """Paired ground-truth poses (K, 4, 4)."""
    est_poses: np.ndarray
    """Paired estimated poses after the alignment (K, 4, 4), in the ground-truth world frame."""
    times: np.ndarray | None
    """Seconds since the first paired ground-truth pose (K,), or None for index pairing; steps
    instead of seconds when ``step_stamps``."""
    step_stamps: bool = False
    """Whether the ground truth's timestamps count steps (0, 1, 2, ...: the TUM files odolab writes
    for simulated episodes, which have no clock) rather than seconds."""


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


def stamps_are_steps(stamps: np.ndarray | None) -> bool:
    """Whether timestamps are step indices 0, 1, 2, ... (as odolab writes a simulated episode's
    trajectory, which has no clock) rather than seconds; False for None (no timestamps)."""
    if stamps is None or len(stamps) < 2:
        return False
    return bool(np.array_equal(np.asarray(stamps, dtype=np.float64), np.arange(len(stamps), dtype=np.float64)))


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
    return Evaluation(pairing, result, rpe, kitti, G, P_aligned, times, stamps_are_steps(gt.timestamps))


def _num(x: float) -> float | None:
    """JSON-safe float: NaN becomes null."""
    return None if x is None or not math.isfinite(x) else float(x)


def _stats_dict(s: metrics.ErrorStats) -> dict:
    return {
        k: (v if k == "n" else _num(v))
        for k, v in (
            ("rmse", s.rmse),
            ("mean", s.mean),
            ("median", s.median),
            ("std", s.std),
            ("min", s.min),
            ("max", s.max),
            ("n", s.n),
        )
    }


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
        "units": {
            "ate": "m (RMSE)",
            "rpe_trans": "m (RMSE)",
            "rpe_rot": "deg (RMSE)",
            "t_rel": "%",
            "r_rel": "deg/100 m",
            "coverage": "share of ground-truth poses within reach of an estimate",
        },
        "pairing": {
            "method": "by index" if p.method == "index" else "by timestamp (evo nearest-time rule)",
            "max_diff_s": p.max_diff,
            "largest_time_diff_s": p.largest_time_diff,
            "pairs": len(p.idx_gt),
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
