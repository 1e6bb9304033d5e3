"""Every metric odolab reports, with its exact definition. Pure math: no files, no plots.

Poses are ``(N, 4, 4)`` arrays ``T_world_cam`` (metres); ground truth ``G_i`` and estimate
``P_i`` are paired by index (associate timestamps first, see :func:`odolab.io.tum.associate`).

Per-step error (the paper's tables, Zhao et al. ICCV 2021, Table S4)
---------------------------------------------------------------------
For each step t with estimated planar motion ``(dx, dz, dyaw)_t`` and the true one (conventions in
:mod:`odolab.core.geometry`)::

    e_t = ( |dx_t - dx*_t|, |dz_t - dz*_t|, |wrap(dyaw_t - dyaw*_t)| )      (m, m, rad)

The paper reports the mean of ``e_t`` over steps, multiplied by 100 ("x 1e-2").

Absolute trajectory error (:func:`ate`)
---------------------------------------
Sturm et al., "A Benchmark for the Evaluation of RGB-D SLAM Systems", IROS 2012, and evo's
``APE`` with ``pose_relation=translation_part`` (``evo_ape ... [-a [-s]]``)::

    e_i = || s * R_a p_i + t_a - g_i ||                                       (m)

where ``p_i``, ``g_i`` are the estimated and true positions and ``(R_a, t_a, s)`` the Umeyama
(1991) least-squares fit of the estimate onto the ground truth (identity for ``align='none'``;
``s = 1`` for ``'se3'``). Statistics (RMSE, mean, median, std, min, max) are over all poses.

Relative pose error (:func:`rpe`)
---------------------------------
Same sources; evo's ``RPE`` with its ``evo_rpe`` defaults::

    E_ij = inv(inv(G_i) G_j) * inv(P_i) P_j
    trans_ij = || t(E_ij) ||  (m),     rot_ij = angle(R(E_ij))  (deg, geodesic, in [0, 180])

Pairs ``(i, j)`` come from the estimate, as evo does by default (``pairs_from_reference=False``):

* ``delta_unit='f'``: consecutive pairs ``(0, d), (d, 2d), ...``; with ``all_pairs=True`` every
  ``(i, i + d)``.
* ``delta_unit='m'``: consecutive pairs: walking the estimate from the last pair end, the next end
  is the first pose at which the path travelled since reaches ``>= d`` metres. With
  ``all_pairs=True``: for every ``i``, the ``j > i`` whose path length from ``i`` is closest to
  ``d``, kept if within ``rel_delta_tol * d``.

KITTI relative errors (:func:`kitti_relative_errors`)
-----------------------------------------------------
Geiger et al., CVPR 2012, devkit ``evaluate_odometry.cpp``: path length ``L(k)`` accumulates
ground-truth position steps. Segments start at every 10th frame ``f`` and have nominal lengths
``len`` in 100, 200, ..., 800 m; the last frame ``l`` is the first with ``L(l) > L(f) + len``
(segments running off the end are skipped). With ``E = inv(inv(P_f) P_l) * inv(G_f) G_l``::

    t_err = || t(E) || / len   (m/m),     r_err = angle(R(E)) / len   (rad/m)

``t_rel = 100 * mean(t_err)`` (%) and ``r_rel = mean(r_err) * 180/pi * 100`` (deg/100 m), means over
all segments of all lengths pooled; also per segment length.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from odolab.core.geometry import invert, rotation_angle, wrap_angle

__all__ = [
    "ALIGNMENTS",
    "KITTI_LENGTHS",
    "ATEResult",
    "ErrorStats",
    "KittiLengthStats",
    "KittiResult",
    "RPEResult",
    "apply_alignment",
    "ate",
    "kitti_relative_errors",
    "path_lengths",
    "per_step_abs_error",
    "relative_motion_errors",
    "rpe",
    "rpe_pairs",
    "umeyama_alignment",
]

#: Accepted values of ``align``: none, rigid (rotation + translation), similarity (+ scale).
ALIGNMENTS = ("none", "se3", "sim3")
#: KITTI devkit segment lengths (m).
KITTI_LENGTHS = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
_KITTI_STEP = 10


def per_step_signed_error(est_planar: np.ndarray, gt_planar: np.ndarray) -> np.ndarray:
    """Signed planar errors (N, 3), estimate minus truth per step: dx m, dz m, dyaw rad (wrapped to
    [-pi, pi)); their mean is an odometer's bias (a steady over- or under-estimate that integrates)."""
    est = np.asarray(est_planar, dtype=np.float64).reshape(-1, 3)
    gt = np.asarray(gt_planar, dtype=np.float64).reshape(-1, 3)
    if est.shape != gt.shape:
        raise ValueError(f"per-step error: shapes differ, {est.shape} vs {gt.shape}")
    err = est - gt
    err[:, 2] = wrap_angle(err[:, 2])
    return err


