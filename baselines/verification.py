"""Is an estimated motion right? Checks on the images themselves, not on a solver's own score.

A motion ``T_prev_cur`` is accepted when it respects the action's motion bounds, moves the current
depth onto the previous depth image, and lines up the two images' grey levels
(:class:`Verifier`). Conventions: :mod:`odolab.api`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from baselines.depth_geometry import DepthRange, backproject_pixels, blurred_grey, depth_mask, pixel_grid
from baselines.motion_search import nominal_motion
from odolab.api import Action, Frame, Intrinsics, transform_to_planar


@dataclass(frozen=True)
class DepthAgreement:
    """How well a motion explains the previous depth image (see :func:`alignment_check`).

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
    v, u = np.nonzero(depth_mask(cur_depth, rng) & pixel_grid(cur_depth.shape, stride))
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


def _depth_agreement(z_moved: np.ndarray, z_prev: np.ndarray) -> tuple[DepthAgreement, np.ndarray]:
    """Agreement statistics of moved vs previous depths, and the mask of agreeing points.

    Tolerance ``0.01 m + 0.01 * z^2`` (z in metres): a Kinect's and the Redwood model's disparity
    noise grows with z^2 (about 4 cm at 4 m). A wrong motion leaves most points disagreeing.
    """
    if len(z_moved) == 0:
        return DepthAgreement(0, 0.0, 0.0), np.zeros(0, dtype=bool)
    agree = _agrees(z_moved, z_prev)
    rms = float(np.sqrt(np.mean((z_prev - z_moved)[agree] ** 2))) if agree.any() else 0.0
    return DepthAgreement(len(z_moved), float(agree.mean()), rms), agree


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
    """Depth agreement and colour agreement of ``T_prev_cur``.

    Every ``stride``-th current pixel is moved into the previous image; of those whose depth
    agrees, the grey levels (Gaussian blur of ``blur_sigma`` pixels first: the simulator's RGB
    noise has sigma = 25 grey levels) are compared by normalised cross-correlation. On the
    simulator's validation episodes a correct motion scores NCC > 0.9 in 95% of steps; a slide
    of 5 cm or more along a textured wall scores well below.
    """
    (v, u), (pv, pu), z, z_prev = _reproject(prev.depth, cur.depth, T_prev_cur, intr, rng, stride)
    depth, agree = _depth_agreement(z, z_prev)
    if agree.sum() < min_points:
        return Alignment(depth, 0.0)
    a = blurred_grey(cur.rgb, blur_sigma)[v[agree], u[agree]].astype(np.float64)
    b = blurred_grey(prev.rgb, blur_sigma)[pv[agree], pu[agree]].astype(np.float64)
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
    Proportional controller, multiplier 0.5; docs/reference-facts.md section 2) truncated at 3 sigma (yaw
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
