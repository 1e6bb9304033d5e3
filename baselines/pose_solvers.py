"""Relative pose from matched features: essential matrix with depth scale, PnP, planar fit.

The solvers of :mod:`baselines.feature_essential`, free of any odometer state. Conventions are
odolab's (:mod:`odolab.api`): camera axes x right, y down, z forward, metres; pixels (u, v) along
width and height; ``T_prev_cur`` maps current-camera points into the previous camera.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from odolab.api import Intrinsics

#: Success probability OpenCV's RANSAC loops aim for (essential matrix and PnP).
RANSAC_CONFIDENCE = 0.999
#: EPnP and its Levenberg-Marquardt refinement need at least this many inliers.
MIN_PNP_INLIERS = 4
#: The planar fit keeps pairs within this many median residuals of the 3D fit ...
PLANAR_OUTLIER_MEDIANS = 3.0
#: ... where the median counts as at least this much (metres): exact fits keep their noisy pairs.
PLANAR_MIN_RESIDUAL = 0.005


@dataclass(frozen=True)
class EssentialMotion:
    """What an essential matrix tells of ``T_prev_cur``: rotation ``R`` (3x3), translation
    direction ``t_dir`` (3,), unit length, no scale), the RANSAC inlier mask of the matches (N,)
    and how many of those inliers triangulate in front of both cameras (``n_in_front``)."""

    R: np.ndarray
    t_dir: np.ndarray
    inliers: np.ndarray
    n_in_front: int


def essential_motion(
    uv_prev: np.ndarray, uv_cur: np.ndarray, K: np.ndarray, ransac_px: float, iterations: int
) -> EssentialMotion | None:
    """OpenCV's ``findEssentialMat`` (RANSAC, ``ransac_px`` pixels, at most ``iterations``) and
    ``recoverPose`` on matched pixels (N, 2) of the two images; None when no matrix is found.

    The current image's points go first, so that ``R``, ``t_dir`` map current-camera points into
    the previous camera.
    """
    E, mask = cv2.findEssentialMat(uv_cur, uv_prev, K, cv2.RANSAC, RANSAC_CONFIDENCE, ransac_px, iterations)
    if E is None or E.shape != (3, 3) or mask is None:
        return None
    inliers = mask.ravel() > 0
    n_in_front, R, t_dir, _ = cv2.recoverPose(E, uv_cur[inliers], uv_prev[inliers], K)
    return EssentialMotion(R, t_dir.ravel(), inliers, int(n_in_front))


def scale_from_depth(P_prev: np.ndarray, P_cur: np.ndarray, R: np.ndarray, t_dir: np.ndarray) -> np.ndarray:
    """Paper step 3: ``T_prev_cur`` with rotation ``R`` and translation ``s * t_dir``.

    ``s`` is the median offset, along the direction, between the previous frame's points and
    the rotated current ones (points (N, 3) in metres, paired by row).
    """
    d = t_dir / np.linalg.norm(t_dir)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.median((P_prev - P_cur @ R.T) @ d) * d
    return T


def pnp(
    X: np.ndarray, uv: np.ndarray, K: np.ndarray, px: float, iterations: int
) -> tuple[np.ndarray | None, np.ndarray]:
    """``T`` (4x4) mapping points ``X`` (N, 3, metres) into the camera that sees them at pixels
    ``uv`` (N, 2), and the inlier mask (reprojection error < ``px`` pixels); T None on failure.

    EPnP in RANSAC (at most ``iterations``), then Levenberg-Marquardt on its inliers.
    """
    ok, rvec, tvec, inl = cv2.solvePnPRansac(
        X,
        uv,
        K,
        None,
        iterationsCount=iterations,
        reprojectionError=px,
        confidence=RANSAC_CONFIDENCE,
        flags=cv2.SOLVEPNP_EPNP,
    )
    mask = np.zeros(len(X), dtype=bool)
    if not ok or inl is None or len(inl) < MIN_PNP_INLIERS:
        return None, mask
    mask[inl.ravel()] = True
    rvec, tvec = cv2.solvePnPRefineLM(X[mask], uv[mask], K, None, rvec, tvec)
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = tvec.ravel()
    return T, reprojection_error(T, X, uv, K) < px


def translation_given_rotation(
    X: np.ndarray, uv: np.ndarray, R: np.ndarray, intr: Intrinsics, px: float, iterations: int = 100
) -> tuple[np.ndarray, np.ndarray]:
    """``t`` with ``uv ~ project(R X + t)``: 2-point RANSAC + linear least squares; (T 4x4, inliers).

    Points ``X`` (N, 3) in metres, pixels ``uv`` (N, 2), inliers within ``px`` pixels. Each pair
    gives two linear equations in ``t``: ``t_x - a t_z = a Y_z - Y_x`` and ``t_y - b t_z = b Y_z -
    Y_y`` with ``Y = R X`` and (a, b) the normalised pixel. Deterministic (seed 0).
    """
    Y = X @ R.T
    a = (uv[:, 0] - intr.cx) / intr.fx
    b = (uv[:, 1] - intr.cy) / intr.fy
    n = len(X)
    one, zero = np.ones(n), np.zeros(n)
    A = np.stack([np.stack([one, zero, -a], 1), np.stack([zero, one, -b], 1)], axis=1)  # (N, 2, 3)
    rhs = np.stack([a * Y[:, 2] - Y[:, 0], b * Y[:, 2] - Y[:, 1]], axis=1)  # (N, 2)
    T = np.eye(4)
    T[:3, :3] = R

    def solve(idx: np.ndarray) -> np.ndarray:
        return np.linalg.lstsq(A[idx].reshape(-1, 3), rhs[idx].reshape(-1), rcond=None)[0]

    rand = np.random.default_rng(0)
    best = np.zeros(n, dtype=bool)
    for _ in range(iterations):
        T[:3, 3] = solve(rand.choice(n, size=2, replace=False))
        inl = reprojection_error(T, X, uv, intr.matrix) < px
        if inl.sum() > best.sum():
            best = inl
    if best.sum() < 2:
        return T, best
    for _ in range(2):
        T[:3, 3] = solve(best)
        best = reprojection_error(T, X, uv, intr.matrix) < px
        if best.sum() < 2:
            break
    return T, best


def planar_procrustes(P_prev: np.ndarray, P_cur: np.ndarray, T: np.ndarray, yaw: float | None = None) -> np.ndarray:
    """Planar motion (dx, dz, dyaw) best mapping ``P_cur`` onto ``P_prev`` (N, 3) seen from above.

    Least squares on the (x, z) coordinates (metres) of the pairs within
    ``PLANAR_OUTLIER_MEDIANS`` median residuals of ``T`` (4x4); ``yaw`` (rad) fixes the rotation
    (oracle) and fits the translation only.
    """
    r = np.linalg.norm(P_prev - (P_cur @ T[:3, :3].T + T[:3, 3]), axis=1)
    keep = r <= PLANAR_OUTLIER_MEDIANS * max(np.median(r), PLANAR_MIN_RESIDUAL)
    a, b = P_cur[keep][:, [0, 2]], P_prev[keep][:, [0, 2]]
    ca, cb = a.mean(0), b.mean(0)
    H = (a - ca).T @ (b - cb)
    # b ~ R a + t with R = [[c, -s], [s, c]] in (x, z): x' = c x - s z, z' = s x + c z.
    if yaw is None:
        yaw = np.arctan2(H[0, 1] - H[1, 0], H[0, 0] + H[1, 1])
    c, s = np.cos(yaw), np.sin(yaw)
    t = cb - np.array([[c, -s], [s, c]]) @ ca
    return np.array([t[0], t[1], yaw])


def reprojection_error(T: np.ndarray, X: np.ndarray, uv: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pixel distance (N,) between ``uv`` and the projection of ``T`` applied to ``X``; inf behind
    the camera."""
    Y = X @ T[:3, :3].T + T[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        proj = (Y @ K.T)[:, :2] / Y[:, 2:3]
    err = np.linalg.norm(proj - uv, axis=1)
    return np.where(Y[:, 2] > 0, err, np.inf)
