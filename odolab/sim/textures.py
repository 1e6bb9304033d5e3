"""Procedural texture tiles, keyed on world coordinates so a surface looks the same from any view.

A tile is a (T, T) float32 brightness pattern in [0, 1]; one texel spans ``TEXEL_SIZE`` metres on
the surface, so a tile repeats every ``T * TEXEL_SIZE`` metres. Patterns mix smooth noise with
sharp edges (bricks, panels, speckles) so corner detectors find trackable features.
"""
from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

TILE_SIZE = 128  # texels
TEXEL_SIZE = 0.015  # m per texel -> 1.92 m period


def _smooth_noise(rng: np.random.Generator, n: int, sigma: float) -> np.ndarray:
    f = gaussian_filter(rng.standard_normal((n, n)), sigma, mode="wrap")
    return (f - f.min()) / (np.ptp(f) + 1e-9)


def _bricks(rng: np.random.Generator, n: int) -> np.ndarray:
    img = np.empty((n, n))
    bh = int(rng.integers(8, 20))
    bw = 2 * bh + int(rng.integers(0, 10))
    yy, xx = np.mgrid[0:n, 0:n]
    row = yy // bh
    xs = (xx + (row % 2) * (bw // 2)) % n
    col = xs // bw
    shade = rng.uniform(0.35, 1.0, size=(n // bh + 2, n // bw + 2))
    img = shade[row, col]
    mortar = ((yy % bh) < 2) | ((xs % bw) < 2)
    return np.where(mortar, 0.1, img)


def _speckles(rng: np.random.Generator, n: int) -> np.ndarray:
    img = 0.5 + 0.3 * _smooth_noise(rng, n, 6)
    for _ in range(160):
        r, c = rng.integers(0, n, 2)
        s = int(rng.integers(2, 6))
        img[np.ix_(np.arange(r, r + s) % n, np.arange(c, c + s) % n)] = rng.uniform(0.0, 1.0)
    return img


def _panels(rng: np.random.Generator, n: int) -> np.ndarray:
    img = 0.6 + 0.2 * _smooth_noise(rng, n, 10)
    for _ in range(14):
        r, c = rng.integers(0, n, 2)
        h, w = rng.integers(6, 40, 2)
        img[np.ix_(np.arange(r, r + h) % n, np.arange(c, c + w) % n)] *= rng.uniform(0.3, 1.3)
    return img


def make_tiles(count: int = 8, size: int = TILE_SIZE, seed: int = 0) -> np.ndarray:
    """``count`` texture tiles (count, size, size) float32 in [0, 1], deterministic in ``seed``."""
    rng = np.random.default_rng(np.random.SeedSequence([0x7E47, seed]))
    makers = [
        lambda: _smooth_noise(rng, size, 2) * 0.6 + _smooth_noise(rng, size, 8) * 0.4,
        lambda: _bricks(rng, size),
        lambda: _speckles(rng, size),
        lambda: _panels(rng, size),
    ]
    tiles = [makers[i % len(makers)]() for i in range(count)]
    return np.clip(np.stack(tiles), 0.0, 1.0).astype(np.float32)
