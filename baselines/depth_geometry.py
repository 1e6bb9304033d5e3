"""Geometry shared by the classical odometers: depth masking, back-projection, rigid fits.

Conventions are odolab's (:mod:`odolab.api`): camera axes x right, y down, z forward, metres;
``T_a_b`` maps points in frame *b* into frame *a*. Covariances are 6x6 over
(rx, ry, rz, tx, ty, tz): a small motion ``exp(delta)`` applied on the left, in the frame the
fitted points are expressed in (for ``T_prev_cur`` that is the previous camera).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

import numpy as np

from odolab.api import Action, Intrinsics, planar_to_transform

__all__ = [
    "DepthAgreement",
    "DepthRange",
    "FrameMemo",
    "backproject",
    "backproject_pixels",
    "covariance_from_information",
    "depth_agreement",
    "depth_mask",
    "image_texture",
    "nominal_motion",
    "normal_constraint",
    "point_to_point_covariance",
    "sample_depth",
    "too_little_depth",
]


@dataclass(frozen=True)
class DepthRange:
    """Depth readings (metres) trusted by an odometer: ``min_depth < d <= max_depth``."""

    min_depth: float = 0.1
    max_depth: float = 4.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.min_depth < self.max_depth:
            raise ValueError(f"need 0 <= min_depth < max_depth, got {self.min_depth}, {self.max_depth}")


_V = TypeVar("_V")


class FrameMemo(Generic[_V]):
    """Remembers per-frame work (features, clouds) for the last two frames seen, by identity.

    In a sequence, ``step(prev, cur)`` is followed by ``step(cur, next)``: the work done on ``cur``
    is reused once. Identity (``is``), not equality, decides: no hashing of images. Pickles empty
    (its values may be Open3D objects).
    """

    def __init__(self) -> None:
        self._items: list[tuple[object, _V]] = []

    def get(self, frame: object, compute: Callable[[], _V]) -> _V:
        """The value remembered for ``frame``, or ``compute()`` (then remembered)."""
        for key, value in self._items:
            if key is frame:
                return value
        value = compute()
        self._items = [*self._items[-1:], (frame, value)]
        return value

    def clear(self) -> None:
        """Forget everything (call on :meth:`Odometer.reset`)."""
        self._items = []

    def __getstate__(self) -> dict:
        return {"_items": []}  # an odometer sent to another process starts with no memory


def depth_mask(depth: np.ndarray, rng: DepthRange) -> np.ndarray:
    """Boolean (H, W): pixels whose depth (metres) is finite and inside ``rng``."""
    d = np.asarray(depth)
    with np.errstate(invalid="ignore"):
        return np.isfinite(d) & (d > rng.min_depth) & (d <= rng.max_depth)


def too_little_depth(depth: np.ndarray, rng: DepthRange, min_valid: int = 500) -> bool:
    """True for frames with fewer than ``min_valid`` usable depth pixels."""
    return int(depth_mask(depth, rng).sum()) < min_valid


def image_texture(rgb: np.ndarray) -> float:
    """Mean absolute grey-level difference between neighbouring pixels (0 for a constant image)."""
    grey = np.asarray(rgb, dtype=np.float32).mean(axis=2)
    return float((np.abs(np.diff(grey, axis=0)).mean() + np.abs(np.diff(grey, axis=1)).mean()) / 2.0)


def normal_constraint(depth: np.ndarray, intr: Intrinsics, rng: DepthRange, stride: int = 4) -> float:
    """How well the surfaces in a depth image pin down a translation: 0 (none) to 1/3 (all ways).

    The smallest eigenvalue of the mean ``n n^T`` over surface normals ``n`` (from neighbouring
    pixels ``stride`` apart, depth edges skipped). A single plane scores 0; a floor and one wall
    score ~0 too (nothing faces the direction along the wall): point-to-plane ICP slides there.
    """
    z = np.where(depth_mask(depth, rng), depth, np.nan).astype(np.float64)
    h, w = z.shape
    v, u = np.mgrid[0:h:stride, 0:w:stride]
    P = backproject_pixels(u, v, z[v, u], intr)  # (h', w', 3), NaN where no depth
    du = P[:-1, 1:] - P[:-1, :-1]
    dv = P[1:, :-1] - P[:-1, :-1]
    n = np.cross(du, dv).reshape(-1, 3)
    zc = P[:-1, :-1, 2].reshape(-1)
    step = np.maximum(np.linalg.norm(du, axis=-1), np.linalg.norm(dv, axis=-1)).reshape(-1)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(n).all(axis=1) & (step < 0.05 * stride * zc)  # no jump across an edge
    n = n[ok]
    norm = np.linalg.norm(n, axis=1)
    n = n[norm > 0] / norm[norm > 0, None]
    if len(n) < 10:
        return 0.0
    return float(np.linalg.eigvalsh(n.T @ n / len(n))[0])


def backproject_pixels(u: np.ndarray, v: np.ndarray, z: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """Camera-frame points (N, 3), metres, of pixels (u along width, v along height) at depth z."""
    u, v, z = (np.asarray(a, dtype=np.float64) for a in (u, v, z))
    return np.stack([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z], axis=-1)


def backproject(depth: np.ndarray, intr: Intrinsics, rng: DepthRange) -> tuple[np.ndarray, np.ndarray]:
    """All usable depth pixels as camera-frame points (N, 3) and their flat pixel indices (N,)."""
    mask = depth_mask(depth, rng)
    v, u = np.nonzero(mask)
    return backproject_pixels(u, v, depth[v, u], intr), np.flatnonzero(mask)


def sample_depth(depth: np.ndarray, uv: np.ndarray, rng: DepthRange, max_spread: float = 0.03) -> np.ndarray:
    """Depth (metres, 0 = unusable) at sub-pixel points ``uv`` (N, 2).

    Reads the nearest pixel and rejects it when its 3x3 neighbourhood has a missing reading or
    spans more than ``max_spread`` times the depth (a depth edge: features love them, and there
    the depth belongs to either side).
    """
    h, w = depth.shape
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    u = np.clip(np.rint(uv[:, 0]).astype(int), 1, w - 2)
    v = np.clip(np.rint(uv[:, 1]).astype(int), 1, h - 2)
    d = np.where(depth_mask(depth, rng), depth, np.nan).astype(np.float64)
    patch = np.stack([d[v + dv, u + du] for dv in (-1, 0, 1) for du in (-1, 0, 1)], axis=1)
    centre = patch[:, 4]
    with np.errstate(invalid="ignore"):
        spread = np.max(patch, axis=1) - np.min(patch, axis=1)
        ok = np.isfinite(spread) & (spread <= max_spread * centre)
    return np.where(ok, centre, 0.0)


@dataclass(frozen=True)
class DepthAgreement:
    """How well a motion explains the previous depth image (see :func:`depth_agreement`).

    ``in_view``: current points that land on a usable previous depth pixel; ``fraction``: the
    share of those whose depth agrees (0 when none lands); ``rms``: root mean square depth
    difference of the agreeing points, metres (0 when none agrees).
    """

    in_view: int
    fraction: float
    rms: float


def depth_agreement(
    prev_depth: np.ndarray,
    cur_depth: np.ndarray,
    T_prev_cur: np.ndarray,
    intr: Intrinsics,
    rng: DepthRange,
    stride: int = 4,
) -> DepthAgreement:
    """Check a motion against the depth images themselves, independently of any solver's flag.

    Back-projects every ``stride``-th current pixel, moves it by ``T_prev_cur`` into the previous
    camera, projects it and compares with the previous depth there. Agreement tolerance
    ``0.01 m + 0.01 * z^2`` (z in metres): a Kinect's and the Redwood model's disparity noise
    grows with z^2 (about 4 cm at 4 m). A wrong motion leaves most points disagreeing.
    """
    sub = np.zeros_like(cur_depth, dtype=bool)
    sub[::stride, ::stride] = True
    mask = depth_mask(cur_depth, rng) & sub
    v, u = np.nonzero(mask)
    X = backproject_pixels(u, v, cur_depth[v, u], intr)
    Y = X @ np.asarray(T_prev_cur)[:3, :3].T + np.asarray(T_prev_cur)[:3, 3]
    front = Y[:, 2] > 1e-6
    Y = Y[front]
    pu = np.rint(intr.fx * Y[:, 0] / Y[:, 2] + intr.cx).astype(np.int64)
    pv = np.rint(intr.fy * Y[:, 1] / Y[:, 2] + intr.cy).astype(np.int64)
    h, w = prev_depth.shape
    inside = (pu >= 0) & (pu < w) & (pv >= 0) & (pv < h)
    z_prev = np.zeros(len(Y))
    z_prev[inside] = prev_depth[pv[inside], pu[inside]]
    seen = inside & depth_mask(z_prev, rng)
    n = int(seen.sum())
    if n == 0:
        return DepthAgreement(0, 0.0, 0.0)
    dz = z_prev[seen] - Y[seen, 2]
    agree = np.abs(dz) < 0.01 + 0.01 * Y[seen, 2] ** 2
    rms = float(np.sqrt(np.mean(dz[agree] ** 2))) if agree.any() else 0.0
    return DepthAgreement(n, float(agree.mean()), rms)


def point_to_point_covariance(points: np.ndarray, residuals: np.ndarray) -> np.ndarray | None:
    """Gauss-Newton covariance (6x6, (rx, ry, rz, tx, ty, tz)) of a point-to-point fit.

    ``points`` (N, 3): fitted points in the target frame; ``residuals`` (N, 3): target minus
    fitted, metres. The per-coordinate noise variance is estimated from the residuals. Treats
    the pairs as independent, so it is optimistic for dense, correlated correspondences.
    """
    p = np.asarray(points, dtype=np.float64)
    r = np.asarray(residuals, dtype=np.float64)
    n = len(p)
    info = np.zeros((6, 6))
    # d(exp(delta) x)/d(omega, v) = [-[x]_x, I]; sum of J^T J over the 3 rows of every pair.
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    zero, one = np.zeros(n), np.ones(n)
    rows = [
        np.stack([zero, z, -y, one, zero, zero], axis=1),
        np.stack([-z, zero, x, zero, one, zero], axis=1),
        np.stack([y, -x, zero, zero, zero, one], axis=1),
    ]
    for J in rows:
        info += J.T @ J
    sigma2 = float(np.sum(r**2)) / max(3 * n - 6, 1)
    return covariance_from_information(info, sigma2)


def covariance_from_information(info: np.ndarray, sigma2: float) -> np.ndarray | None:
    """``sigma2 * inv(info)`` for a 6x6 information matrix of unit-variance residuals.

    ``sigma2``: residual variance per coordinate (m^2). None when ``info`` is singular (the
    geometry leaves a direction unconstrained, e.g. a single plane).
    """
    info = np.asarray(info, dtype=np.float64)
    if not np.all(np.isfinite(info)) or np.linalg.cond(info) > 1e12:
        return None
    return sigma2 * np.linalg.inv(info)


def nominal_motion(action: Action | None) -> np.ndarray:
    """``T_prev_cur`` (4x4) of an action's noiseless motion; identity for STOP or no action.

    move_forward = 0.25 m forward, turn_left / turn_right = +/-30 degrees (PointNav 2020).
    """
    if action is Action.MOVE_FORWARD:
        return planar_to_transform(0.0, 0.25, 0.0)
    if action is Action.TURN_LEFT:
        return planar_to_transform(0.0, 0.0, np.radians(30.0))
    if action is Action.TURN_RIGHT:
        return planar_to_transform(0.0, 0.0, -np.radians(30.0))
    return np.eye(4)
