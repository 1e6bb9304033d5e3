"""Open3D's dense RGB-D odometry (``compute_rgbd_odometry``; Steinbruecker's photometric term by default).

The peer a user would reach for (docs/reference-facts.md section 6: 4.43 mm / 0.241 deg on the TUM frames with
default options and a 4 m depth cut). Called with the current frame as *source* and the previous
one as *target*, Open3D returns the motion mapping source points into the target camera, i.e.
``T_prev_cur``; checked against ground truth on TUM and on synthetic views with known motion.

Open3D reports success on frames that do not overlap (Open3D issue 3781; measured here too: a
blank depth image and an unrelated view both came back "successful"), so validity is judged on
the images (:func:`baselines.verification.verify`: motion bounds of the action, depth
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

Photometric term, two levels (val split, 12 episodes x 60 steps: ``python -m odolab.compare --split
val --episodes 12 --max-steps 60 --odometers open3d-rgbd --odometer-option open3d-rgbd.term=T
--odometer-option open3d-rgbd.iterations=[...]``): the hybrid term's geometric residual compares
the two depth images, and the simulator's Redwood distortion (a depth scale that changes across the
image) makes them disagree wherever the view shifts, most on turns; the photometric term uses depth
only to warp, where a few percent of depth error moves a pixel by a fraction of a pixel. With four
pyramid levels it diverged (more than 5 degrees off) on 77 of 141 steps started within 2 degrees
(the coarsest level, 21 x 12 pixels, has too little texture); with two on 7. Per-step error as
used (dx, dz, dyaw x 1e-2; failed steps take the prior), failed share: hybrid, 4 levels (1.68, 0.75,
1.14), 7.1 %; hybrid, 2 levels (1.58, 0.72, 1.09), 6.4 %; photometric, 1 level (0.76, 0.42, 0.79),
7.7 %; 3 levels (0.63, 0.37, 0.65), 7.9 %; 2 levels of 10 and 5 iterations (0.58, 0.34, 0.49), 5.1 %;
of 20 and 5 (0.59, 0.34, 0.51), 5.1 %. The default is 20 and 5: started from no motion (no action,
so no planar search; a real sequence), 10 coarse iterations left a synthetic 3-degree view of a TUM
frame 2.3 cm off, 15 or more find it to 0.6 mm (``tests/test_baselines.py``). On the TUM frames:
4.44 mm, 0.196 degrees (the hybrid set-up: 4.62 mm, 0.255 degrees).

Where it still failed, in navigation (81 steps of five fused-odometry test episodes the agent lost
its way in, replayed): in large rooms most pixels lay beyond the 4 m cut (median depth 4.5 m, a
quarter of the pixels left), and near walls (median depth 0.2-1 m) every start diverged from
turns the planar search misjudged by 10-18 cm, though the true motion passes the checks. Trusting
depth to 6 m answered 26 of the 81 (median yaw error 0.07 degrees), and a three-level schedule
(20, 10, 5) tried only after the two-level one failed, 14 more (``fallback_iterations``; four levels:
5 more). On the val split (12 x 60, the command above): 4 m (0.59, 0.34, 0.51), ATE 0.276 m, drift
0.418 m, 5.1 % failed; 5 m (0.55, 0.32, 0.47), 0.276 m, 5.0 %; 6 m (0.53, 0.32, 0.45), 0.238 m,
4.3 %; 8 m (0.55, 0.32, 0.51), 0.279 m, 5.8 %; 6 m with the fallback (0.54, 0.32, 0.42), 0.224 m,
drift 0.345 m, 3.8 %: the default.

Far views failed the image check, not the alignment (``python -m studies.turns_by_depth``: 400
turns from random poses of 20 val scenes, binned by median depth): Open3D's answer was within 0.2
degrees of the truth, and the image check refused it: the simulator's depth noise outgrows the
shared tolerance 0.01 + 0.01 z^2 m beyond 3 m, so that fewer than the required 80 % of the points
agree in depth even for the true motion (it failed the check in 6 of the first 8 views of that
study reaching past 4.5 m: ``tests/test_turns_study.py``). With 0.01 + 0.015 z^2, turns beyond
4 m fail 14.6 % of the time (56.2 %), at 2-4 m 0.9 % (5.3 %), all 5.5 % (12.7 %), at the same
accuracy; on the val split (12 x 60, the command above): (0.51, 0.31, 0.35), ATE 0.152 m, drift
0.238 m, 2.6 % failed (0.02 z^2: the same to 0.003 m). Near walls (median depth below 1 m) 11.6 %
of turns still fail: there the grey levels of even the true motion correlate poorly (a blurred,
magnified texture under 25 grey levels of noise), and the check cannot rule out a slide along
the wall.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from baselines.config import OdometerConfig, check_choice, config_digest, configure, options_signature
from baselines.covariance import covariance_from_information
from baselines.depth_geometry import DepthRange, FrameMemo, depth_mask, image_texture, normal_constraint
from baselines.motion_search import initial_guesses
from baselines.open3d_threads import one_thread
from baselines.verification import first_verified
from odolab.api import Action, Estimate, Frame, Intrinsics, Odometer

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
    default and of the other baselines: the photometric term uses depth only to warp (module
    docstring); the TUM reference figure used 4 m. Two readings of a surface z m away agree within
    0.01 + 0.015 z^2 m (the other baselines: 0.01 + 0.01 z^2), which the simulator's depth noise needs
    beyond 3 m (module docstring)."""

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

    __signature__ = options_signature(Open3DRGBDConfig)  # the options, not just (config, **overrides)

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
        found = None
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
                )
        if found is None:
            return Estimate.invalid()
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
