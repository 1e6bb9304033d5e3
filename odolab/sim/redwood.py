"""The Redwood depth-distortion table that habitat-sim's Redwood noise model always applies.

habitat-sim (MIT licence, ``habitat_sim/sensors/noise_models/redwood_depth_noise_model.py``) loads
``data/redwood-depth-dist-model.npy``, a table of 80 x 80 cells x 5 depth bins from the Redwood
simulated-depth model (Choi, Zhou, Koltun, "Robust Reconstruction of Indoor Scenes", CVPR 2015;
redwood-data.org). For an output pixel with jittered image coordinates (x, y) and depth d it reads

* the cell ``(row, col) = (int(y / (H - 1) * 479 + 0.5) // 6, int(x / (W - 1) * 639 + 0.5) // 8)``
  (the table was made for a 640 x 480 sensor; any image size is mapped onto it),
* the factor ``f = (1 - a) * T[row, col, i1] + a * T[row, col, i2]`` with ``i2 = int((d + 1) / 2)``,
  ``i1 = i2 - 1`` (both clipped to 0..4) and ``a = (d - (2 i1 + 1)) / 2`` (bins centred on 1, 3,
  5, 7, 9 m), and returns ``d / f``; ``f < 1e-5`` marks a *hole*: no reading, ever.

odolab cannot ship habitat-sim's file itself (it is not on any package index this project installs
from), so :func:`default_table` looks for the exact table first (``ODOLAB_REDWOOD_TABLE`` naming a
``.npy`` file, or an installed ``habitat_sim``) and otherwise builds :func:`surrogate_table`: a
statistical model of the same table, written from its measured properties:

* holes: the same cells (rows 0-1 and 78-79, columns 0 and 76-79, and columns 55-79 of row 2);
  at 341 x 192 that is 11 % of the frame, a band along all four edges, widest on the right;
* factor: per depth bin, a quintic profile across the columns (the table varies mostly along x)
  plus a smooth zero-mean cell-to-cell field with the table's residual spread per bin
  (0.002, 0.006, 0.011, 0.017, 0.020) and its spatial correlation (lag-1 about 0.85).

:mod:`odolab.simcard` measures the resulting hole share, bias and spread per depth bin.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

ROWS, COLS, BINS = 80, 80, 5
SENSOR_WIDTH, SENSOR_HEIGHT = 640, 480  # the sensor the table was made for
ENV_VAR = "ODOLAB_REDWOOD_TABLE"

# Per-bin column profile of the factor: polynomial coefficients (constant first) in the column
# coordinate s = (col + 0.5) / 40 - 1 in [-1, 1], fitted by least squares to habitat-sim's table
# (column means over the non-hole rows); and the spread of the cells around that profile.
_PROFILE = np.array(
    [
        [0.9980, 0.0061, 0.0043, -0.0205, -0.0002, 0.0150],
        [0.9904, 0.0170, 0.0427, -0.0584, -0.0114, 0.0457],
        [0.9821, 0.0378, 0.0879, -0.1159, -0.0231, 0.0911],
        [0.9716, 0.0400, 0.1552, -0.0806, -0.0765, 0.0315],
        [0.9627, 0.0603, 0.1832, -0.1379, -0.1381, 0.0805],
    ]
)
_CELL_SPREAD = np.array([0.0021, 0.0059, 0.0110, 0.0172, 0.0201])
_CELL_CORRELATION_SIGMA = 2.5  # cells: a Gaussian field with lag-1 correlation about 0.85


@dataclass(frozen=True)
class DistortionTable:
    """Factors ``(80, 80, 5)`` float32 (row, col, depth bin); ``source`` says where they came from."""

    factors: np.ndarray
    source: str


def hole_cells() -> np.ndarray:
    """(80, 80) bool: the hole cells of habitat-sim's table."""
    holes = np.zeros((ROWS, COLS), bool)
    holes[[0, 1, ROWS - 2, ROWS - 1], :] = True
    holes[:, [0, COLS - 4, COLS - 3, COLS - 2, COLS - 1]] = True
    holes[2, 55:] = True
    return holes


