"""Sensor and actuation noise of the Habitat PointNav Challenge 2020 (docs/reference-facts.md section 2, with its sources).

* RGB: ``out = clip(img / 255 + N(0, 1) * sigma * m, 0, 1) * 255`` per channel (sigma = 0.1).
* Depth: the Redwood model (Choi et al., CVPR 2015) as Habitat applies it, multiplier ``m``:
  pixel jitter N(0, (0.25 m)^2) px, read on the 2x-downsampled grid, d >= 10 m -> 0, then
  disparity quantisation ``denom = round((35.130 / d + N(0, 1) * 0.027778 * m) * 8)``,
  ``out = 35.130 * 8 / denom`` (0 if denom <= 0), with habitat-sim's distortion table
  (:mod:`odolab.sim.redwood`) between the two, and habitat-lab's clip to [0.1, 10] m after.
* Actuation: PyRobot's LoCoBot model, each component an independent normal truncated at
  +-3 sigma, scaled by the multiplier (Proportional controller, multiplier 0.5 in the challenge).

All per-pixel normal draws come from :class:`GaussianTable`, a 16-bit inverse-CDF table (exact up to
1/65536 in probability; tails beyond 4.17 sigma are clipped, a 3e-5 share), which is 10x cheaper
than drawing float normals and keeps a noisy frame within a small factor of bare ray casting.
A multiplier of 0 turns a noise source off exactly.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.special import ndtri

from odolab.core.types import FORWARD_STEP, TURN_ANGLE, Action  # the nominal motions, defined once
from odolab.sim.redwood import BINS, COLS, DistortionTable, cell_lookup, default_table

_DISPARITY = 35.130  # Redwood's baseline x focal length, m px / 8
_CELL_BITS = 13  # table cells (6400) fit in 13 bits of the packed index
_CELL_MASK = (1 << _CELL_BITS) - 1


class GaussianTable:
    """Standard-normal samples by 16-bit inverse-CDF lookup: ``draw(rng, shape)`` -> float32."""

    def __init__(self) -> None:
        self.table = ndtri((np.arange(65536) + 0.5) / 65536.0).astype(np.float32)

    def draw(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        return np.take(self.table, uniform_u16(rng, shape))  # np.take: 3x faster than []


def uniform_u16(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Uniform 16-bit integers: raw 64-bit draws viewed as four uint16 each (2x ``rng.integers``)."""
    n = int(np.prod(shape))
    return rng.bit_generator.random_raw((n + 3) // 4).view(np.uint16)[:n].reshape(shape)


@dataclass
class RGBNoise:
    """Additive Gaussian colour noise; ``sigma`` in [0, 1] intensity units, scaled by ``multiplier``."""

    sigma: float = 0.1
    multiplier: float = 1.0
    gauss: GaussianTable = field(default_factory=GaussianTable, repr=False)

    def __post_init__(self) -> None:
        # Habitat stores (clip(img / 255 + s N, 0, 1) * 255) as uint8, i.e. floor(clip(img + 255 s N)).
        # For integer img that is clip(img + floor(255 s N)): an integer table per 16-bit draw, exact.
        self._steps = np.floor(self.gauss.table * (255.0 * self.sigma * self.multiplier)).astype(np.int16)

    def apply(self, rgb: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Noisy copy of a (H, W, 3) uint8 image."""
        return self.add(rgb, self.draw(rgb.shape, rng))

    def draw(self, shape: tuple[int, ...], rng: np.random.Generator) -> np.ndarray | None:
        """The noise of one image of ``shape``, in integer grey levels (int16; None when off). It does
        not depend on the image, so it may be drawn while the image is being rendered."""
        return None if self.multiplier == 0 else np.take(self._steps, uniform_u16(rng, shape))

    @staticmethod
    def add(rgb: np.ndarray, steps: np.ndarray | None) -> np.ndarray:
        """``rgb`` (uint8) plus the :meth:`draw` ``steps``, clipped to [0, 255]: a new uint8 image."""
        if steps is None:
            return rgb.copy()
        steps += rgb
        return np.clip(steps, 0, 255, out=steps).astype(np.uint8)


@dataclass
class RedwoodDepthNoise:
    """Redwood depth noise exactly as habitat-sim applies it, then habitat-lab's range clip.

    Per output pixel (j, i): jitter the coordinates by N(0, (0.25 m)^2) px (rounded, clipped to the
    image); read depth d on the 2x-downsampled grid; d >= ``max_depth`` -> no reading; divide by the
    distortion factor of the jittered pixel's table cell (:mod:`odolab.sim.redwood`; a hole cell ->
    no reading); quantise disparity: ``denom = round((35.130 / d + N(0, 1) * 0.027778 * m) * 8)``,
    ``out = 35.130 * 8 / denom`` (no reading if denom <= 0). Finally habitat-lab's depth sensor clips
    to [``min_depth``, ``max_depth``]: readings beyond ``max_depth`` become ``max_depth``; readings
    below ``min_depth`` and holes are 0 here, odolab's "no reading", which habitat-lab's normalised
    depth ``(d - min) / (max - min)`` clipped to [0, 1] maps to the same 0 (see
    :func:`habitat_normalized_depth`). ``distortion=None`` uses :func:`odolab.sim.redwood.default_table`;
    ``use_distortion=False`` skips the table (the Redwood paper's optional step).
    """

    multiplier: float = 1.0
    min_depth: float = 0.1
    max_depth: float = 10.0
    distortion: DistortionTable | None = None
    use_distortion: bool = True
    gauss: GaussianTable = field(default_factory=GaussianTable, repr=False)

    def __post_init__(self) -> None:
        # Pixel shift of step 1 per 16-bit draw: floor(0.25 m N + 0.5). Adding it to the integer pixel
        # index and then clipping equals Habitat's int(clip(j + 0.25 m N, 0, H - 1) + 0.5) exactly.
        self._shift = np.floor(0.25 * self.multiplier * self.gauss.table + 0.5).astype(np.int16)
        if self.use_distortion and self.distortion is None:
            self.distortion = default_table()
        # disparity noise in the units of 8 x disparity, one 16-bit draw each
        self._noise8 = (self.gauss.table * np.float32(0.027778 * 8.0 * self.multiplier)).astype(np.float32)
        self._lut_shape: tuple[int, int] | None = None

    def _luts(self, H: int, W: int) -> None:
        """Index tables for an H x W image, from a padded jittered row (column) index to a packed
        integer ``(source pixel << 13) | table cell``, so that adding a row and a column entry gives
        both the downsampled pixel to read and the distortion cell of the jittered coordinates."""
        pad = int(np.abs(self._shift).max())
        rows = np.clip(np.arange(-pad, H + pad), 0, H - 1)
        cols = np.clip(np.arange(-pad, W + pad), 0, W - 1)
        cell_r, cell_c = cell_lookup(W, H)
        packed = np.int32 if (H * W) << _CELL_BITS < 2**31 else np.int64  # int32 is faster to gather
        self._row_pack = ((((rows & ~1) * W) << _CELL_BITS) + cell_r[rows] * COLS).astype(packed)
        self._col_pack = (((cols & ~1) << _CELL_BITS) + cell_c[cols]).astype(packed)
        self._y_base = np.arange(pad, H + pad, dtype=np.int16)[:, None]
        self._x_base = np.arange(pad, W + pad, dtype=np.int16)[None, :]
        if self.distortion is not None:
            # f(d) is piecewise linear in d between bin centres 1, 3, 5, 7, 9 m (constant outside):
            # on segment k = clip(int((d + 1) / 2), 0, 5), f = A[cell, k] + B[cell, k] d
            T = self.distortion.factors.reshape(-1, BINS).astype(np.float64)
            A, B = np.empty((len(T), BINS + 1)), np.zeros((len(T), BINS + 1))
            A[:, 0], A[:, BINS] = T[:, 0], T[:, BINS - 1]
            for k in range(1, BINS):
                B[:, k] = (T[:, k] - T[:, k - 1]) / 2.0
                A[:, k] = T[:, k - 1] - B[:, k] * (2 * k - 1)
            self._seg_a, self._seg_b = A.astype(np.float32).reshape(-1), B.astype(np.float32).reshape(-1)
        self._lut_shape = (H, W)

    def apply(self, depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Noisy copy of a (H, W) float32 depth image in metres (0 = no reading)."""
        if self.multiplier == 0:  # noise off: the clean depth within habitat-lab's range
            return np.where((depth >= self.min_depth) & (depth <= self.max_depth), depth, 0.0).astype(np.float32)
        H, W = depth.shape
        if self._lut_shape != (H, W):
            self._luts(H, W)
        draws = uniform_u16(rng, (3, H, W))
        packed = np.take(self._row_pack, self._y_base + np.take(self._shift, draws[0])) + np.take(
            self._col_pack, self._x_base + np.take(self._shift, draws[1])
        )
        d = np.take(depth.reshape(-1), packed >> _CELL_BITS)  # 2x-downsampled read at the jittered pixel
        valid = (d > 0) & (d < self.max_depth)
        if self.distortion is not None:  # disparity 35.130 / (d / f) = 35.130 f / d
            k = (packed & _CELL_MASK) * (BINS + 1) + np.minimum(((d + 1.0) * 0.5).astype(np.int32), BINS)
            f = np.take(self._seg_a, k) + np.take(self._seg_b, k) * d
            valid &= f >= 1e-5
        else:
            f = np.float32(1.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            scaled = np.where(valid, f / d, np.float32(0.0)) * np.float32(_DISPARITY * 8.0)
            denom = np.rint(scaled + np.take(self._noise8, draws[2]))
            out = np.where(valid & (denom > 0), np.float32(_DISPARITY * 8.0) / denom, np.float32(0.0))
        np.minimum(out, np.float32(self.max_depth), out=out)  # habitat-lab's clip from above
        out[out < self.min_depth] = 0.0  # and from below: "no reading" (normalised 0)
        return out


def habitat_normalized_depth(depth: np.ndarray, min_depth: float = 0.1, max_depth: float = 10.0) -> np.ndarray:
    """habitat-lab's normalised depth observation, ``clip((d - min) / (max - min), 0, 1)``, from
    odolab depth in metres (0 = no reading maps to 0, as a clipped hole does in habitat-lab)."""
    return np.clip((np.asarray(depth, np.float32) - min_depth) / (max_depth - min_depth), 0.0, 1.0)


# (mean, VARIANCE) per component, metres and radians (docs/reference-facts.md section 2; habitat-sim pyrobot_noisy_controls.py).
_ACTUATION = {
    "ilqr": {
        "forward": ((0.014, 0.009, 0.008), (0.006, 0.005, 0.004)),
        "turn": ((0.003, 0.003, 0.023), (0.002, 0.003, 0.012)),
    },
    "proportional": {
        "forward": ((0.017, 0.042, 0.031), (0.007, 0.023, 0.026)),
        "turn": ((0.001, 0.005, 0.043), (0.001, 0.004, 0.017)),
    },
    "movebase": {
        "forward": ((0.074, 0.036, 0.189), (0.019, 0.033, 0.038)),
        "turn": ((0.002, 0.003, 0.219), (0.0, 0.002, 0.019)),
    },
}
CONTROLLERS = tuple(_ACTUATION)


def truncated_normal(rng: np.random.Generator, mean: np.ndarray, std: np.ndarray, k: float = 3.0) -> np.ndarray:
    """Independent normals N(mean, std^2) truncated to mean +- k std (rejection sampling)."""
    mean, std = np.asarray(mean, float), np.asarray(std, float)
    out = np.empty_like(mean)
    todo = np.ones(mean.shape, dtype=bool)
    while todo.any():
        z = rng.standard_normal(mean.shape)
        take = todo & (np.abs(z) <= k)
        out[take] = (mean + std * z)[take]
        todo &= ~take
    return out


@dataclass(frozen=True)
class Motion:
    """An executed motion in the agent's frame before the step: ``forward`` and ``right`` (m), then
    a rotation ``yaw`` (rad, + = left)."""

    forward: float
    right: float
    yaw: float


@dataclass(frozen=True)
class ActuationNoise:
    """PyRobot LoCoBot actuation noise for a controller, scaled by ``multiplier`` (0 = exact)."""

    controller: str = "proportional"
    multiplier: float = 0.5

    def __post_init__(self) -> None:
        if self.controller not in _ACTUATION:
            raise ValueError(f"unknown controller {self.controller!r}; expected one of {', '.join(CONTROLLERS)}")

    def sample(self, action: Action, rng: np.random.Generator) -> Motion:
        """The motion actually executed for ``action`` (a fresh noise draw).

        Translation: (amount + n_along) forward and n_lateral to the right; rotation: the commanded
        angle plus n_yaw times the command's sign (so turns overshoot on average; a forward step
        counts as positive). Along-track forward noise is truncated below at -0.95 * 0.25 m and the
        turn yaw noise below at -0.95 * 30 deg.
        """
        if action == Action.STOP:
            return Motion(0.0, 0.0, 0.0)
        amount = FORWARD_STEP if action == Action.MOVE_FORWARD else 0.0
        angle = {Action.TURN_LEFT: TURN_ANGLE, Action.TURN_RIGHT: -TURN_ANGLE}.get(action, 0.0)
        kind = "forward" if action == Action.MOVE_FORWARD else "turn"
        mean, var = _ACTUATION[self.controller][kind]
        along, lateral, yaw = self.multiplier * truncated_normal(rng, np.array(mean), np.sqrt(var))
        if action == Action.MOVE_FORWARD:
            along = max(along, -0.95 * FORWARD_STEP)
        else:
            yaw = max(yaw, -0.95 * TURN_ANGLE)
        sign_t = np.sign(amount + 1e-8)
        sign_r = np.sign(angle + 1e-8)
        return Motion(float((amount + along) * sign_t), float(lateral), float(angle + yaw * sign_r))
