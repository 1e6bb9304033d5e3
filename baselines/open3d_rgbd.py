"""Open3D's dense RGB-D odometry (``compute_rgbd_odometry``; Steinbruecker's photometric term by default).

The peer a user would reach for (with Open3D's own defaults on the TUM frames:
docs/reference-facts.md section 6). Called with the current frame as *source* and the previous one
as *target*, Open3D returns the motion mapping source points into the target camera, i.e.
``T_prev_cur``. It is started from each of :func:`~baselines.motion_search.initial_guesses` with
``iterations`` per pyramid level and, only when none of those is accepted, with
``fallback_iterations``. Open3D reports success on frames that do not overlap, so
:func:`~baselines.verification.verify` (motion bounds, depth agreement, grey-level correlation)
decides as well as the flag.

Why the defaults (photometric term, two pyramid levels, depth to 6 m, a three-level fallback, a
wider depth tolerance): the simulator's depth distortion pulls a depth-to-depth residual, so depth
only warps; a 341 x 192 frame's coarser levels have too little texture; large rooms leave few
pixels within 4 m (measurements: docs/odometers.md#open3d-rgbd).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from baselines.config import OdometerConfig
from baselines.covariance import covariance_from_information
from baselines.depth_geometry import DepthRange, FrameMemo, depth_mask, image_texture, normal_constraint
from baselines.motion_search import initial_guesses
from baselines.open3d_threads import one_thread
from baselines.verification import first_verified
from odolab.api import Action, Estimate, Frame, Intrinsics, Odometer, check_choice, config_digest, configure

__all__ = ["Open3DRGBDConfig", "Open3DRGBDOdometer"]

_odo = o3d.pipelines.odometry
_JACOBIANS = {
    "hybrid": _odo.RGBDOdometryJacobianFromHybridTerm,
    "color": _odo.RGBDOdometryJacobianFromColorTerm,
}


#: Pyramid levels at most (each halves the image: a 341 x 192 frame is 11 x 6 pixels at the sixth)
#: and iterations per level at most (a level converges in tens; a million would never end).
MAX_LEVELS, MAX_ITERATIONS = 6, 1000


@dataclass(frozen=True)
class Open3DRGBDConfig(OdometerConfig):
    """Options of :class:`Open3DRGBDOdometer` (besides ``verify``, see
    :class:`~baselines.config.OdometerConfig`). Depth is trusted to 6 m, not the 4 m of Open3D's own
    default and of the other baselines: the photometric term uses depth only to warp; the TUM
    reference figure used 4 m. Two readings of a surface z m away agree within 0.01 + 0.015 z^2 m
    (the other baselines: 0.01 + 0.01 z^2), which the simulator's depth noise needs beyond 3 m
    (measurements: docs/odometers.md#open3d-rgbd)."""

    depth: DepthRange = DepthRange(max_depth=6.0, noise_growth=0.015)

    #: ``"color"`` (photometric; depth only warps) or ``"hybrid"`` (photometric + geometric).
    term: str = "color"
    #: Iterations per pyramid level, coarse to fine (the number of levels).
    iterations: tuple[int, ...] = (20, 5)
    #: A second schedule, tried from the same starts only when ``iterations`` found nothing the
    #: images confirm (``()``: none).
    fallback_iterations: tuple[int, ...] = (20, 10, 5)
    #: Open3D's correspondence gate, metres of depth difference.
    depth_diff_max: float = 0.03
    #: Fewer usable depth pixels in a frame = invalid step.
    min_depth_pixels: int = 200
    #: A frame below both this texture (mean grey-level step, :func:`~baselines.depth_geometry.image_texture`) ...
    min_texture: float = 0.5
    #: ... and this normal constraint (0 to 1/3, :func:`~baselines.depth_geometry.normal_constraint`)
    #: is featureless (e.g. a blank wall): invalid step.
    min_normal_constraint: float = 0.02

    def __post_init__(self) -> None:
        check_choice("term", self.term, _JACOBIANS)
        for name, fewest in (("iterations", 1), ("fallback_iterations", 0)):
            its = getattr(self, name)
            if (
                isinstance(its, (str, bytes))
                or not hasattr(its, "__len__")
                or not fewest <= len(its) <= MAX_LEVELS
                or not all(
                    isinstance(n, (int, np.integer)) and not isinstance(n, bool) and 1 <= n <= MAX_ITERATIONS
                    for n in its
                )
            ):
                raise ValueError(
                    f"{name}: expected a list of {fewest}-{MAX_LEVELS} whole numbers (one per pyramid "
                    f"level, coarse to fine) each in 1-{MAX_ITERATIONS}, got {its!r:.80}"
                )
            object.__setattr__(self, name, tuple(int(n) for n in its))


class Open3DRGBDOdometer(Odometer):
    """``open3d.pipelines.odometry.compute_rgbd_odometry`` behind odolab's interface.

    Configured by :class:`Open3DRGBDConfig` (``config``, or keyword overrides of its fields, e.g.
    ``Open3DRGBDOdometer(term="hybrid", max_depth=3.0)``). Started from each of
    :func:`~baselines.motion_search.initial_guesses` until one is accepted.

    Covariance: ``sigma^2 * inv(I)`` with ``I`` the information matrix Open3D returns (point-to-
    point, previous camera frame, (rx, ry, rz, tx, ty, tz)) and ``sigma^2`` a third of the mean
    squared depth residual of the agreeing points. Optimistic in absolute terms (dense pixels are
    not independent).
    """

    Config = Open3DRGBDConfig  # its options: every field of Open3DRGBDConfig (odolab.odometry.configured)

    def __init__(self, config: Open3DRGBDConfig | None = None, **overrides) -> None:
        self.config = configure(Open3DRGBDConfig, config, **overrides)
        self.identity_digest = config_digest(self.config)  # results kept per odometer follow its settings
        self._images: FrameMemo[o3d.geometry.RGBDImage | None] = FrameMemo()

    def reset(self, intrinsics: Intrinsics) -> None:
        super().reset(intrinsics)
        self._images.clear()

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate:
        """``T_prev_cur`` by dense RGB-D alignment from each initial guess until one checks out."""
        cfg = self.config
        target = self._images.get(prev, lambda: self._rgbd(prev))
        source = self._images.get(cur, lambda: self._rgbd(cur))
        if target is None or source is None or self._featureless(prev) or self._featureless(cur):
            return Estimate.invalid()
        guesses = initial_guesses(action, prev, cur, self.intrinsics, cfg.depth)
        found, refined = None, []
        for schedule in (cfg.iterations, cfg.fallback_iterations):
            if found is None and schedule:
                found = first_verified(
                    guesses,
                    lambda T, its=schedule: self._align(source, target, T, its),
                    prev,
                    cur,
                    action,
                    self.intrinsics,
                    cfg.depth,
                    cfg.verify,
                    refined,
                )
        if found is None:  # refused: the first guess's alignment is the unverified estimate
            return Estimate.invalid(unverified=refined[0] if refined else None)
        sigma2 = found.check.depth.rms**2 / 3.0  # per-coordinate variance of the agreeing depths
        return Estimate(found.T_prev_cur, covariance=covariance_from_information(found.detail, sigma2))

    def _align(
        self,
        source: o3d.geometry.RGBDImage,
        target: o3d.geometry.RGBDImage,
        guess: np.ndarray,
        iterations: tuple[int, ...],
    ) -> tuple[np.ndarray | None, np.ndarray]:
        """Open3D's ``T_prev_cur`` (None when it fails) and information matrix, from ``guess``, with
        ``iterations`` per pyramid level."""
        i, cfg = self.intrinsics, self.config
        camera = o3d.camera.PinholeCameraIntrinsic(i.width, i.height, i.fx, i.fy, i.cx, i.cy)
        option = _odo.OdometryOption(
            o3d.utility.IntVector(iterations), cfg.depth_diff_max, cfg.depth.min_depth, cfg.depth.max_depth
        )
        with one_thread():  # the same answer every run (baselines.open3d_threads)
            ok, T, info = _odo.compute_rgbd_odometry(source, target, camera, guess, _JACOBIANS[cfg.term](), option)
        T = np.asarray(T)
        return (T if ok and np.all(np.isfinite(T)) else None), np.asarray(info)

    def _featureless(self, frame: Frame) -> bool:
        """No texture for the photometric term and no shape for the geometric one."""
        cfg = self.config
        return (
            image_texture(frame.rgb) < cfg.min_texture
            and normal_constraint(frame.depth, self.intrinsics, cfg.depth) < cfg.min_normal_constraint
        )

    def _rgbd(self, frame: Frame) -> o3d.geometry.RGBDImage | None:
        """Open3D's RGB-D image of ``frame`` (unusable depth zeroed); None if too little depth."""
        mask = depth_mask(frame.depth, self.config.depth)
        if mask.sum() < self.config.min_depth_pixels:
            return None
        depth = np.where(mask, frame.depth, 0.0).astype(np.float32)
        return o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(np.ascontiguousarray(frame.rgb, dtype=np.uint8)),
            o3d.geometry.Image(depth),
            depth_scale=1.0,
            depth_trunc=self.config.depth.max_depth,
            convert_rgb_to_intensity=True,
        )
