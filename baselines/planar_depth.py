"""Planar depth alignment: a ground robot's motion (dx, dz, dyaw) fitted to the depth images alone.

A 3-degree-of-freedom projective point-to-plane ICP: every ``pixel_stride``-th current depth pixel
is moved by the candidate motion into the previous camera, projected, and compared along the normal
with the previous depth surface there (point and normal from the organised depth image).
Gauss-Newton on (yaw, lateral, forward) with a Tukey kernel (``tukey`` times the depth tolerance)
and a weak prior on the translation round the action's nominal motion (``prior_sigma``), from each
of :func:`~baselines.motion_search.initial_guesses`; the lowest robust cost wins and
:func:`~baselines.verification.verify` checks it (bounds and depth agreement; no grey-level test).
Its covariance is ``inv(H)`` of that system (so it scales with ``tukey`` squared) plus
``translation_floor`` on each planar translation; the out-of-plane components are held at zero
with ``out_of_plane_sigma`` (conventions: :mod:`odolab.api`). It needs the action
(``needs_action``) and refuses views whose median depth is beyond ``max_median_depth``.

Why: facing a wall, where the photometric and coloured solvers fail, the walls' normals fix the
yaw and the distance to each wall, and the prior decides only the slide the depth leaves free
(measurements: docs/odometers.md#planar-depth).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from baselines.config import OdometerConfig
from baselines.depth_geometry import DepthRange, FrameMemo, backproject, backproject_pixels, depth_mask
from baselines.motion_search import initial_guesses
from baselines.verification import VerifyConfig, verify
from odolab.api import (
    Action,
    Estimate,
    Frame,
    Intrinsics,
    Odometer,
    check,
    config_digest,
    configure,
    nominal_motion,
    planar_to_transform,
    setting,
    transform_to_planar,
)

__all__ = ["PlanarDepthConfig", "PlanarDepthOdometer"]


@dataclass(frozen=True)
class PlanarDepthConfig(OdometerConfig):
    """Options of :class:`PlanarDepthOdometer` (besides ``depth`` and ``verify``, see
    :class:`~baselines.config.OdometerConfig`)."""

    depth: DepthRange = DepthRange(max_depth=6.0, noise_growth=0.015)
    #: No grey-level test: only the bounds and the depth agreement (NCC >= -1 always holds).
    verify: VerifyConfig = field(default_factory=lambda: VerifyConfig(min_ncc=-1.0))
    pixel_stride: int = setting(4, range=(1, 64), doc="fit every n-th current pixel row and column")
    normal_step: int = setting(2, range=(1, 16), doc="normals of the previous surface from neighbours n px away")
    iterations: int = setting(20, range=(1, 1000), doc="Gauss-Newton iterations per start at most")
    tukey: float = setting(3.0, range=(0.5, 100.0), doc="Tukey kernel width, multiple of the depth tolerance")
    prior_sigma: float = setting(0.1, range=(1e-3, 10.0), doc="sigma (m) of the prior round the nominal motion")
    out_of_plane_sigma: float = setting(
        1e-3, range=(1e-6, 1.0), doc="sigma (rad, m) of the components held at zero (roll, pitch, height)"
    )
    #: The depth's scale error (uncorrected distortion) moves the walls by centimetres, which the
    #: fit's own statistics cannot see.
    translation_floor: float = setting(0.015, range=(0.0, 1.0), doc="sigma (m) added to each planar translation's")
    min_points: int = setting(200, range=(3, 10**7), doc="fewer fitted points: invalid step")
    #: Far views bend under the depth distortion (docs/odometers.md#planar-depth).
    max_median_depth: float = setting(
        2.0, range=(0.0, 1000.0), doc="a previous view whose median depth (m) is beyond this: invalid step"
    )
    #: The slide along a single wall is then the prior's. 0 = never (the default; why:
    #: docs/odometers.md#planar-depth).
    one_plane_ratio: float = setting(
        0.0,
        range=(0.0, 0.5),
        doc="normals taken as one plane when the (x, z) scatter's smaller eigenvalue is below this share",
    )

    def __post_init__(self) -> None:
        check(self)
        if self.max_median_depth <= self.depth.min_depth:
            raise ValueError(
                f"max_median_depth ({self.max_median_depth:g} m) must exceed min_depth "
                f"({self.depth.min_depth:g} m): no view could be answered"
            )
        if self.depth.noise_floor <= 0:
            raise ValueError(
                f"planar-depth needs noise_floor > 0 m (its Tukey kernel is tukey x the depth tolerance, "
                f"which is 0 at z = 0 without it), got {self.depth.noise_floor!r}"
            )


@dataclass(frozen=True)
class _Surface:
    """A frame's organised depth surface: points (H, W, 3) and unit normals facing the camera
    (H, W, 3), previous camera frame; ``ok`` (H, W) where both exist."""

    points: np.ndarray
    normals: np.ndarray
    ok: np.ndarray


def _surface(depth: np.ndarray, intr: Intrinsics, rng: DepthRange, k: int) -> _Surface:
    """Points and normals (cross product of the horizontal and vertical differences over ``k``
    pixels) of a depth image; a normal exists where all five depths are usable and the
    neighbours lie within 5 % of the centre's depth (no depth edge)."""
    h, w = depth.shape
    v, u = np.mgrid[0:h, 0:w]
    P = backproject_pixels(u, v, depth, intr)
    usable = depth_mask(depth, rng)
    z = np.where(usable, depth, np.nan).astype(np.float64)
    ok = np.zeros((h, w), dtype=bool)
    n = np.zeros((h, w, 3))
    c = (slice(k, h - k), slice(k, w - k))
    du = P[k : h - k, 2 * k :] - P[k : h - k, : w - 2 * k]
    dv = P[2 * k :, k : w - k] - P[: h - 2 * k, k : w - k]
    m = np.cross(du, dv)
    norm = np.linalg.norm(m, axis=-1)
    near = [z[k : h - k, 2 * k :], z[k : h - k, : w - 2 * k], z[2 * k :, k : w - k], z[: h - 2 * k, k : w - k]]
    with np.errstate(invalid="ignore"):
        smooth = np.all([np.abs(zz - z[c]) < 0.05 * z[c] for zz in near], axis=0)
    ok[c] = usable[c] & smooth & (norm > 0)
    m = m / np.where(norm > 0, norm, 1.0)[..., None]
    m *= -np.sign(np.sum(m * P[c], axis=-1, keepdims=True) + 1e-300)  # face the camera
    n[c] = m
    return _Surface(P, n, ok)