def per_step_abs_error(est_planar: np.ndarray, gt_planar: np.ndarray) -> np.ndarray:
    """Absolute planar errors (N, 3): |dx| m, |dz| m, |dyaw| rad (wrapped) per step."""
    return np.abs(per_step_signed_error(est_planar, gt_planar))


# ----------------------------------------------------------------------------- value types


@dataclass(frozen=True)
class ErrorStats:
    """Summary of a set of errors (same unit as the errors); NaN when there are none.

    ``std`` is the population standard deviation (numpy default, as in evo).
    """

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    n: int

    @classmethod
    def of(cls, errors: np.ndarray) -> ErrorStats:
        """Statistics of a 1-D error array; finite wherever the errors are (errors near 1e300 are
        scaled down first, :func:`_scaled`, where squaring or summing them would overflow)."""
        e = np.asarray(errors, dtype=np.float64).reshape(-1)
        if e.size == 0:
            nan = float("nan")
            return cls(nan, nan, nan, nan, nan, nan, 0)
        with np.errstate(over="ignore", invalid="ignore"):
            return cls(
                rmse=_scaled(e, lambda x: np.sqrt(np.mean(x * x))),
                mean=_scaled(e, np.mean),
                median=float(np.median(e)),
                std=_scaled(e, np.std),
                min=float(np.min(e)),
                max=float(np.max(e)),
                n=int(e.size),
            )


@dataclass(frozen=True)
class ATEResult(ErrorStats):
    """Absolute trajectory error (m) and the alignment used.

    ``errors``: per-pose position error (N,) m. ``rotation`` (3x3), ``translation`` (3,) m and
    ``scale`` map estimate world coordinates into ground-truth ones: ``g ~ s R p + t``.
    """

    errors: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    align: str = "none"
    scale: float = 1.0
    rotation: np.ndarray = field(repr=False, default_factory=lambda: np.eye(3))
    translation: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(3))


@dataclass(frozen=True)
class RPEResult:
    """Relative pose error over index pairs ``pairs`` (K, 2) of the paired pose arrays.

    ``trans_errors`` (K,) m and ``rot_errors`` (K,) deg; ``trans`` and ``rot`` their statistics.
    """

    trans: ErrorStats
    rot: ErrorStats
    trans_errors: np.ndarray = field(repr=False)
    rot_errors: np.ndarray = field(repr=False)
    pairs: np.ndarray = field(repr=False)
    delta: float = 1.0
    delta_unit: str = "f"
    all_pairs: bool = False


@dataclass(frozen=True)
class KittiLengthStats:
    """KITTI errors of the ``n`` segments of one nominal length (m): t_rel %, r_rel deg/100 m."""

    length: float
    n: int
    t_rel: float
    r_rel: float


@dataclass(frozen=True)
class KittiResult:
    """KITTI devkit relative errors. ``t_rel`` in %, ``r_rel`` in deg per 100 m (NaN if no segment).

    Per segment (K,): ``first``, ``last`` frame, nominal ``length`` (m), ``t_err`` (m/m),
    ``r_err`` (rad/m). ``per_length``: the same means per nominal length (lengths with segments).
    """

    t_rel: float
    r_rel: float
    n_segments: int
    per_length: tuple[KittiLengthStats, ...]
    first: np.ndarray = field(repr=False)
    last: np.ndarray = field(repr=False)
    length: np.ndarray = field(repr=False)
    t_err: np.ndarray = field(repr=False)
    r_err: np.ndarray = field(repr=False)


# ----------------------------------------------------------------------------- building blocks


def _scaled(e: np.ndarray, stat: Callable[[np.ndarray], np.floating]) -> float:
    """``stat(e)`` for a statistic that scales with its input (``stat(c e) = c stat(e)``, c > 0):
    computed directly, and again on ``e / max|e|`` (times ``max|e|``) only when the direct value
    overflowed although every error is finite (e.g. errors of 1e300 m), so usual values are
    unchanged to the last bit."""
    value = float(stat(e))
    if np.isfinite(value) or not np.all(np.isfinite(e)):
        return value
    scale = float(np.max(np.abs(e)))
    return float(scale * stat(e / scale))


