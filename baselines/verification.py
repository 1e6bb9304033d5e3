"""Is an estimated motion right? Checks on the images themselves, not on a solver's own score.

A motion ``T_prev_cur`` is accepted when it respects the action's motion bounds, moves the current
depth onto the previous depth image, and lines up the two images' grey levels
(:func:`verify`, configured by :class:`VerifyConfig`). Conventions: :mod:`odolab.api`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Generic, TypeVar

import numpy as np

from baselines.depth_geometry import DepthRange, backproject_pixels, blurred_grey, depth_mask, pixel_grid
from baselines.motion_search import nominal_motion
from odolab.api import Action, Frame, Intrinsics, check, setting, transform_to_planar

#: Moved points nearer than this (metres) to the previous camera's plane land nowhere.
_IN_FRONT = 1e-6


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
    prev_depth: np.ndarray,
    cur_depth: np.ndarray,
    T_prev_cur: np.ndarray,
    intr: Intrinsics,
    rng: DepthRange,
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
    inside = (z > _IN_FRONT) & (pu >= 0) & (pu < w) & (pv >= 0) & (pv < h)
    pu, pv = pu[inside].astype(np.int64), pv[inside].astype(np.int64)
    z_prev = np.asarray(prev_depth)[pv, pu].astype(np.float64)
    seen = depth_mask(z_prev, rng)
    return (v[inside][seen], u[inside][seen]), (pv[seen], pu[seen]), z[inside][seen], z_prev[seen]


def _depth_agreement(z_moved: np.ndarray, z_prev: np.ndarray, rng: DepthRange) -> tuple[DepthAgreement, np.ndarray]:
    """Agreement statistics of moved vs previous depths (metres), and the mask of agreeing points.

    Two depths agree within the noise model's :meth:`~baselines.depth_geometry.DepthRange.tolerance`.
    A wrong motion leaves most points disagreeing.
    """
    if len(z_moved) == 0:
        return DepthAgreement(0, 0.0, 0.0), np.zeros(0, dtype=bool)
    agree = np.abs(z_prev - z_moved) < rng.tolerance(z_moved)
    rms = float(np.sqrt(np.mean((z_prev - z_moved)[agree] ** 2))) if agree.any() else 0.0
    return DepthAgreement(len(z_moved), float(agree.mean()), rms), agree


@dataclass(frozen=True)
class Alignment:
    """How well a motion explains the previous frame, in depth and in colour.

    ``depth``: the :class:`DepthAgreement`; ``ncc``: normalised cross-correlation (-1..1) of the
    blurred grey levels of the depth-agreeing points in the two images (0 when fewer than
    ``min_ncc_points`` agree). Depth alone cannot see a slide along a wall (every point still lands
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
    config: VerifyConfig,
) -> Alignment:
    """Depth agreement and colour agreement of ``T_prev_cur``.

    Every ``config.check_stride``-th current pixel is moved into the previous image; of those
    whose depth agrees, the grey levels (Gaussian blur of ``config.ncc_blur_sigma`` pixels first:
    the simulator's RGB noise has sigma = 25 grey levels) are compared by normalised
    cross-correlation. On the simulator's validation episodes a correct motion scores NCC > 0.9
    in 95% of steps; a slide of 5 cm or more along a textured wall scores well below.
    """
    (v, u), (pv, pu), z, z_prev = _reproject(prev.depth, cur.depth, T_prev_cur, intr, rng, config.check_stride)
    depth, agree = _depth_agreement(z, z_prev, rng)
    if agree.sum() < config.min_ncc_points:
        return Alignment(depth, 0.0)
    a = blurred_grey(cur.rgb, config.ncc_blur_sigma)[v[agree], u[agree]].astype(np.float64)
    b = blurred_grey(prev.rgb, config.ncc_blur_sigma)[pv[agree], pu[agree]].astype(np.float64)
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

    max_height: float = setting(0.03, range=(0.0, np.inf), doc="|ty| at most, m: the camera stays at its height")
    max_tilt_deg: float = setting(2.0, range=(0.0, np.inf), doc="roll and pitch at most, degrees")
    max_yaw_error: float = setting(0.3, range=(0.0, np.inf), doc="yaw within this of the action's nominal one, rad")
    max_lateral: float = setting(0.3, range=(0.0, np.inf), doc="move_forward: |dx| at most, m")
    forward_range: tuple[float, float] = setting((-0.05, 0.42), doc="move_forward: dz in [lowest, highest], m")
    max_turn_translation: float = setting(0.15, range=(0.0, np.inf), doc="turns: |dx| and |dz| at most, m")

    def __post_init__(self) -> None:
        check(self)
        r = self.forward_range
        if isinstance(r, (str, bytes)) or not hasattr(r, "__len__") or len(r) != 2:
            raise ValueError(f"forward_range: expected two numbers [lowest, highest] in metres, got {r!r:.80}")
        if any(isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)) for x in r):
            raise ValueError(f"forward_range: expected two numbers [lowest, highest] in metres, got {r!r:.80}")
        if not r[0] < r[1]:
            raise ValueError(f"forward_range: expected lowest < highest, got {list(r)!r:.80}")
        object.__setattr__(self, "forward_range", (float(r[0]), float(r[1])))

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
class VerifyConfig:
    """When the images confirm a motion; one configuration shared by all baselines.

    A motion ``T_prev_cur`` passes when it is in ``bounds`` for the action (see
    :class:`MotionBounds`; None = unbounded), at least ``min_points_in_view`` of the current depth
    points (every ``check_stride``-th row and column) land on a usable previous depth pixel, a share
    ``min_agreement`` of them agree in depth (the noise model of
    :class:`~baselines.depth_geometry.DepthRange`) and their grey levels, blurred by
    ``ncc_blur_sigma`` pixels, correlate with NCC >= ``min_ncc`` (0 when fewer than
    ``min_ncc_points`` agree); see :func:`alignment_check`. On the simulator's validation
    episodes, 0.8 / 0.85 cut the mean error of the accepted Open3D RGB-D steps from 3.4 to 0.8 cm
    (dx) while rejecting 4 of 175 good ones.
    """

    bounds: MotionBounds | None = setting(MotionBounds(), doc="the motions the action can make (None: unbounded)")
    min_points_in_view: int = setting(
        200, range=(0, np.inf), doc="current depth points that must land on a usable previous depth pixel"
    )
    min_agreement: float = setting(0.8, range=(0.0, 1.0), doc="share of them that must agree in depth")
    min_ncc: float = setting(0.85, range=(-1.0, 1.0), doc="NCC of their blurred grey levels at least")
    check_stride: int = setting(2, range=(1, 64), doc="every n-th row and column checked")
    ncc_blur_sigma: float = setting(1.5, range=(0.0, 100.0), doc="Gaussian blur before the NCC, px")
    min_ncc_points: int = setting(100, range=(0, np.inf), doc="fewer agreeing points: NCC 0")

    def __post_init__(self) -> None:
        check(self)


