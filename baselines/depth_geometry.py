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

import cv2
import numpy as np

from odolab.api import Action, Frame, Intrinsics, planar_to_transform, transform_to_planar

__all__ = [
    "Alignment",
    "DepthAgreement",
    "MotionBounds",
    "Verifier",
    "alignment_check",
    "initial_guesses",
    "planar_search",
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


def _grid(shape: tuple[int, ...], stride: int) -> np.ndarray:
    """Boolean mask of every ``stride``-th row and column."""
    sub = np.zeros(shape[:2], dtype=bool)
    sub[::stride, ::stride] = True
    return sub


def backproject(
    depth: np.ndarray, intr: Intrinsics, rng: DepthRange, stride: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """Usable depth pixels (every ``stride``-th row and column) as camera-frame points (N, 3), and
    their flat pixel indices (N,)."""
    mask = depth_mask(depth, rng)
    if stride > 1:
        mask &= _grid(mask.shape, stride)
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


def _reproject(
    prev_depth: np.ndarray, cur_depth: np.ndarray, T_prev_cur: np.ndarray, intr: Intrinsics, rng: DepthRange,
    stride: int,
) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray], np.ndarray, np.ndarray]:
    """Every ``stride``-th usable current pixel moved by ``T_prev_cur`` onto the previous image.

    Returns the current pixels ``(v, u)``, the previous pixels ``(pv, pu)`` they land on, the
    moved points' depth in the previous camera (metres) and the previous depth read there, for
    the points that land on a usable previous depth pixel only.
    """
    v, u = np.nonzero(depth_mask(cur_depth, rng) & _grid(cur_depth.shape, stride))
    X = backproject_pixels(u, v, cur_depth[v, u], intr)
    T = np.asarray(T_prev_cur, dtype=np.float64)
    # Elementwise products: a BLAS call right after Open3D's OpenMP work can stall (thread contention).
    Y = [X[:, 0] * T[k, 0] + X[:, 1] * T[k, 1] + X[:, 2] * T[k, 2] + T[k, 3] for k in range(3)]
    z = Y[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        pu = np.rint(intr.fx * Y[0] / z + intr.cx)
        pv = np.rint(intr.fy * Y[1] / z + intr.cy)
    h, w = prev_depth.shape
    inside = (z > 1e-6) & (pu >= 0) & (pu < w) & (pv >= 0) & (pv < h)
    pu, pv = pu[inside].astype(np.int64), pv[inside].astype(np.int64)
    z_prev = np.asarray(prev_depth)[pv, pu].astype(np.float64)
    seen = depth_mask(z_prev, rng)
    return (v[inside][seen], u[inside][seen]), (pv[seen], pu[seen]), z[inside][seen], z_prev[seen]


def _agrees(z_moved: np.ndarray, z_prev: np.ndarray) -> np.ndarray:
    """Depths (metres) equal within ``0.01 m + 0.01 * z^2`` (Kinect / Redwood noise grows as z^2)."""
    return np.abs(z_prev - z_moved) < 0.01 + 0.01 * z_moved**2


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
    _, _, z, z_prev = _reproject(prev_depth, cur_depth, T_prev_cur, intr, rng, stride)
    if len(z) == 0:
        return DepthAgreement(0, 0.0, 0.0)
    agree = _agrees(z, z_prev)
    rms = float(np.sqrt(np.mean((z_prev - z)[agree] ** 2))) if agree.any() else 0.0
    return DepthAgreement(len(z), float(agree.mean()), rms)


@dataclass(frozen=True)
class Alignment:
    """How well a motion explains the previous frame, in depth and in colour.

    ``depth``: the :class:`DepthAgreement`; ``ncc``: normalised cross-correlation (-1..1) of the
    blurred grey levels of the depth-agreeing points in the two images (0 when fewer than
    ``min_points`` agree). Depth alone cannot see a slide along a wall (every point still lands
    on the wall); the texture can.
    """

    depth: DepthAgreement
    ncc: float


def _blurred_grey(rgb: np.ndarray, sigma: float) -> np.ndarray:
    grey = cv2.cvtColor(np.ascontiguousarray(rgb, dtype=np.uint8), cv2.COLOR_RGB2GRAY).astype(np.float32)
    return cv2.GaussianBlur(grey, (0, 0), sigma) if sigma > 0 else grey


def alignment_check(
    prev: Frame,
    cur: Frame,
    T_prev_cur: np.ndarray,
    intr: Intrinsics,
    rng: DepthRange,
    stride: int = 2,
    blur_sigma: float = 1.5,
    min_points: int = 100,
) -> Alignment:
    """Depth agreement (as :func:`depth_agreement`) and colour agreement of ``T_prev_cur``.

    Every ``stride``-th current pixel is moved into the previous image; of those whose depth
    agrees, the grey levels (Gaussian blur of ``blur_sigma`` pixels first: the simulator's RGB
    noise has sigma = 25 grey levels) are compared by normalised cross-correlation. On the
    simulator's validation episodes a correct motion scores NCC > 0.9 in 95% of steps; a slide
    of 5 cm or more along a textured wall scores well below.
    """
    (v, u), (pv, pu), z, z_prev = _reproject(prev.depth, cur.depth, T_prev_cur, intr, rng, stride)
    if len(z) == 0:
        return Alignment(DepthAgreement(0, 0.0, 0.0), 0.0)
    agree = _agrees(z, z_prev)
    rms = float(np.sqrt(np.mean((z_prev - z)[agree] ** 2))) if agree.any() else 0.0
    depth = DepthAgreement(len(z), float(agree.mean()), rms)
    if agree.sum() < min_points:
        return Alignment(depth, 0.0)
    a = _blurred_grey(cur.rgb, blur_sigma)[v[agree], u[agree]].astype(np.float64)
    b = _blurred_grey(prev.rgb, blur_sigma)[pv[agree], pu[agree]].astype(np.float64)
    a -= a.mean()
    b -= b.mean()
    denom = np.sqrt(np.sum(a * a) * np.sum(b * b))
    return Alignment(depth, float(np.sum(a * b) / denom) if denom > 0 else 0.0)


@dataclass(frozen=True)
class MotionBounds:
    """The motions a ground robot can make for one PointNav action; anything else is a failure.

    Applies only when the action is known (a robot on a floor); real hand-held data (action None)
    is not bounded. The camera stays level and at its height: ``|ty| <= max_height`` (m) and roll
    and pitch ``<= max_tilt_deg``. The planar motion must stay within reach of the action's
    nominal one: yaw within ``max_yaw_error`` (rad); ``move_forward``: ``|dx| <= max_lateral``
    and ``dz`` in ``forward_range`` (m; a blocked step moves ~0); turns: ``|dx|, |dz| <=
    max_turn_translation`` (m). The defaults are the PointNav 2020 actuation noise (LoCoBot,
    Proportional controller, multiplier 0.5; facts.md section 2) truncated at 3 sigma (yaw
    0.24 rad forward, 0.22 rad turning; lateral 0.25 m forward, 0.10 m turning), plus margin.
    """

    max_height: float = 0.03
    max_tilt_deg: float = 2.0
    max_yaw_error: float = 0.3
    max_lateral: float = 0.3
    forward_range: tuple[float, float] = (-0.05, 0.42)
    max_turn_translation: float = 0.15

    def contains(self, T_prev_cur: np.ndarray, action: Action | None) -> bool:
        """True when ``T_prev_cur`` (4x4) is a motion ``action`` can produce (always for None)."""
        if action is None:
            return True
        T = np.asarray(T_prev_cur, dtype=np.float64)
        tilt = np.degrees(np.arcsin(np.clip(np.abs(T[1, [0, 2]]), 0.0, 1.0)).max())
        if abs(T[1, 3]) > self.max_height or tilt > self.max_tilt_deg:
            return False
        dx, dz, dyaw = transform_to_planar(T)
        if abs(dyaw - transform_to_planar(nominal_motion(action))[2]) > self.max_yaw_error:
            return False
        if action is Action.MOVE_FORWARD:
            return abs(dx) <= self.max_lateral and self.forward_range[0] <= dz <= self.forward_range[1]
        return max(abs(dx), abs(dz)) <= self.max_turn_translation


_UNBOUNDED = MotionBounds(np.inf, np.inf, np.inf, np.inf, (-np.inf, np.inf), np.inf)


@dataclass(frozen=True)
class Verifier:
    """Accepts a motion only if the images themselves confirm it; shared by the dense odometers.

    A motion ``T_prev_cur`` passes when it is in ``bounds`` for the action (see
    :class:`MotionBounds`; None = unbounded), at least ``min_points`` current depth points land on
    the previous depth image, a share ``min_agreement`` of them agree in depth and their grey
    levels correlate with NCC >= ``min_ncc`` (see :func:`alignment_check`). On the simulator's
    validation episodes, 0.8 / 0.85 cut the mean error of the accepted Open3D RGB-D steps from
    3.4 to 0.8 cm (dx) while rejecting 4 of 175 good ones.
    """

    depth_range: DepthRange = DepthRange()
    bounds: MotionBounds | None = MotionBounds()
    min_points: int = 200
    min_agreement: float = 0.8
    min_ncc: float = 0.85

    def check(
        self, prev: Frame, cur: Frame, T_prev_cur: np.ndarray | None, action: Action | None, intr: Intrinsics
    ) -> Alignment | None:
        """The :class:`Alignment` of an accepted motion; None when rejected (or ``T_prev_cur`` is None)."""
        if T_prev_cur is None or not np.all(np.isfinite(T_prev_cur)):
            return None
        if not (self.bounds or _UNBOUNDED).contains(T_prev_cur, action):
            return None
        check = alignment_check(prev, cur, T_prev_cur, intr, self.depth_range)
        ok = (
            check.depth.in_view >= self.min_points
            and check.depth.fraction >= self.min_agreement
            and check.ncc >= self.min_ncc
        )
        return check if ok else None


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


def initial_guesses(
    action: Action | None, prev: Frame | None = None, cur: Frame | None = None, intr: Intrinsics | None = None,
    rng: DepthRange = DepthRange(),
) -> list[np.ndarray]:
    """Starting motions ``T_prev_cur`` (4x4) to try for an action, most likely first.

    With the frames (and a known action): the best two motions of :func:`planar_search` first.
    Then the nominal motion (:func:`nominal_motion`); for ``move_forward`` also the blocked step
    (no translation): about one step in ten collides, and a solver started 0.25 m off rarely
    finds the way back.
    """
    guesses = []
    if action is not None and prev is not None and cur is not None and intr is not None:
        guesses += planar_search(prev, cur, action, intr, rng)
    guesses.append(nominal_motion(action))
    if action is Action.MOVE_FORWARD:
        guesses.append(np.eye(4))
    return guesses


def _search_grid(action: Action | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Coarse candidate offsets (lateral m, forward m, yaw rad) around an action's nominal motion."""
    yaw = np.radians(np.arange(-16.0, 16.1, 2.0))
    if action is Action.MOVE_FORWARD:
        return np.array([-0.2, -0.1, 0.0, 0.1, 0.2]), np.array([-0.25, -0.125, 0.0, 0.125]), yaw
    return np.array([-0.08, 0.0, 0.08]), np.array([-0.08, 0.0, 0.08]), yaw


def _planar_candidates(center: np.ndarray, dx: np.ndarray, dz: np.ndarray, dyaw: np.ndarray) -> np.ndarray:
    """(K, 3) planar motions: ``center`` + every combination of the offsets."""
    g = np.stack(np.meshgrid(dx, dz, dyaw, indexing="ij"), axis=-1).reshape(-1, 3)
    return g + center


def _planar_costs(
    X: np.ndarray, g_cur: np.ndarray, z_prev: np.ndarray, g_prev: np.ndarray, cand: np.ndarray, intr: Intrinsics
) -> np.ndarray:
    """Mean robust cost (K,) of planar motions ``cand`` (K, 3) moving points ``X`` (N, 3) with grey
    levels ``g_cur`` onto the previous depth ``z_prev`` (0 = unusable) and grey ``g_prev`` (float32).

    Per point: 1 when it leaves the image or meets no depth; else the mean of its depth difference
    over ``0.02 m + 0.02 z^2`` and its grey difference over 30 levels, each capped at 1.
    """
    c = np.cos(cand[:, 2:3]).astype(np.float32)
    s = np.sin(cand[:, 2:3]).astype(np.float32)
    x, y, z = (X[:, k].astype(np.float32) for k in range(3))
    zp = s * x + c * z + cand[:, 1:2].astype(np.float32)
    h, w = z_prev.shape
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.float32(1.0) / np.maximum(zp, np.float32(0.05))
        pu = (intr.fx * (c * x - s * z + cand[:, 0:1].astype(np.float32)) * inv + intr.cx + 0.5).astype(np.int32)
        pv = (intr.fy * y * inv + intr.cy + 0.5).astype(np.int32)
    inside = (zp > 0.05) & (pu >= 0) & (pu < w) & (pv >= 0) & (pv < h)
    idx = np.where(inside, pv * w + pu, 0)
    zq = z_prev.reshape(-1)[idx]
    gq = g_prev.reshape(-1)[idx]
    dz_cost = np.minimum(np.abs(zq - zp) / (0.02 + 0.02 * zp * zp), 1.0)
    dg_cost = np.minimum(np.abs(gq - g_cur) * np.float32(1.0 / 30.0), 1.0)
    cost = np.where(inside & (zq > 0), 0.5 * (dz_cost + dg_cost), 1.0)
    return cost.mean(axis=1)


def planar_search(
    prev: Frame, cur: Frame, action: Action, intr: Intrinsics, rng: DepthRange, stride: int = 8, top: int = 2
) -> list[np.ndarray]:
    """Planar motions ``T_prev_cur`` (4x4) that best explain the images, best first (``top`` of them).

    A brute-force search over (lateral, forward, yaw) around the action's nominal motion (yaw
    +-16 degrees in 2 degree steps; forward steps from blocked to 0.375 m, lateral +-0.2 m), then a
    finer one around the best: every ``stride``-th current pixel with depth is moved into the
    previous image and scored on depth and (blurred) grey-level agreement. Cheap (a few ms) and
    its result lands in the convergence basin of the dense solvers, which the nominal motion
    often does not: the actuation noise turns a step by up to 14 degrees. The runner-up is
    taken from candidates at least 3 degrees or 8 cm away from the best.
    """
    v, u = np.nonzero(depth_mask(cur.depth, rng) & _grid(cur.depth.shape, stride))
    X = backproject_pixels(u, v, cur.depth[v, u], intr)
    g_cur = _blurred_grey(cur.rgb, 3.0)[v, u]
    z_prev = np.where(depth_mask(prev.depth, rng), prev.depth, 0.0).astype(np.float32)
    g_prev = _blurred_grey(prev.rgb, 3.0)
    nominal = transform_to_planar(nominal_motion(action))
    cand = _planar_candidates(nominal, *_search_grid(action))
    costs = _planar_costs(X[::2], g_cur[::2], z_prev, g_prev, cand, intr)  # coarse grid: half the points
    order = np.argsort(costs)
    seeds = [cand[order[0]]]
    for k in order[1:]:
        d = np.abs(cand[k] - seeds[0])
        if d[2] > np.radians(3.0) or max(d[0], d[1]) > 0.08:
            seeds.append(cand[k])
            break
    out = []
    for seed in seeds[:top]:
        fine = _planar_candidates(seed, np.array([-0.04, 0.0, 0.04]), np.array([-0.05, 0.0, 0.05]),
                                  np.radians([-1.0, 0.0, 1.0]))
        fc = _planar_costs(X, g_cur, z_prev, g_prev, fine, intr)
        out.append(planar_to_transform(*fine[np.argmin(fc)]))
    return out