def _exp_planar(omega: float, v: tuple[float, float]) -> np.ndarray:
    """4x4 rotation ``omega`` (rad) about the camera's y axis with translation (v_x, 0, v_z)."""
    c, s = np.cos(omega), np.sin(omega)
    E = np.eye(4)
    E[:3, :3] = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
    E[0, 3], E[2, 3] = v
    return E


def _without_slide(
    H: np.ndarray, g: np.ndarray, normals: np.ndarray, weights: np.ndarray, ratio: float
) -> tuple[np.ndarray, np.ndarray]:
    """The data's Gauss-Newton system over (omega_y, v_x, v_z) with the information along a wall
    removed when the weighted normals' (x, z) scatter is that of one plane (smaller eigenvalue
    below ``ratio`` of the sum): the translation along the least-seen normal direction is then
    projected out of ``H`` and ``g``. Otherwise unchanged."""
    if ratio <= 0:  # the switch off (the default): nothing to compute on every iteration
        return H, g
    nt = normals[:, [0, 2]]
    lam, vec = np.linalg.eigh((nt * weights[:, None]).T @ nt)
    if not lam.sum() > 0 or lam[0] >= ratio * lam.sum():
        return H, g
    d = np.array([0.0, vec[0, 0], vec[1, 0]])  # the slide: along the wall, in the floor plane
    P = np.eye(3) - np.outer(d, d)
    return P @ H @ P, P @ g


@dataclass(frozen=True)
class _Fit:
    T_prev_cur: np.ndarray
    cost: float  # mean Tukey cost per point (0 = perfect, 1 = every point an outlier)
    information: np.ndarray  # 3x3 over (omega_y, v_x, v_z)


