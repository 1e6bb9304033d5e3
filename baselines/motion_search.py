"""Where to start a solver: the action's nominal motion and a brute-force planar search around it.

Conventions: :mod:`odolab.api` (planar ``(dx, dz, dyaw)``, ``T_prev_cur``).
"""

from __future__ import annotations

import numpy as np

from baselines.depth_geometry import DepthRange, backproject_pixels, blurred_grey, depth_mask, pixel_grid
from odolab.api import Action, Frame, Intrinsics, nominal_motion, planar_to_transform, transform_to_planar


def initial_guesses(
    action: Action | None,
    prev: Frame | None = None,
    cur: Frame | None = None,
    intr: Intrinsics | None = None,
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


#: A depth difference costs fully at this multiple of the noise model's tolerance (the verifier
#: uses 1): the grid's candidates are only near the true motion, and a wider band ranks them smoothly.
DEPTH_COST_SCALE = 2.0
#: A grey-level difference (0-255 scale, after the blur) costs fully at this many levels.
GREY_COST_SCALE = 30.0
#: Gaussian blur of both images before their grey levels are compared, pixels.
SEARCH_BLUR_SIGMA = 3.0
#: Points closer than this (metres) in front of the previous camera count as leaving the image.
MIN_POINT_DEPTH = 0.05
#: The runner-up motion differs from the best by more than this yaw (rad) or shift (m).
RUNNER_UP_YAW = np.radians(3.0)
RUNNER_UP_SHIFT = 0.08
#: The fine search around each seed: offsets (lateral m, forward m, yaw rad).
FINE_OFFSETS = (np.array([-0.04, 0.0, 0.04]), np.array([-0.05, 0.0, 0.05]), np.radians([-1.0, 0.0, 1.0]))


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
    X: np.ndarray,
    g_cur: np.ndarray,
    z_prev: np.ndarray,
    g_prev: np.ndarray,
    cand: np.ndarray,
    intr: Intrinsics,
    rng: DepthRange,
) -> np.ndarray:
    """Mean robust cost (K,) of planar motions ``cand`` (K, 3) moving points ``X`` (N, 3) with grey
    levels ``g_cur`` onto the previous depth ``z_prev`` (0 = unusable) and grey ``g_prev`` (float32).

    Per point: 1 when it leaves the image or meets no depth; else the mean of its depth difference
    over ``DEPTH_COST_SCALE`` times the noise model's tolerance (``rng.tolerance``) and its grey
    difference over ``GREY_COST_SCALE`` levels, each capped at 1.
    """
    c = np.cos(cand[:, 2:3]).astype(np.float32)
    s = np.sin(cand[:, 2:3]).astype(np.float32)
    x, y, z = (X[:, k].astype(np.float32) for k in range(3))
    zp = s * x + c * z + cand[:, 1:2].astype(np.float32)
    h, w = z_prev.shape
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.float32(1.0) / np.maximum(zp, np.float32(MIN_POINT_DEPTH))
        pu = (intr.fx * (c * x - s * z + cand[:, 0:1].astype(np.float32)) * inv + intr.cx + 0.5).astype(np.int32)
        pv = (intr.fy * y * inv + intr.cy + 0.5).astype(np.int32)
    inside = (zp > MIN_POINT_DEPTH) & (pu >= 0) & (pu < w) & (pv >= 0) & (pv < h)
    idx = np.where(inside, pv * w + pu, 0)
    zq = z_prev.reshape(-1)[idx]
    gq = g_prev.reshape(-1)[idx]
    dz_cost = np.minimum(np.abs(zq - zp) / (DEPTH_COST_SCALE * rng.tolerance(zp)), 1.0)
    dg_cost = np.minimum(np.abs(gq - g_cur) * np.float32(1.0 / GREY_COST_SCALE), 1.0)
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
    v, u = np.nonzero(depth_mask(cur.depth, rng) & pixel_grid(cur.depth.shape, stride))
    X = backproject_pixels(u, v, cur.depth[v, u], intr)
    g_cur = blurred_grey(cur.rgb, SEARCH_BLUR_SIGMA)[v, u]
    z_prev = np.where(depth_mask(prev.depth, rng), prev.depth, 0.0).astype(np.float32)
    g_prev = blurred_grey(prev.rgb, SEARCH_BLUR_SIGMA)
    nominal = transform_to_planar(nominal_motion(action))
    cand = _planar_candidates(nominal, *_search_grid(action))
    costs = _planar_costs(X[::2], g_cur[::2], z_prev, g_prev, cand, intr, rng)  # coarse grid: half the points
    order = np.argsort(costs)
    seeds = [cand[order[0]]]
    for k in order[1:]:
        d = np.abs(cand[k] - seeds[0])
        if d[2] > RUNNER_UP_YAW or max(d[0], d[1]) > RUNNER_UP_SHIFT:
            seeds.append(cand[k])
            break
    out = []
    for seed in seeds[:top]:
        fine = _planar_candidates(seed, *FINE_OFFSETS)
        fc = _planar_costs(X, g_cur, z_prev, g_prev, fine, intr, rng)
        out.append(planar_to_transform(*fine[np.argmin(fc)]))
    return out
