"""Point-cloud ICP odometry with Open3D: colored ICP (depth + texture), coarse to fine.

Each frame's depth (every ``pixel_stride``-th pixel row and column, 2) is back-projected (odolab
camera axes, metres), cut to ``[min_depth, max_depth]`` and voxel-downsampled at two ``levels`` (2
and 1 x ``voxel``, 4 cm: 8 and 4 cm; correspondences up to 16 and 6 cm) with normals and mean
colours; the clouds are built once per frame and reused by the next step. The current cloud is
registered onto the previous one under a Tukey kernel (``tukey_k``), so the result is ``T_prev_cur``
directly, from the first ``max_starts`` (2) of :func:`~baselines.motion_search.initial_guesses`
until :func:`~baselines.verification.verify` accepts one
(:func:`~baselines.verification.first_verified`); ICP's own fitness is not trusted.

Why: the colour term pins a slide along a single textured wall, where point-to-plane ICP
(``variant="point_to_plane"``) slides; the searched starts, two levels and the kernel keep it from
diverging; 4 cm voxels average out the RGB noise at a fraction of 2 cm's cost (measurements:
docs/odometers.md#icp).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from baselines.config import OdometerConfig
from baselines.covariance import covariance_from_information
from baselines.depth_geometry import FrameMemo, backproject, normal_constraint
from baselines.motion_search import initial_guesses
from baselines.open3d_threads import one_thread
from baselines.verification import first_verified
from odolab.api import (
    Action,
    Estimate,
    Frame,
    Intrinsics,
    Odometer,
    check,
    check_choice,
    config_digest,
    configure,
    setting,
)

__all__ = ["ICPConfig", "ICPOdometer"]

_reg = o3d.pipelines.registration
_VARIANTS = ("point_to_plane", "colored")


@dataclass(frozen=True)
class ICPConfig(OdometerConfig):
    """Options of :class:`ICPOdometer` (besides ``depth`` and ``verify``, see
    :class:`~baselines.config.OdometerConfig`; the 4 m depth cut: beyond it the depth is coarsely
    quantised on a Kinect and in the simulator's Redwood model, >5 cm steps)."""

    variant: str = setting("colored", doc='"colored" (depth + texture) or "point_to_plane"')
    pixel_stride: int = setting(2, range=(1, 64), doc="back-project every n-th pixel row and column")
    voxel: float = setting(0.04, range=(1e-4, 1.0), doc="finest voxel edge, m")
    #: Per level, coarse to fine: (voxel as a multiple of ``voxel``, correspondence reach as a
    #: multiple of that level's voxel).
    levels: tuple[tuple[float, float], ...] = setting(
        ((2.0, 2.0), (1.0, 1.5)), doc="per level, coarse to fine: (voxel multiple, reach multiple of the level's voxel)"
    )
    normal_radius: float = setting(2.0, range=(0.1, 100.0), doc="normals from neighbours within this many voxels ...")
    normal_neighbours: int = setting(15, range=(3, 1000), doc="... and at most this many of them")
    max_iterations: int = setting(10, range=(1, 10_000), doc="ICP iterations per level")
    tolerance: float = setting(1e-5, range=(0.0, 1.0), doc="relative change of fitness and RMSE that ends a level")
    geometric_weight: float = setting(
        0.968, range=(0.0, 1.0), doc="colored ICP's weight of the geometric term against the colour term"
    )
    tukey_k: float | None = setting(0.05, range=(1e-4, 10.0), doc="Tukey kernel width, m; None: least squares")
    max_starts: int = setting(2, range=(1, 100), doc="initial guesses tried, best first")
    min_cloud_points: int = setting(200, range=(3, 10**7), doc="fewer points in the finest cloud: invalid step ...")
    min_coarse_points: int = setting(20, range=(3, 10**7), doc="... or fewer in the coarsest cloud")
    min_normal_constraint: float = setting(
        0.02, range=(0.0, 1.0), doc="point-to-plane: how well the surfaces must constrain translation (0 to 1/3)"
    )

    def __post_init__(self) -> None:
        check_choice("variant", self.variant, _VARIANTS)
        check(self)
        try:
            levels = tuple((float(a), float(b)) for a, b in self.levels)
        except (TypeError, ValueError):
            raise ValueError(f"levels must be (voxel multiple, reach multiple) pairs, got {self.levels!r}") from None
        if not levels or not all(a > 0 and b > 0 for a, b in levels):
            raise ValueError(f"levels must be one or more pairs of positive numbers, got {self.levels!r}")
        object.__setattr__(self, "levels", levels)

    def reach(self, level: int) -> float:
        """Maximum correspondence distance (metres) at ``level`` (0 = coarsest, -1 = finest)."""
        scale, reach = self.levels[level]
        return reach * scale * self.voxel


@dataclass(frozen=True)
class _Pyramid:
    """One frame's clouds, coarse to fine, each with normals (and colours), and how well its
    surfaces constrain a translation (:func:`~baselines.depth_geometry.normal_constraint`)."""

    clouds: tuple[o3d.geometry.PointCloud, ...]
    constraint: float


class ICPOdometer(Odometer):
    """Open3D ICP of the current depth cloud onto the previous one, coarse to fine.

    Configured by :class:`ICPConfig` (``config``, or keyword overrides of its fields, e.g.
    ``ICPOdometer(voxel=0.05, max_depth=3.0)``).

    Covariance: ``sigma^2 * inv(I)`` with ``I`` Open3D's
    ``get_information_matrix_from_point_clouds`` at the result (previous camera frame, ordering
    (rx, ry, rz, tx, ty, tz)) and ``sigma^2 = inlier_rmse^2 / 3``. Dense correspondences are not
    independent, so it is optimistic in absolute terms; use it to compare steps.
    """

    Config = ICPConfig  # its options: every field of ICPConfig (odolab.odometry.configured)

    def __init__(self, config: ICPConfig | None = None, **overrides) -> None:
        self.config = configure(ICPConfig, config, **overrides)
        self.identity_digest = config_digest(self.config)  # results kept per odometer follow its settings
        self._clouds: FrameMemo[_Pyramid | None] = FrameMemo()

    def reset(self, intrinsics: Intrinsics) -> None:
        super().reset(intrinsics)
        self._clouds.clear()

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate:
        """``T_prev_cur`` by ICP from each initial guess until one checks out; else invalid."""
        cfg = self.config
        target = self._clouds.get(prev, lambda: self._pyramid(prev))
        source = self._clouds.get(cur, lambda: self._pyramid(cur))
        if target is None or source is None:
            return Estimate.invalid()
        if min(target.constraint, source.constraint) < cfg.min_normal_constraint and cfg.variant != "colored":
            return Estimate.invalid()  # a plane, or a floor and one wall: point-to-plane ICP would slide
        refined: list[np.ndarray] = []
        found = first_verified(
            initial_guesses(action, prev, cur, self.intrinsics, cfg.depth)[: cfg.max_starts],
            lambda T: self._coarse_to_fine(source, target, T),
            prev,
            cur,
            action,
            self.intrinsics,
            cfg.depth,
            cfg.verify,
            refined,
        )
        if found is None:  # refused: the first start's registration is the unverified estimate
            return Estimate.invalid(unverified=refined[0] if refined else None)
        T, rmse = found.T_prev_cur, found.detail
        return Estimate(T, covariance=self._covariance(source, target, T, rmse))

    def _coarse_to_fine(self, source: _Pyramid, target: _Pyramid, T: np.ndarray) -> tuple[np.ndarray | None, float]:
        """ICP at every level from ``T``: (``T_prev_cur`` or None on failure, final inlier RMSE m)."""
        rmse = 0.0
        try:
            for level, (src, tgt) in enumerate(zip(source.clouds, target.clouds)):
                result = self._register(src, tgt, self.config.reach(level), T)
                T, rmse = np.array(result.transformation), float(result.inlier_rmse)
        except RuntimeError:  # Open3D raises when no correspondence is left (colored ICP)
            return None, rmse
        return (T if np.all(np.isfinite(T)) else None), rmse

    def _covariance(self, source: _Pyramid, target: _Pyramid, T: np.ndarray, rmse: float) -> np.ndarray | None:
        """``sigma^2 inv(I)`` at the finest level (see the class docstring)."""
        dist = self.config.reach(-1)
        with one_thread():
            info = _reg.get_information_matrix_from_point_clouds(source.clouds[-1], target.clouds[-1], dist, T)
        return covariance_from_information(info, rmse**2 / 3.0)

    def _register(
        self, src: o3d.geometry.PointCloud, tgt: o3d.geometry.PointCloud, dist: float, T: np.ndarray
    ) -> _reg.RegistrationResult:
        """One ICP run of ``src`` onto ``tgt`` (correspondences within ``dist`` m) from ``T``."""
        cfg = self.config
        criteria = _reg.ICPConvergenceCriteria(
            relative_fitness=cfg.tolerance, relative_rmse=cfg.tolerance, max_iteration=cfg.max_iterations
        )
        kernel = () if cfg.tukey_k is None else (_reg.TukeyLoss(k=cfg.tukey_k),)
        with one_thread():  # the same answer every run (baselines.open3d_threads)
            if cfg.variant == "colored":
                estimation = _reg.TransformationEstimationForColoredICP(cfg.geometric_weight, *kernel)
                return _reg.registration_colored_icp(src, tgt, dist, T, estimation, criteria)
            return _reg.registration_icp(
                src, tgt, dist, T, _reg.TransformationEstimationPointToPlane(*kernel), criteria
            )

    def _pyramid(self, frame: Frame) -> _Pyramid | None:
        """Clouds of ``frame`` at each level; None when it has too few depth readings."""
        cfg = self.config
        points, index = backproject(frame.depth, self.intrinsics, cfg.depth, cfg.pixel_stride)
        if len(points) < cfg.min_cloud_points:  # the finest cloud cannot have more
            return None
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
        cloud.colors = o3d.utility.Vector3dVector(frame.rgb.reshape(-1, 3)[index] / 255.0)
        clouds = []
        for scale, _ in reversed(cfg.levels):  # fine to coarse, each level from the one before
            voxel = scale * cfg.voxel
            cloud = cloud.voxel_down_sample(voxel)
            search = o3d.geometry.KDTreeSearchParamHybrid(
                radius=cfg.normal_radius * voxel, max_nn=cfg.normal_neighbours
            )
            cloud.estimate_normals(search)
            clouds.append(cloud)
        if len(clouds[-1].points) < cfg.min_coarse_points or len(clouds[0].points) < cfg.min_cloud_points:
            return None
        constraint = normal_constraint(frame.depth, self.intrinsics, cfg.depth)
        return _Pyramid(tuple(reversed(clouds)), constraint)
