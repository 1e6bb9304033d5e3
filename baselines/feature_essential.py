"""Feature matching + essential matrix + depth scale: the paper's E1 (and E2 with oracle rotation).

After Zhao et al. (ICCV 2021), appendix "Estimate Relative Pose from Depth": SIFT matches between
the two RGB frames (Lowe's ratio test), the rotation and the translation *direction* from OpenCV's
``findEssentialMat`` (RANSAC) and ``recoverPose``, the scale from depth (the inliers back-projected
in both frames, one set rotated by the estimate, a robust average of their offsets along the
direction). The direction needs parallax, so the essential matrix is used only when ``recoverPose``
keeps ``min_cheirality`` (50 %) of the inliers and the scaled translation is ``min_parallax`` (5 %)
of the median inlier depth; otherwise ``cv2.solvePnPRansac`` on the current frame's depth gives
``T_prev_cur`` (refined with Levenberg-Marquardt). With a known action, matches are searched only
where :func:`~baselines.motion_search.planar_search` puts each keypoint (``guide_px``) and the
result is fitted in the plane (``planar=False`` keeps 6-DoF). Each result is checked against the
images (``verify``, :func:`~baselines.verification.verify`): repetitive textures make wrong RANSAC
consensus common. Measurements behind these choices:
docs/odometers.md#feature-essential-the-papers-e1-and-feature-essential-oracle-rot-e2.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from baselines.config import OdometerConfig
from baselines.covariance import point_to_point_covariance
from baselines.depth_geometry import (
    FrameMemo,
    backproject_pixels,
    sample_depth,
    too_little_depth,
)
from baselines.motion_search import planar_search
from baselines.pose_solvers import (
    essential_motion,
    planar_procrustes,
    pnp,
    scale_from_depth,
    translation_given_rotation,
)
from baselines.verification import VerifyConfig, verify
from odolab.api import (
    Action,
    Estimate,
    Frame,
    Intrinsics,
    Odometer,
    config_digest,
    configure,
    invert,
    planar_to_transform,
    transform_to_planar,
)

__all__ = ["FeatureEssentialConfig", "FeatureEssentialOdometer", "OracleRotationFeatureEssentialOdometer"]


@dataclass(frozen=True)
class _Features:
    """Keypoint pixels (N, 2) as (u, v) and their descriptors (N, D) float32, of one frame."""

    uv: np.ndarray
    desc: np.ndarray | None


@dataclass(frozen=True)
class _Matches:
    """Matched pixels: ``prev[i]`` and ``cur[i]`` (each (N, 2), (u, v)) see the same point."""

    prev: np.ndarray
    cur: np.ndarray

    @staticmethod
    def none() -> _Matches:
        return _Matches(np.zeros((0, 2)), np.zeros((0, 2)))

    def __len__(self) -> int:
        return len(self.prev)

    def subset(self, index: np.ndarray) -> _Matches:
        """The matches at ``index`` (integer indices or a boolean mask)."""
        return _Matches(self.prev[index], self.cur[index])


@dataclass(frozen=True)
class _PoseFit:
    """A solver's ``T_prev_cur`` (4x4), the 3D pairs supporting it (matched inliers with depth in
    both frames, (N, 3) each, metres, in the previous and the current camera) and how it was
    solved: ``"essential"`` or ``"pnp"``."""

    T_prev_cur: np.ndarray
    P_prev: np.ndarray
    P_cur: np.ndarray
    path: str


#: Fewer matches than this leave no essential matrix worth fitting (invalid step).
MIN_MATCHES = 8
#: PnP needs at least this many matched points with depth in the current frame.
MIN_PNP_POINTS = 6
#: The planar fit and the covariance need at least this many 3D pairs.
MIN_3D_PAIRS = 4
#: Predicted keypoints closer than this (metres) in front of the current camera match nothing.
MIN_PREDICTED_DEPTH = 0.05
#: SIFT keypoints per frame by default at the simulator's image size (``SIM_IMAGE_AREA`` pixels,
#: 341 x 192), scaled with the image area up to ``MAX_AUTO_FEATURES``.
AUTO_FEATURES = 800
SIM_IMAGE_AREA = 341 * 192
MAX_AUTO_FEATURES = 2000


@dataclass(frozen=True)
class FeatureEssentialConfig(OdometerConfig):
    """Options of :class:`FeatureEssentialOdometer` (besides ``depth`` and ``verify``, see
    :class:`~baselines.config.OdometerConfig`; ``verify=None`` accepts every solved motion)."""

    verify: VerifyConfig | None = VerifyConfig()
    #: Fewer usable depth pixels in either frame = invalid step.
    min_depth_pixels: int = 500
    #: SIFT keypoints per frame; 0 = all; None = by image size (see ``_n_features``).
    n_features: int | None = None
    #: SIFT's contrast threshold (half OpenCV's default).
    contrast_threshold: float = 0.02
    #: Gaussian pre-blur before SIFT, pixels (0 = none).
    blur_sigma: float = 1.0
    #: Lowe's ratio test of the unguided matching.
    ratio: float = 0.8
    #: Guided matching (known action): search window radius, pixels (0 = off) ...
    guide_px: float = 20.0
    #: ... and its ratio test against the runner-up in the window.
    guide_ratio: float = 0.9
    #: Essential-matrix RANSAC threshold, pixels ...
    ransac_px: float = 1.0
    #: ... and iteration cap (OpenCV's 1000 is slow on the simulator's outlier-heavy matches).
    ransac_iterations: int = 200
    #: PnP (and oracle-rotation translation) RANSAC threshold, pixels (the 3D points add depth noise) ...
    pnp_px: float = 2.0
    #: ... and iteration cap of PnP ...
    pnp_iterations: int = 200
    #: ... and of the oracle-rotation translation fit.
    translation_iterations: int = 100
    #: Fewer final inliers = invalid step.
    min_inliers: int = 15
    #: Share of the essential matrix's inliers that ``recoverPose`` must keep, else PnP.
    min_cheirality: float = 0.5
    #: Depth-scaled baseline over the median inlier depth below which the essential matrix's
    #: direction is not trusted and PnP is used (0.05 ~ 3 degrees of parallax).
    min_parallax: float = 0.05
    #: With a known action, fit a planar motion to the final inliers.
    planar: bool = True


class FeatureEssentialOdometer(Odometer):
    """SIFT matches -> essential matrix (R, t direction) -> scale from depth; PnP when degenerate.

    Configured by :class:`FeatureEssentialConfig` (``config``, or keyword overrides of its fields,
    e.g. ``FeatureEssentialOdometer(ransac_px=2.0, max_depth=3.0)``).

    ``last_path`` tells how the last :meth:`step` solved: ``"essential"`` (the paper's pipeline),
    ``"pnp"`` (the fallback) or None (invalid).

    Covariance: point-to-point Gauss-Newton covariance of the final inliers that have depth in
    both frames (noise level from their residuals), see
    :func:`baselines.covariance.point_to_point_covariance`.
    """

    Config = FeatureEssentialConfig  # its options: every field of FeatureEssentialConfig (odolab.odometry.configured)

    def __init__(self, config: FeatureEssentialConfig | None = None, **overrides) -> None:
        self.config = configure(FeatureEssentialConfig, config, **overrides)
        self.identity_digest = config_digest(self.config)  # results kept per odometer follow its settings
        self._features: FrameMemo[_Features] = FrameMemo()
        self.last_path: str | None = None

    def reset(self, intrinsics: Intrinsics) -> None:
        super().reset(intrinsics)
        self._features.clear()

    # -- hooks -------------------------------------------------------------------------------

    def oracle_rotation(self, prev: Frame, cur: Frame) -> np.ndarray | None:
        """Rotation ``R_prev_cur`` (3x3) to use instead of the estimate; None = estimate it."""
        return None

    # -- the pipeline: match -> solve -> planarise -> verify ----------------------------------

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate:
        """``T_prev_cur`` from features; ``valid=False`` with too few matches, inliers or depth, or
        when the images do not confirm the result (``config.verify``)."""
        cfg = self.config
        R_oracle = self.oracle_rotation(prev, cur)
        self.last_path = None
        if any(too_little_depth(f.depth, cfg.depth, cfg.min_depth_pixels) for f in (prev, cur)):
            return Estimate.invalid()
        matches = self._match(prev, cur, action)
        if len(matches) < max(cfg.min_inliers, MIN_MATCHES):
            return Estimate.invalid()
        fit = self._solve_essential(prev, cur, matches, R_oracle)
        if fit is None:  # no parallax: the essential matrix cannot tell the direction
            fit = self._solve_pnp(prev, cur, matches, R_oracle)
        if fit is None:
            return Estimate.invalid()
        T = fit.T_prev_cur
        if action is not None and cfg.planar:
            T = _planarise(fit, fixed_yaw=R_oracle is not None)
        if cfg.verify is not None and verify(prev, cur, T, action, self.intrinsics, cfg.depth, cfg.verify) is None:
            return Estimate.invalid(unverified=T)  # what the paper's E1/E2 would have used
        self.last_path = fit.path
        return Estimate(T, covariance=_covariance(fit))

    def _solve_essential(self, prev: Frame, cur: Frame, m: _Matches, R_oracle: np.ndarray | None) -> _PoseFit | None:
        """The paper's solver (see the module docstring); None where it cannot be trusted."""
        cfg = self.config
        e = essential_motion(m.prev, m.cur, self.intrinsics.matrix, cfg.ransac_px, cfg.ransac_iterations)
        if e is None or e.n_in_front < max(cfg.min_inliers, cfg.min_cheirality * e.inliers.sum()):
            return None
        P_prev, P_cur = self._pairs_3d(prev, cur, m.subset(e.inliers))
        if len(P_prev) < cfg.min_inliers:
            return None
        T = scale_from_depth(P_prev, P_cur, e.R if R_oracle is None else R_oracle, e.t_dir)
        if np.linalg.norm(T[:3, 3]) < cfg.min_parallax * np.median(P_prev[:, 2]):
            return None
        return _PoseFit(T, P_prev, P_cur, "essential")

    def _solve_pnp(self, prev: Frame, cur: Frame, m: _Matches, R_oracle: np.ndarray | None) -> _PoseFit | None:
        """Pose from 3D points of the current frame and their pixels in the previous one (with an
        oracle rotation: the translation only)."""
        cfg, intr = self.config, self.intrinsics
        z_cur = sample_depth(cur.depth, m.cur, cfg.depth)
        has = z_cur > 0
        if has.sum() < max(cfg.min_inliers, MIN_PNP_POINTS):
            return None
        X_cur = backproject_pixels(m.cur[has, 0], m.cur[has, 1], z_cur[has], intr)
        uv_prev = m.prev[has]
        if R_oracle is None:
            T, inl = pnp(X_cur, uv_prev, intr.matrix, cfg.pnp_px, cfg.pnp_iterations)
        else:
            T, inl = translation_given_rotation(X_cur, uv_prev, R_oracle, intr, cfg.pnp_px, cfg.translation_iterations)
        if T is None or inl.sum() < cfg.min_inliers:
            return None
        P_prev, P_cur = self._pairs_3d(prev, cur, m.subset(np.flatnonzero(has)[inl]))
        return _PoseFit(T, P_prev, P_cur, "pnp")

    # -- features ----------------------------------------------------------------------------

    def _detect(self, frame: Frame) -> _Features:
        gray = cv2.cvtColor(np.ascontiguousarray(frame.rgb), cv2.COLOR_RGB2GRAY)
        cfg = self.config
        if cfg.blur_sigma > 0:
            gray = cv2.GaussianBlur(gray, (0, 0), cfg.blur_sigma)
        sift = cv2.SIFT_create(nfeatures=self._n_features(), contrastThreshold=cfg.contrast_threshold)
        kps, desc = sift.detectAndCompute(gray, None)
        uv = np.array([k.pt for k in kps], dtype=np.float64).reshape(-1, 2)
        return _Features(uv, desc)

    def _n_features(self) -> int:
        """``n_features``, or by default ``AUTO_FEATURES`` per 341x192 image area, at most
        ``MAX_AUTO_FEATURES`` (why: docs/odometers.md, feature-essential's keypoints)."""
        if self.config.n_features is not None:
            return int(self.config.n_features)
        area = self.intrinsics.width * self.intrinsics.height / SIM_IMAGE_AREA
        return int(np.clip(round(AUTO_FEATURES * area), AUTO_FEATURES, MAX_AUTO_FEATURES))

    def _match(self, prev: Frame, cur: Frame, action: Action | None = None) -> _Matches:
        """Ratio-test matches; with a known action, matches guided by the motion prior instead."""
        fp = self._features.get(prev, lambda: self._detect(prev))
        fc = self._features.get(cur, lambda: self._detect(cur))
        empty = _Matches.none()
        if fp.desc is None or fc.desc is None or len(fp.uv) < 2 or len(fc.uv) < 2:
            return empty
        if action is not None and self.config.guide_px > 0:
            return self._guided_match(prev, cur, fp, fc, action)
        pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(fp.desc, fc.desc, k=2)
        good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < self.config.ratio * p[1].distance]
        if not good:
            return empty
        i_prev = np.array([g.queryIdx for g in good])
        i_cur = np.array([g.trainIdx for g in good])
        return _Matches(fp.uv[i_prev], fc.uv[i_cur])

    def _guided_match(self, prev: Frame, cur: Frame, fp: _Features, fc: _Features, action: Action) -> _Matches:
        """Matches searched only near where the motion prior puts each previous keypoint.

        The prior is :func:`~baselines.motion_search.planar_search`'s best motion; a previous
        keypoint with depth is moved into the current image by it and may match only current
        keypoints within ``guide_px`` pixels, the nearest descriptor winning if it beats the
        runner-up in that window by ``guide_ratio`` and the match is mutual (the best previous
        keypoint for that current one, among those predicted near it). On repetitive textures
        (bricks, tiles) the global ratio test rejects most true matches: every brick looks alike.
        """
        intr = self.intrinsics
        T = planar_search(prev, cur, action, intr, self.config.depth)[0]
        z = sample_depth(prev.depth, fp.uv, self.config.depth)
        has = np.flatnonzero(z > 0)
        if len(has) < 2:
            return _Matches.none()
        X = backproject_pixels(fp.uv[has, 0], fp.uv[has, 1], z[has], intr)
        T_cur_prev = invert(T)
        Y = X @ T_cur_prev[:3, :3].T + T_cur_prev[:3, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            pred = (Y @ intr.matrix.T)[:, :2] / Y[:, 2:3]
        # two 2-D outer differences: 10x faster than one (N, M, 2) broadcast
        du = np.subtract.outer(pred[:, 0], fc.uv[:, 0])
        dv = np.subtract.outer(pred[:, 1], fc.uv[:, 1])
        near = du * du + dv * dv < self.config.guide_px**2
        near &= (Y[:, 2] > MIN_PREDICTED_DEPTH)[:, None]
        a, b = fp.desc[has].astype(np.float32), fc.desc.astype(np.float32)
        d2 = np.sum(a * a, 1)[:, None] + np.sum(b * b, 1)[None, :] - 2.0 * (a @ b.T)
        d2 = np.where(near, d2, np.inf)
        best = np.argmin(d2, axis=1)
        rows = np.arange(len(has))
        first = d2[rows, best]
        d2[rows, best] = np.inf
        second = d2.min(axis=1)
        d2[rows, best] = first
        ok = np.isfinite(first) & (first < self.config.guide_ratio**2 * second)
        ok &= np.argmin(d2, axis=0)[best] == rows  # mutual
        return _Matches(fp.uv[has[ok]], fc.uv[best[ok]])

    def _pairs_3d(self, prev: Frame, cur: Frame, m: _Matches) -> tuple[np.ndarray, np.ndarray]:
        """The matches with depth in both frames, back-projected into each camera ((N, 3) each)."""
        z_prev = sample_depth(prev.depth, m.prev, self.config.depth)
        z_cur = sample_depth(cur.depth, m.cur, self.config.depth)
        ok = (z_prev > 0) & (z_cur > 0)
        P_prev = backproject_pixels(m.prev[ok, 0], m.prev[ok, 1], z_prev[ok], self.intrinsics)
        P_cur = backproject_pixels(m.cur[ok, 0], m.cur[ok, 1], z_cur[ok], self.intrinsics)
        return P_prev, P_cur


class OracleRotationFeatureEssentialOdometer(FeatureEssentialOdometer):
    """The paper's E2: :class:`FeatureEssentialOdometer` with the ground-truth rotation.

    The true ``R_prev_cur`` (from ``Frame.gt_pose``) replaces the estimated rotation in the depth
    scale step, and in the PnP fallback only the translation is fitted (linear least squares on
    the reprojection constraints). Raises ``ValueError`` when a frame has no ground truth.
    """

    oracle = True

    def oracle_rotation(self, prev: Frame, cur: Frame) -> np.ndarray:
        if prev.gt_pose is None or cur.gt_pose is None:
            raise ValueError(
                f"{self.name}: needs ground-truth poses (Frame.gt_pose) of both frames; this sequence has none"
            )
        return np.asarray(prev.gt_pose)[:3, :3].T @ np.asarray(cur.gt_pose)[:3, :3]


def _planarise(fit: _PoseFit, fixed_yaw: bool) -> np.ndarray:
    """The planar motion (4x4) closest to ``fit``: a planar least-squares fit of its 3D pairs seen
    from above (keeping ``fit``'s yaw when ``fixed_yaw``), or with too few pairs its projection."""
    T = fit.T_prev_cur
    if len(fit.P_prev) < MIN_3D_PAIRS:
        return planar_to_transform(*transform_to_planar(T))
    yaw = transform_to_planar(T)[2] if fixed_yaw else None
    return planar_to_transform(*planar_procrustes(fit.P_prev, fit.P_cur, T, yaw))


def _covariance(fit: _PoseFit) -> np.ndarray | None:
    """Point-to-point covariance of ``fit``'s 3D pairs (None with too few)."""
    if len(fit.P_prev) < MIN_3D_PAIRS:
        return None
    T = fit.T_prev_cur
    fitted = fit.P_cur @ T[:3, :3].T + T[:3, 3]
    return point_to_point_covariance(fitted, fit.P_prev - fitted)
