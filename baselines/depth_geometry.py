"""Depth images as geometry, shared by the classical odometers: masking, back-projection, sampling.

Conventions are odolab's (:mod:`odolab.api`): camera axes x right, y down, z forward, metres;
``T_a_b`` maps points in frame *b* into frame *a*.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

import cv2
import numpy as np

from odolab.api import Intrinsics, check, setting

#: The farthest depth cut a baseline accepts, metres (no sensor reads beyond; infinity is a typo).
MAX_DEPTH_LIMIT = 1000.0
#: Largest noise_floor (m) and noise_growth (1/m): 1 m of tolerance at 1 m accepts any depth.
MAX_NOISE = 1.0


@dataclass(frozen=True)
class DepthRange:
    """The depth readings an odometer trusts, and how far two readings of one surface may differ.

    ``min_depth < d <= max_depth`` (metres; beyond 4 m a Kinect's and the simulated Redwood
    depth's quantisation step exceeds ~5 cm). Noise model, the one all baselines use: two readings
    of one surface at depth ``z`` agree within :meth:`tolerance` ``= noise_floor + noise_growth *
    z^2`` (metres; ``noise_growth`` in 1/m): a Kinect's and the Redwood model's disparity noise
    grows with z^2 (about 4 cm at 4 m).
    """

    min_depth: float = setting(
        0.1, range=(0.0, MAX_DEPTH_LIMIT), open_high=True, doc="readings at or below this are not trusted, m"
    )
    max_depth: float = setting(
        4.0, range=(0.0, MAX_DEPTH_LIMIT), open_low=True, doc="readings beyond this are not trusted, m"
    )
    noise_floor: float = setting(0.01, range=(0.0, MAX_NOISE), doc="readings of one surface agree within this, m ...")
    noise_growth: float = setting(0.01, range=(0.0, MAX_NOISE), doc="... plus this times depth squared, 1/m")

    def __post_init__(self) -> None:
        check(self)
        if not self.min_depth < self.max_depth:
            raise ValueError(
                f"need min_depth < max_depth, got min_depth {self.min_depth:g}, max_depth {self.max_depth:g}"
            )

    def tolerance(self, z: np.ndarray) -> np.ndarray:
        """Largest difference (metres) between two readings of one surface at depth ``z`` (metres)."""
        return self.noise_floor + self.noise_growth * z**2


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


def too_little_depth(depth: np.ndarray, rng: DepthRange, min_valid: int) -> bool:
    """True for frames with fewer than ``min_valid`` usable depth pixels."""
    return int(depth_mask(depth, rng).sum()) < min_valid


def image_texture(rgb: np.ndarray) -> float:
    """Mean absolute grey-level difference between neighbouring pixels (0 for a constant image)."""
    grey = np.asarray(rgb, dtype=np.float32).mean(axis=2)
    return float((np.abs(np.diff(grey, axis=0)).mean() + np.abs(np.diff(grey, axis=1)).mean()) / 2.0)


#: Neighbouring points farther apart than this fraction of their depth per pixel between them
#: straddle a depth edge (no surface normal there).
EDGE_STEP = 0.05
#: Fewer surface normals than this constrain nothing.
MIN_NORMALS = 10


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
        ok = np.isfinite(n).all(axis=1) & (step < EDGE_STEP * stride * zc)  # no jump across an edge
    n = n[ok]
    norm = np.linalg.norm(n, axis=1)
    n = n[norm > 0] / norm[norm > 0, None]
    if len(n) < MIN_NORMALS:
        return 0.0
    return float(np.linalg.eigvalsh(n.T @ n / len(n))[0])


def backproject_pixels(u: np.ndarray, v: np.ndarray, z: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """Camera-frame points (N, 3), metres, of pixels (u along width, v along height) at depth z."""
    u, v, z = (np.asarray(a, dtype=np.float64) for a in (u, v, z))
    return np.stack([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z], axis=-1)


def pixel_grid(shape: tuple[int, ...], stride: int) -> np.ndarray:
    """Boolean mask of every ``stride``-th row and column."""
    sub = np.zeros(shape[:2], dtype=bool)
    sub[::stride, ::stride] = True
    return sub


def backproject(depth: np.ndarray, intr: Intrinsics, rng: DepthRange, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Usable depth pixels (every ``stride``-th row and column) as camera-frame points (N, 3), and
    their flat pixel indices (N,)."""
    mask = depth_mask(depth, rng)
    if stride > 1:
        mask &= pixel_grid(mask.shape, stride)
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


def blurred_grey(rgb: np.ndarray, sigma: float) -> np.ndarray:
    grey = cv2.cvtColor(np.ascontiguousarray(rgb, dtype=np.uint8), cv2.COLOR_RGB2GRAY).astype(np.float32)
    return cv2.GaussianBlur(grey, (0, 0), sigma) if sigma > 0 else grey