def verify(
    prev: Frame,
    cur: Frame,
    T_prev_cur: np.ndarray | None,
    action: Action | None,
    intr: Intrinsics,
    rng: DepthRange,
    config: VerifyConfig,
) -> Alignment | None:
    """The :class:`Alignment` of an accepted motion; None when rejected (or ``T_prev_cur`` is None)."""
    if T_prev_cur is None or not np.all(np.isfinite(T_prev_cur)):
        return None
    if not (config.bounds or _UNBOUNDED).contains(T_prev_cur, action):
        return None
    check = alignment_check(prev, cur, T_prev_cur, intr, rng, config)
    ok = (
        check.depth.in_view >= config.min_points_in_view
        and check.depth.fraction >= config.min_agreement
        and check.ncc >= config.min_ncc
    )
    return check if ok else None


_X = TypeVar("_X")


@dataclass(frozen=True)
class Verified(Generic[_X]):
    """A refined motion ``T_prev_cur`` (4x4) the images confirmed, what the solver reported with
    it (``detail``, e.g. an RMSE or an information matrix) and the verifier's :class:`Alignment`."""

    T_prev_cur: np.ndarray
    detail: _X
    check: Alignment


def first_verified(
    guesses: Iterable[np.ndarray],
    register: Callable[[np.ndarray], tuple[np.ndarray | None, _X]],
    prev: Frame,
    cur: Frame,
    action: Action | None,
    intr: Intrinsics,
    rng: DepthRange,
    config: VerifyConfig,
    refined: list[np.ndarray] | None = None,
) -> Verified[_X] | None:
    """Guess, refine, verify: the outer loop of the dense odometers.

    Each initial motion ``T_prev_cur`` of ``guesses`` (most likely first) is refined by
    ``register(initial) -> (T_prev_cur or None on failure, detail)`` and checked by :func:`verify`;
    the first one accepted is returned, None when none is. Each refined motion, accepted or not, is
    appended to ``refined`` when given (the first one is the odometer's unverified estimate).
    """
    for guess in guesses:
        T, detail = register(guess)
        if refined is not None and T is not None:
            refined.append(T)
        check = verify(prev, cur, T, action, intr, rng, config)
        if check is not None:
            return Verified(T, detail, check)
    return None