def surrogate_table(seed: int = 0) -> DistortionTable:
    """The statistical model of habitat-sim's table described in the module docstring."""
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(np.random.SeedSequence([0x2ED, seed]))
    s = (np.arange(COLS) + 0.5) / (COLS / 2) - 1.0
    factors = np.empty((ROWS, COLS, BINS), np.float32)
    for b in range(BINS):
        profile = np.polynomial.polynomial.polyval(s, _PROFILE[b])
        field = gaussian_filter(rng.standard_normal((ROWS, COLS)), _CELL_CORRELATION_SIGMA, mode="reflect")
        field *= _CELL_SPREAD[b] / field.std()
        factors[:, :, b] = profile[None, :] + field
    factors[hole_cells()] = 0.0
    return DistortionTable(factors, "odolab surrogate of habitat-sim's redwood-depth-dist-model.npy")


def load_table(path: str | os.PathLike) -> DistortionTable:
    """Read a ``redwood-depth-dist-model.npy`` (32,000 float values, e.g. shape (80, 400)).

    Raises ``ValueError`` naming the file when it is not such a table.
    """
    p = Path(path)
    try:
        with open(p, "rb") as f:
            if f.read(6) != b"\x93NUMPY":
                raise ValueError(f"{p}: not a .npy file (expected habitat-sim's redwood-depth-dist-model.npy)")
        try:
            arr = np.load(p, allow_pickle=False)
        except (ValueError, EOFError) as exc:
            raise ValueError(f"{p}: damaged .npy file ({exc})") from None
    except OSError as exc:
        raise ValueError(f"{p}: cannot be read ({exc.strerror or exc})") from None
    if arr.size != ROWS * COLS * BINS or not np.issubdtype(arr.dtype, np.floating):
        raise ValueError(
            f"{p}: expected {ROWS * COLS * BINS} float values (80 x 80 cells x 5 bins), got {arr.size} of {arr.dtype}"
        )
    factors = arr.reshape(ROWS, COLS, BINS).astype(np.float32)  # habitat-sim's own reshape
    if not np.all(np.isfinite(factors)) or factors.min() < 0 or factors.max() > 2:
        raise ValueError(f"{p}: factors must be finite and in [0, 2], got {factors.min():g}..{factors.max():g}")
    return DistortionTable(factors, str(p))


def find_exact_table() -> Path | None:
    """habitat-sim's table if this machine has it: ``$ODOLAB_REDWOOD_TABLE``, else an installed
    ``habitat_sim`` package's data file; None otherwise."""
    named = os.environ.get(ENV_VAR)
    if named:
        return Path(named)
    try:
        import importlib.util

        spec = importlib.util.find_spec("habitat_sim")
    except (ImportError, ValueError):
        spec = None
    if spec is not None and spec.submodule_search_locations:
        for root in spec.submodule_search_locations:
            p = Path(root) / "sensors" / "noise_models" / "data" / "redwood-depth-dist-model.npy"
            if p.is_file():
                return p
    return None


def default_table() -> DistortionTable:
    """The exact table when :func:`find_exact_table` finds one, else :func:`surrogate_table`.

    A bad file raises ``ValueError`` naming it (and ``ODOLAB_REDWOOD_TABLE`` when that chose it)."""
    exact = find_exact_table()
    if exact is None:
        return surrogate_table()
    try:
        return load_table(exact)
    except ValueError as exc:
        if os.environ.get(ENV_VAR):
            raise ValueError(f"{ENV_VAR}: {exc}") from None
        raise


def cell_lookup(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column of the table cell seen by each pixel row (``height``,) and column (``width``,)."""
    rows = (np.arange(height) / max(height - 1, 1) * (SENSOR_HEIGHT - 1) + 0.5).astype(np.int64) // 6
    cols = (np.arange(width) / max(width - 1, 1) * (SENSOR_WIDTH - 1) + 0.5).astype(np.int64) // 8
    return np.minimum(rows, ROWS - 1), np.minimum(cols, COLS - 1)


def table_digest() -> str:
    """A short hash of :func:`default_table`'s factors, for cache keys (episodes made with another
    table are never reused); computed once per value of ``ODOLAB_REDWOOD_TABLE``."""
    return _digest(os.environ.get(ENV_VAR, ""))


@lru_cache(maxsize=8)
def _digest(_named: str) -> str:
    return hashlib.sha256(default_table().factors.tobytes()).hexdigest()[:16]