def row_norms(v: np.ndarray) -> np.ndarray:
    """Euclidean norms (N,) of the rows of ``v`` (N, K): ``np.linalg.norm(v, axis=1)``, computed
    again after scaling for a finite row whose norm overflowed (entries near 1e300)."""
    with np.errstate(over="ignore"):
        n = np.linalg.norm(v, axis=1)
    over = np.isinf(n) & np.all(np.isfinite(v), axis=1)
    if over.any():
        m = np.max(np.abs(v[over]), axis=1)
        n[over] = m * np.linalg.norm(v[over] / m[:, None], axis=1)
    return n


def _as_poses(poses: np.ndarray, name: str) -> np.ndarray:
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim != 3 or p.shape[1:] != (4, 4):
        raise ValueError(f"{name}: expected poses of shape (N, 4, 4), got {p.shape}")
    return p


def _paired(gt_poses: np.ndarray, est_poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    gt, est = _as_poses(gt_poses, "gt_poses"), _as_poses(est_poses, "est_poses")
    if len(gt) != len(est):
        raise ValueError(f"{len(gt)} ground-truth poses but {len(est)} estimated poses; pair them first")
    if len(gt) == 0:
        raise ValueError("no poses to evaluate")
    return gt, est


def path_lengths(positions: np.ndarray) -> np.ndarray:
    """Accumulated path length (N,) m along positions (N, 3); the first entry is 0."""
    p = np.asarray(positions, dtype=np.float64)
    steps = row_norms(p[:-1] - p[1:])
    return np.concatenate(([0.0], np.cumsum(steps)))


def umeyama_alignment(src: np.ndarray, dst: np.ndarray, with_scale: bool) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares similarity ``dst ~ s R src + t`` of paired points (N, 3) (Umeyama, PAMI 1991).

    Returns ``(R (3, 3), t (3,), s)``; ``s = 1`` unless ``with_scale``. A reflection is never
    returned (``det R = +1``). Raises ``ValueError`` if the points are degenerate (covariance
    rank < 2, e.g. all on one line), as evo does.
    """
    x = np.asarray(src, dtype=np.float64)
    y = np.asarray(dst, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 2:
        raise ValueError(f"umeyama_alignment: point sets differ in shape, {x.shape} vs {y.shape}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError("alignment impossible: a position is not a finite number")
    n, m = x.shape
    # coordinates near 1e308 would overflow the sums (and LAPACK's SVD of an inf never returns): each
    # set is then scaled to at most 1 first, which leaves R unchanged and scales s and t back
    kx, ky = (_unit_scale(a) for a in (x, y))
    x, y = x / kx, y / ky
    mx, my = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - mx, y - my
    var_x = float(np.sum(xc * xc)) / n
    cov = yc.T @ xc / n
    u, d, vt = np.linalg.svd(cov)
    if np.count_nonzero(d > np.finfo(d.dtype).eps / (kx * ky)) < m - 1:
        raise ValueError(f"alignment impossible: the {n} paired positions are degenerate (all on a line or a point)")
    S = np.eye(m)
    if np.linalg.det(u) * np.linalg.det(vt) < 0.0:
        S[-1, -1] = -1.0
    R = u @ S @ vt
    s = float(np.sum(d * np.diag(S)) / var_x * (ky / kx)) if with_scale else 1.0
    t = ky * my - s * (R @ (kx * mx))
    return R, t, s


def _unit_scale(points: np.ndarray, limit: float = 1e100) -> float:
    """1, or the largest absolute coordinate where it passes ``limit`` (points scaled by it keep
    their sums and products finite)."""
    big = float(np.max(np.abs(points))) if points.size else 0.0
    return big if big > limit else 1.0


def apply_alignment(poses: np.ndarray, R: np.ndarray, t: np.ndarray, s: float = 1.0) -> np.ndarray:
    """Poses (N, 4, 4) moved by the similarity ``x -> s R x + t`` (rotations: ``R @ R_i``)."""
    p = _as_poses(poses, "poses")
    out = p.copy()
    out[:, :3, :3] = R @ p[:, :3, :3]
    out[:, :3, 3] = s * p[:, :3, 3] @ R.T + t
    return out


def _align(gt: np.ndarray, est: np.ndarray, align: str) -> tuple[np.ndarray, np.ndarray, float]:
    if align not in ALIGNMENTS:
        raise ValueError(f"align must be one of {ALIGNMENTS}, got {align!r}")
    if align == "none":
        return np.eye(3), np.zeros(3), 1.0
    return umeyama_alignment(est[:, :3, 3], gt[:, :3, 3], with_scale=(align == "sim3"))


def _relative_errors(gt: np.ndarray, est: np.ndarray, i: np.ndarray, j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``E = inv(inv(G_i) G_j) inv(P_i) P_j`` for index arrays: (||t_E|| m, angle(R_E) rad)."""
    dg = invert(gt[i]) @ gt[j]
    dp = invert(est[i]) @ est[j]
    E = invert(dg) @ dp
    return row_norms(E[:, :3, 3]), rotation_angle(E[:, :3, :3])


# ----------------------------------------------------------------------------- metrics


def ate(gt_poses: np.ndarray, est_poses: np.ndarray, align: str = "none") -> ATEResult:
    """Absolute trajectory error (m) of paired poses after ``align`` in ``none|se3|sim3``."""
    gt, est = _paired(gt_poses, est_poses)
    R, t, s = _align(gt, est, align)
    p = s * est[:, :3, 3] @ R.T + t
    errors = row_norms(p - gt[:, :3, 3])
    st = ErrorStats.of(errors)
    return ATEResult(**st.__dict__, errors=errors, align=align, scale=s, rotation=R, translation=t)


def rpe_pairs(
    poses: np.ndarray, delta: float, delta_unit: str = "f", all_pairs: bool = False, rel_delta_tol: float = 0.1
) -> np.ndarray:
    """Index pairs (K, 2) for the RPE, chosen on ``poses`` as evo does (module docstring)."""
    p = _as_poses(poses, "poses")
    n = len(p)
    if delta <= 0:
        raise ValueError(f"delta must be positive, got {delta}")
    if delta_unit == "f":
        if float(delta) != int(delta):
            raise ValueError(f"delta in frames must be a whole number, got {delta}")
        d = int(delta)
        i = np.arange(n - d) if all_pairs else np.arange(0, n, d)[:-1]
        return np.stack([i, i + d], axis=1).astype(np.intp).reshape(-1, 2)
    if delta_unit != "m":
        raise ValueError(f"delta_unit must be 'f' (frames) or 'm' (metres), got {delta_unit!r}")
    pos = p[:, :3, 3]
    if all_pairs:
        cum = path_lengths(pos)
        pairs = []
        # Candidates: the nearest accumulated lengths below and above cum[i] + delta.
        hi = np.searchsorted(cum, cum + delta, side="left")
        for i in range(n - 1):
            cand = {min(max(hi[i], i + 1), n - 1), min(max(hi[i] - 1, i + 1), n - 1)}
            best = min(cand, key=lambda k: (abs((cum[k] - cum[i]) - delta), k))
            # evo takes the first index reaching the minimum: step back over equal lengths.
            best = max(int(np.searchsorted(cum, cum[best], side="left")), i + 1)
            if abs((cum[best] - cum[i]) - delta) <= delta * rel_delta_tol:
                pairs.append((i, best))
        return np.array(pairs, dtype=np.intp).reshape(-1, 2)
    steps = row_norms(pos[1:] - pos[:-1]).tolist()
    ids, travelled = [0], 0.0
    for k, step in enumerate(steps, start=1):
        travelled += step
        if travelled >= delta:
            ids.append(k)
            travelled = 0.0
    ids_arr = np.array(ids, dtype=np.intp)
    return np.stack([ids_arr[:-1], ids_arr[1:]], axis=1)


def rpe(
    gt_poses: np.ndarray,
    est_poses: np.ndarray,
    delta: float = 1.0,
    delta_unit: str = "f",
    all_pairs: bool = False,
    rel_delta_tol: float = 0.1,
    pairs_from_gt: bool = False,
) -> RPEResult:
    """Relative pose error: translation (m) and rotation (deg) over pairs ``delta`` apart.

    Defaults reproduce ``evo_rpe`` defaults (delta 1 frame, consecutive pairs chosen on the
    estimate). Raises ``ValueError`` when ``delta`` yields no pair.
    """
    gt, est = _paired(gt_poses, est_poses)
    pairs = rpe_pairs(gt if pairs_from_gt else est, delta, delta_unit, all_pairs, rel_delta_tol)
    if len(pairs) == 0:
        raise ValueError(_no_rpe_pair(gt if pairs_from_gt else est, delta, delta_unit, rel_delta_tol))
    trans, rot = _relative_errors(gt, est, pairs[:, 0], pairs[:, 1])
    rot = np.degrees(rot)
    return RPEResult(
        trans=ErrorStats.of(trans),
        rot=ErrorStats.of(rot),
        trans_errors=trans,
        rot_errors=rot,
        pairs=pairs,
        delta=float(delta),
        delta_unit=delta_unit,
        all_pairs=all_pairs,
    )


def _no_rpe_pair(poses: np.ndarray, delta: float, delta_unit: str, rel_tol: float) -> str:
    """Why ``delta`` gives no RPE pair among ``poses``, in words that are true for the case."""
    unit = "frames" if delta_unit == "f" else "m"
    if len(poses) < 2:
        return f"RPE needs at least 2 poses to compare, got {len(poses)}"
    if delta_unit == "f":
        return (
            f"RPE: delta = {delta:g} frames gives no pose pair among {len(poses)} poses; "
            f"a delta of at most {len(poses) - 1} frames does"
        )
    length = float(path_lengths(poses[:, :3, 3])[-1])
    if length == 0:
        return f"RPE: delta = {delta:g} m gives no pose pair: the {len(poses)} poses do not move (a path of 0 m)"
    if delta > length:
        return (
            f"RPE: delta = {delta:g} {unit} gives no pose pair: the path is {length:.4g} m long; "
            "a delta shorter than the path does"
        )
    return f"RPE: no two of the {len(poses)} poses are {delta:g} {unit} apart along the path (within {rel_tol:.0%})"


def relative_motion_errors(gt_poses: np.ndarray, est_poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Consecutive-frame RPE: translation (N-1,) m and rotation (N-1,) deg of frame pairs (i, i+1)."""
    gt, est = _paired(gt_poses, est_poses)
    i = np.arange(len(gt) - 1)
    trans, rot = _relative_errors(gt, est, i, i + 1)
    return trans, np.degrees(rot)


def kitti_relative_errors(
    gt_poses: np.ndarray, est_poses: np.ndarray, lengths: tuple[float, ...] = KITTI_LENGTHS
) -> KittiResult:
    """KITTI devkit translational (%) and rotational (deg/100 m) drift; see the module docstring."""
    gt, est = _paired(gt_poses, est_poses)
    cum = path_lengths(gt[:, :3, 3])
    starts = np.arange(0, len(gt), _KITTI_STEP)
    lens = np.asarray(lengths, dtype=np.float64)
    # Row-major over (first frame, length) like the devkit's loops.
    first = np.repeat(starts, len(lens))
    seg_len = np.tile(lens, len(starts))
    last = np.searchsorted(cum, cum[first] + seg_len, side="right")  # first L(l) > L(f) + len
    ok = last < len(gt)
    first, seg_len, last = first[ok], seg_len[ok], last[ok]
    # Devkit: E = inv(inv(P_f) P_l) * inv(G_f) G_l; norms equal those of its inverse.
    dg = invert(gt[first]) @ gt[last]
    dp = invert(est[first]) @ est[last]
    E = invert(dp) @ dg
    t_err = row_norms(E[:, :3, 3]) / seg_len
    r_err = rotation_angle(E[:, :3, :3]) / seg_len

    def summary(mask: np.ndarray) -> tuple[float, float]:
        if not mask.any():
            return float("nan"), float("nan")
        return float(100.0 * t_err[mask].mean()), float(np.degrees(r_err[mask].mean()) * 100.0)

    t_rel, r_rel = summary(np.ones(len(first), dtype=bool))
    per_length = tuple(
        KittiLengthStats(float(L), int(np.sum(seg_len == L)), *summary(seg_len == L))
        for L in lens
        if np.any(seg_len == L)
    )
    return KittiResult(
        t_rel=t_rel,
        r_rel=r_rel,
        n_segments=len(first),
        per_length=per_length,
        first=first,
        last=last,
        length=seg_len,
        t_err=t_err,
        r_err=r_err,
    )