class PlanarDepthOdometer(Odometer):
    """Planar point-to-plane alignment of the depth images (module docstring), with a covariance."""

    Config = PlanarDepthConfig  # its options: every field of PlanarDepthConfig (odolab.odometry.configured)
    needs_action = True  # the prior and the starts come from the action; hand-held data need not be planar

    def __init__(self, config: PlanarDepthConfig | None = None, **overrides) -> None:
        self.config = configure(PlanarDepthConfig, config, **overrides)
        self.identity_digest = config_digest(self.config)
        self._surfaces: FrameMemo[_Surface] = FrameMemo()

    def reset(self, intrinsics: Intrinsics) -> None:
        super().reset(intrinsics)
        self._surfaces.clear()

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate:
        """``T_prev_cur`` of the best start after Gauss-Newton, if the depth confirms it."""
        cfg, intr = self.config, self.intrinsics
        if action is None:
            return Estimate.invalid()
        surface = self._surfaces.get(prev, lambda: _surface(prev.depth, intr, cfg.depth, cfg.normal_step))
        if surface.ok.sum() < cfg.min_points or np.median(surface.points[..., 2][surface.ok]) > cfg.max_median_depth:
            return Estimate.invalid()
        X, _ = backproject(cur.depth, intr, cfg.depth, cfg.pixel_stride)
        if len(X) < cfg.min_points:
            return Estimate.invalid()
        prior = nominal_motion(action)[[0, 2], 3]
        fits = [self._fit(X, surface, start, prior) for start in initial_guesses(action, prev, cur, intr, cfg.depth)]
        fits = [f for f in fits if f is not None]
        if not fits:
            return Estimate.invalid()
        best = min(fits, key=lambda f: f.cost)
        if verify(prev, cur, best.T_prev_cur, action, intr, cfg.depth, cfg.verify) is None:
            return Estimate.invalid()
        return Estimate(best.T_prev_cur, covariance=self._covariance(best.information))

    def _fit(self, X: np.ndarray, surf: _Surface, start: np.ndarray, prior: np.ndarray) -> _Fit | None:
        """Gauss-Newton from ``start`` (4x4, made planar) with the translation prior centred on
        ``prior`` ((dx, dz) m); None when too few points take part."""
        cfg, intr = self.config, self.intrinsics
        T = planar_to_transform(*transform_to_planar(start))
        h, w = surf.ok.shape
        for _ in range(cfg.iterations):  # at least one: H and cost are always set
            Y = X @ T[:3, :3].T + T[:3, 3]
            with np.errstate(divide="ignore", invalid="ignore"):
                pu = np.rint(intr.fx * Y[:, 0] / Y[:, 2] + intr.cx)
                pv = np.rint(intr.fy * Y[:, 1] / Y[:, 2] + intr.cy)
            inside = (Y[:, 2] > cfg.depth.min_depth) & (pu >= 0) & (pu < w) & (pv >= 0) & (pv < h)
            idx = np.where(inside, pv * w + pu, 0).astype(np.int64)
            hit = inside & surf.ok.reshape(-1)[idx]
            if hit.sum() < cfg.min_points:
                return None
            Yh, P, n = Y[hit], surf.points.reshape(-1, 3)[idx[hit]], surf.normals.reshape(-1, 3)[idx[hit]]
            r = np.sum(n * (Yh - P), axis=1)
            c = cfg.tukey * cfg.depth.tolerance(P[:, 2])
            u2 = np.minimum((r / c) ** 2, 1.0)
            wgt = (1.0 - u2) ** 2 / c**2  # Tukey weight over the residual's scale squared
            # d(exp(delta) Y)/d(omega_y, v_x, v_z) = ((Y_z, 0, -Y_x), e_x, e_z)
            J = np.stack([n[:, 0] * Yh[:, 2] - n[:, 2] * Yh[:, 0], n[:, 0], n[:, 2]], axis=1)
            H = (J * wgt[:, None]).T @ J
            g = (J * wgt[:, None]).T @ r
            H, g = _without_slide(H, g, n, wgt, cfg.one_plane_ratio)
            t = T[[0, 2], 3]
            Jp = np.array([[T[2, 3], 1.0, 0.0], [-T[0, 3], 0.0, 1.0]]) / cfg.prior_sigma
            H = H + Jp.T @ Jp
            g = g + Jp.T @ ((t - prior) / cfg.prior_sigma)
            cost = float(np.sum(1.0 - (1.0 - u2) ** 3) + (len(X) - hit.sum())) / len(X)
            try:
                delta = -np.linalg.solve(H, g)
            except np.linalg.LinAlgError:
                return None
            T = _exp_planar(delta[0], (delta[1], delta[2])) @ T
            if abs(delta[0]) < 1e-6 and np.hypot(delta[1], delta[2]) < 1e-5:
                break
        return _Fit(T, cost, H)

    def _covariance(self, information: np.ndarray) -> np.ndarray | None:
        """6x6 covariance (rx, ry, rz, tx, ty, tz) from the 3x3 information over (ry, tx, tz)."""
        try:
            planar = np.linalg.inv(information)
        except np.linalg.LinAlgError:
            return None
        cov = np.eye(6) * self.config.out_of_plane_sigma**2
        keep = [1, 3, 5]
        cov[np.ix_(keep, keep)] = planar + np.diag([0.0, 1.0, 1.0]) * self.config.translation_floor**2
        return cov
