"""Calibrated covariances of each fused input, per action, fitted on held-out steps.

For each input and action, from its valid raw steps against the true motions (residuals rx, ry, rz
rad, tx, ty, tz m; right perturbation, :mod:`odolab.fusion.graph`):

* ``bias``: the mean residual of the steps whose every component lies within 3 robust sigmas
  (1.4826 x median absolute deviation, at least :data:`SIGMA_FLOOR`) of its median; fusion corrects
  each answer by it, ``T @ exp(bias)``.
* ``fixed``: six sigmas, the RMS of each component of those steps' debiased residuals (at least the
  floor), all scaled by one factor so that 95 % of all the steps fall inside the 95 % ellipsoid
  (chi-square, 6 degrees of freedom) of ``D R D``, with ``correlation`` R their correlation matrix
  (components at the floor uncorrelated): the covariance of steps that bring none of their own.
* ``own_scale``: the factor that does the same to the odometer's own covariances; None when it
  gives none, or when they explain the residuals less well (mean Gaussian negative log-likelihood).

A view is *near* when its median depth reading is below the file's ``near_depth`` (m; absent or 0:
none is); an input and action with at least 10 valid near steps and 10 others gets a second entry,
``"<action>@near"``, fitted on the near steps and used for near views (the plain entry is then
fitted on the others, else on all). ``bias`` and ``correlation`` may be absent from a file: no
bias, no correlation. A quantile fit, because the residuals have heavy tails; :func:`ellipsoid_share`
checks it on other data. Why each part, and what the shipped calibration holds:
docs/fusion.md#calibration.
"""

from __future__ import annotations

import hashlib
import json
import os
import reprlib
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import gtsam
import numpy as np

from odolab.core.types import MOTION_ACTIONS, Action
from odolab.io.atomic import write_bytes_atomic
from odolab.io.inputs import parse_input_json, read_input_bytes, read_input_json

#: Sigmas outside this range (rad or m) are refused in a calibration file: their squares misbehave.
SIGMA_RANGE = (1e-6, 1e3)
#: Scales on an odometer's own covariance outside this range are refused likewise.
SCALE_RANGE = (1e-12, 1e12)
#: Correlation matrices are shrunk this much towards the identity, so that they stay invertible.
CORRELATION_SHRINK = 1e-3
#: Smallest eigenvalue a correlation matrix in a file may have (GTSAM fails on nearly singular ones).
MIN_CORRELATION_EIGENVALUE = 5e-4
#: Largest bias a file may give: rotations (rad), translations (m).
BIAS_LIMITS = (0.5, 1.0)
#: chi-square with 6 degrees of freedom: 95 % quantile.
CHI2_6_95 = 12.591587243743977
#: Smallest sigma per component (rad or m): planar odometers leave out-of-plane residuals near zero.
SIGMA_FLOOR = 1e-3
FORMAT = 1
#: The command that writes calibration files: each one's ``source`` begins with it.
COMMAND = "python -m odolab.fusion.calibrate"
#: Suffix of the labels of near-view entries (``turn_left@near``).
NEAR = "@near"
#: Largest near_depth a file may give, metres.
MAX_NEAR_DEPTH = 100.0
#: Fewest valid steps an entry is fitted from.
MIN_STEPS = 10


def view_is_near(depth: np.ndarray, near_depth: float) -> bool:
    """True when the median of the depth image's readings (metres, 0 = none) is below ``near_depth``
    (never when ``near_depth`` is 0 or no pixel has a reading)."""
    if near_depth <= 0:
        return False
    seen = np.asarray(depth)[np.asarray(depth) > 0]
    return bool(seen.size) and float(np.median(seen)) < near_depth


def context_labels() -> list[str]:
    """Every label an entry may have: each motion action's, and its near-view one."""
    return [a.label for a in MOTION_ACTIONS] + [a.label + NEAR for a in MOTION_ACTIONS]


def mahalanobis2(xi: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Squared Mahalanobis distances of residuals ``xi`` (N, 6) under covariances ``cov`` (N, 6, 6)
    or one (6, 6)."""
    cov = np.broadcast_to(cov, (len(xi), 6, 6))
    return np.einsum("ni,ni->n", xi, np.linalg.solve(cov, xi[..., None])[..., 0])


def ellipsoid_share(xi: np.ndarray, cov: np.ndarray) -> float:
    """Share of residuals inside their 95 % ellipsoid (0.95 when calibrated)."""
    return float(np.mean(mahalanobis2(xi, cov) <= CHI2_6_95)) if len(xi) else float("nan")


def _scale(m2: np.ndarray) -> float:
    """Factor on a covariance that puts the 95 % quantile of ``m2`` on the chi-square one."""
    return float(max(np.quantile(m2, 0.95) / CHI2_6_95, 1e-12))


def _number(x) -> float:
    """A JSON number (not a bool, not a string), as float."""
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise TypeError(f"expected a number, got {x!r}")
    return float(x)


def _count(x) -> int:
    """A JSON whole number >= 0."""
    if isinstance(x, bool) or not isinstance(x, int) or x < 0:
        raise TypeError(f"expected a whole number of steps >= 0, got {x!r}")
    return x


def _share(x) -> float:
    """A JSON number in [0, 1]."""
    v = _number(x)
    if not 0.0 <= v <= 1.0:
        raise ValueError(f"expected a share in [0, 1], got {x!r}")
    return v


@dataclass(frozen=True)
class InputCalibration:
    """One input's calibration, per action label (see the module docstring)."""

    fixed: dict[str, list[float]]
    own_scale: dict[str, float | None]
    steps: dict[str, int]
    inside95: dict[str, float] = field(default_factory=dict)  # on the calibration steps themselves
    bias: dict[str, list[float]] = field(default_factory=dict)
    correlation: dict[str, list[list[float]]] = field(default_factory=dict)

    def label(self, action: Action | None, near: bool = False) -> str | None:
        """The entry used for a step of ``action`` (near view or not); None for an action it lacks."""
        if action not in MOTION_ACTIONS:
            return None
        if near and action.label + NEAR in self.fixed:
            return action.label + NEAR
        return action.label if action.label in self.fixed else None

    def covariance(self, action: Action | None, own: np.ndarray | None, near: bool = False) -> np.ndarray:
        """Calibrated 6x6 (right perturbation) for a step of ``action`` (from a near view or not);
        ``own``: the step's own covariance, already right-perturbation (or None). Unknown actions take
        the largest fixed one."""
        label = self.label(action, near)
        if label is None:
            return np.diag(np.max([np.square(v) for v in self.fixed.values()], axis=0))
        scale = self.own_scale.get(label)
        if own is not None and scale is not None and np.all(np.isfinite(own)):
            return scale * np.asarray(own, np.float64)
        return _joint(np.asarray(self.fixed[label]), np.asarray(self.correlation.get(label, np.eye(6)), np.float64))

    def bias_of(self, action: Action | None, near: bool = False) -> np.ndarray:
        """The bias (6,) of a step of ``action`` (zeros when none was calibrated for it)."""
        label = self.label(action, near)
        return np.asarray(self.bias.get(label, np.zeros(6)) if label else np.zeros(6), np.float64)

    def corrected(self, action: Action | None, T: np.ndarray, near: bool = False) -> np.ndarray:
        """A measured step ``T`` (4x4, previous camera -> current) corrected by the bias: ``T @ exp(bias)``."""
        bias = self.bias_of(action, near)
        if not np.any(bias):
            return np.asarray(T, np.float64)
        return np.asarray(T, np.float64) @ gtsam.Pose3.Expmap(bias).matrix()


def _joint(sigma: np.ndarray, corr: np.ndarray) -> np.ndarray:
    """The covariance (6, 6) ``D R D`` of sigmas ``sigma`` (6,) and correlation matrix ``corr``."""
    return np.diag(sigma) @ corr @ np.diag(sigma)


def inliers(xi: np.ndarray) -> np.ndarray:
    """(N,) bool: the residuals ``xi`` (N, 6) whose every component lies within 3 robust sigmas
    (1.4826 x median absolute deviation, at least :data:`SIGMA_FLOOR`) of that component's median."""
    med = np.median(xi, axis=0)
    mad = 1.4826 * np.median(np.abs(xi - med), axis=0)
    return np.all(np.abs(xi - med) <= 3.0 * np.maximum(mad, SIGMA_FLOOR), axis=1)


def debiased(xi: np.ndarray, bias: np.ndarray) -> np.ndarray:
    """Residuals (N, 6) of the bias-corrected measurements ``T @ exp(bias)`` from those of ``T``:
    ``log(exp(-bias) exp(xi))`` per row (exact on SE(3), not a subtraction)."""
    B = gtsam.Pose3.Expmap(np.asarray(bias, np.float64))
    return np.array([gtsam.Pose3.Logmap(B.between(gtsam.Pose3.Expmap(np.asarray(x, np.float64)))) for x in xi]).reshape(
        -1, 6
    )


def nll(xi: np.ndarray, cov: np.ndarray) -> float:
    """Mean Gaussian negative log-likelihood (nats, constant left out) of residuals ``xi`` (N, 6) under
    covariances ``cov`` (N, 6, 6) or one (6, 6)."""
    sign, logdet = np.linalg.slogdet(np.broadcast_to(cov, (len(xi), 6, 6)))
    if np.any(sign <= 0):  # not a covariance at all: explains nothing
        return float("inf")
    return float(np.mean(0.5 * (mahalanobis2(xi, cov) + logdet)))


def _correlation(r: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Correlation matrix (6, 6) of residuals ``r`` about zero; components whose sigma is at the floor
    are left uncorrelated; shrunk by :data:`CORRELATION_SHRINK` towards the identity."""
    live = sigma > SIGMA_FLOOR
    rms = np.sqrt(np.mean(r**2, axis=0))
    corr = np.eye(6)
    if live.sum() >= 2:
        sub = r[:, live] / rms[live]
        corr[np.ix_(live, live)] = sub.T @ sub / len(r)
    corr = (1.0 - CORRELATION_SHRINK) * corr + CORRELATION_SHRINK * np.eye(6)
    np.fill_diagonal(corr, 1.0)
    return corr


def _fit_entry(
    xi: np.ndarray, own: list[np.ndarray | None]
) -> tuple[list[float], float | None, list[float], list[list[float]], float]:
    """One entry from its steps' residuals ``xi`` (N, 6) and own covariances: (sigmas, own scale or
    None, bias, correlation, share of the steps inside the 95 % ellipsoid)."""
    keep = inliers(xi)
    if keep.sum() < MIN_STEPS:
        keep[:] = True
    bias = xi[keep].mean(axis=0)
    r = debiased(xi, bias)
    sigma = np.maximum(np.sqrt(np.mean(r[keep] ** 2, axis=0)), SIGMA_FLOOR)  # the shape from the inliers,
    corr = _correlation(r[keep], sigma)  # the size (below) from every step
    sigma = np.maximum(sigma * np.sqrt(_scale(mahalanobis2(r, _joint(sigma, corr)))), SIGMA_FLOOR)
    fixed = _joint(sigma, corr)
    have = [i for i, c in enumerate(own) if c is not None and np.all(np.isfinite(c))]
    scale = None
    if len(have) >= MIN_STEPS:
        covs = np.stack([own[i] for i in have])
        try:
            s = _scale(mahalanobis2(r[have], covs))
            if nll(r[have], s * covs) < nll(r[have], fixed):  # own covariances must earn their place
                scale = s
        except np.linalg.LinAlgError:
            pass
    covs = np.stack([scale * own[i] if scale is not None and i in have else fixed for i in range(len(r))])
    return (
        [float(v) for v in sigma],
        scale,
        [float(b) for b in bias],
        [[float(c) for c in row] for row in corr],
        ellipsoid_share(r, covs),
    )


def fit_input(
    xi: np.ndarray, actions: np.ndarray, own: list[np.ndarray | None], near: np.ndarray | None = None
) -> InputCalibration:
    """Fit one input from its valid steps: residuals ``xi`` (N, 6), action values (N,), own
    covariances (right perturbation) or None per step, and whether each step's view was near (N,
    bool; None = no near class)."""
    near = np.zeros(len(actions), bool) if near is None else np.asarray(near, bool)
    tables: dict[str, dict] = {k: {} for k in ("fixed", "own_scale", "steps", "inside95", "bias", "correlation")}
    for a in MOTION_ACTIONS:
        mine = actions == a.value
        near_rows, far_rows = np.flatnonzero(mine & near), np.flatnonzero(mine & ~near)
        split = len(near_rows) >= MIN_STEPS and len(far_rows) >= MIN_STEPS
        groups = [(a.label + NEAR, near_rows), (a.label, far_rows)] if split else [(a.label, np.flatnonzero(mine))]
        for label, rows in groups:
            if len(rows) < MIN_STEPS:
                continue
            entry = _fit_entry(xi[rows], [own[k] for k in rows])
            for key, value in zip(("fixed", "own_scale", "bias", "correlation", "inside95"), entry):
                tables[key][label] = value
            tables["steps"][label] = len(rows)
    if not tables["fixed"]:
        raise ValueError(f"too few valid steps to calibrate (at least {MIN_STEPS} of some action are needed)")
    return InputCalibration(**tables)


@dataclass(frozen=True)
class Calibration:
    """Calibrations by odometer name, the depth (m) below which a view is near (0 = no near class;
    module docstring), and the command that made them."""

    inputs: dict[str, InputCalibration]
    source: str = ""
    near_depth: float = 0.0
    digest: str = field(default="", compare=False)  # sha256 of the file it was loaded from ("" if made here)

    def for_input(self, name: str) -> InputCalibration:
        if name not in self.inputs:
            raise ValueError(
                f"no calibration for odometer {name!r} (calibrated: {', '.join(sorted(self.inputs))}); "
                f"run python -m odolab.fusion.calibrate --odometers {name},..."
            )
        return self.inputs[name]

    def save(self, path: str | os.PathLike) -> None:
        doc = {
            "format": FORMAT,
            "source": self.source,
            "near_depth": self.near_depth,
            "inputs": {n: asdict(c) for n, c in self.inputs.items()},
        }
        write_bytes_atomic(path, (json.dumps(doc, indent=1) + "\n").encode())

    @classmethod
    def load(cls, path: str | os.PathLike) -> Calibration:
        """Read a calibration file; errors name the file, the input, the field and the action, and
        say what was expected and what was found."""
        data = read_input_bytes(path, "calibration file")  # the digest is of these bytes
        doc = parse_input_json(data, path, "calibration file")
        fmt = doc.get("format") if isinstance(doc, dict) else None
        if type(fmt) is int and fmt != FORMAT and isinstance(doc.get("inputs"), dict):
            raise ValueError(
                f"{path}: a calibration of format {fmt}, this odolab reads format {FORMAT}; "
                "calibrate again with python -m odolab.fusion.calibrate"
            )
        if (
            not isinstance(doc, dict)
            or type(fmt) is not int
            or fmt != FORMAT
            or not isinstance(doc.get("inputs"), dict)
        ):
            raise ValueError(f"{path}: not a calibration file of format {FORMAT} (expected keys format, inputs)")
        stray = sorted(set(doc) - {"format", "source", "near_depth", "inputs"})
        if stray:
            raise ValueError(
                f"{path}: unknown key {stray[0]!r}; a calibration file has format, source, near_depth, inputs"
            )
        near_depth = doc.get("near_depth", 0.0)
        if (
            isinstance(near_depth, bool)
            or not isinstance(near_depth, (int, float))
            or not 0.0 <= near_depth <= MAX_NEAR_DEPTH
        ):
            raise ValueError(
                f"{path}: near_depth must be a number of metres in [0, {MAX_NEAR_DEPTH:g}] (0: no near "
                f"class), got {reprlib.repr(near_depth)}"
            )
        if not isinstance(doc.get("source", ""), str):
            raise ValueError(
                f"{path}: source must be a string (the command that made the file), got {reprlib.repr(doc['source'])}"
            )
        if not doc["inputs"]:
            raise ValueError(f"{path}: calibrates no odometer (its 'inputs' is empty)")
        inputs = {name: _input(c, f"{path}: input {name!r}") for name, c in doc["inputs"].items()}
        for name, cal in inputs.items():
            near = sorted(label for label in cal.fixed if label.endswith(NEAR))
            lone = next((label for label in near if label[: -len(NEAR)] not in cal.fixed), None)
            if lone is not None:
                raise ValueError(
                    f"{path}: input {name!r}: {lone!r} without {lone[: -len(NEAR)]!r} (a near entry "
                    "refines a plain one; far views need the plain one)"
                )
            if near and not near_depth:
                raise ValueError(
                    f"{path}: input {name!r} has near-view entries ({', '.join(near)}) but the file's "
                    "near_depth is 0 or absent, so they would never be used; give near_depth in metres"
                )
        return cls(inputs, doc.get("source", ""), float(near_depth), hashlib.sha256(data).hexdigest())


def what_file(path: str | os.PathLike) -> str | None:
    """None when existing file ``path`` is a calibration :data:`COMMAND` wrote (of any format: a new
    calibration may replace it); else what it is, in words ("a JSON file that is not a fusion
    calibration (...)"), for a refusal to replace it."""
    try:
        doc = read_input_json(path, "calibration file")
    except ValueError:  # not JSON, not UTF-8, too large, not a regular file
        return "a file that is not a fusion calibration (not a JSON document odolab reads)"
    if not isinstance(doc, dict) or "format" not in doc or not isinstance(doc.get("inputs"), dict):
        has = f"keys {reprlib.repr(sorted(doc))}" if isinstance(doc, dict) else "not a JSON object"
        return f"a JSON file that is not a fusion calibration ({has}; a calibration has format, source, inputs)"
    source = doc.get("source")
    if not isinstance(source, str) or not source.startswith(COMMAND):
        return f"a calibration that {COMMAND} did not write (its source is {reprlib.repr(source)})"
    return None


def _numbers(v: Any, n: int) -> list[float]:
    if not isinstance(v, list) or len(v) != n:
        raise ValueError(f"expected a list of {n} numbers, got {reprlib.repr(v)}")
    out = [_number(x) for x in v]
    if not all(np.isfinite(out)):
        raise ValueError(f"expected finite numbers, got {reprlib.repr(v)}")
    return out


def _sigmas(v: Any) -> list[float]:
    out, (lo, hi) = _numbers(v, 6), SIGMA_RANGE
    if not all(lo <= x <= hi for x in out):
        raise ValueError(f"expected 6 sigmas in [{lo:g}, {hi:g}], got {reprlib.repr(v)}")
    return out


def _bias(v: Any) -> list[float]:
    out, (rot, trans) = _numbers(v, 6), BIAS_LIMITS
    if not all(abs(x) <= rot for x in out[:3]) or not all(abs(x) <= trans for x in out[3:]):
        raise ValueError(
            f"expected rotations within +-{rot:g} rad then translations within +-{trans:g} m "
            f"(a larger systematic error is a broken odometer, not one to correct), got {reprlib.repr(v)}"
        )
    return out


def _correlation_matrix(v: Any) -> list[list[float]]:
    if not isinstance(v, list) or len(v) != 6:
        raise ValueError(f"expected 6 rows of 6 numbers, got {reprlib.repr(v)}")
    rows = [_numbers(row, 6) for row in v]
    a = np.asarray(rows)
    if not np.allclose(a, a.T, atol=1e-9):
        raise ValueError("expected a symmetric matrix")
    if not np.allclose(np.diag(a), 1.0, atol=1e-9):
        raise ValueError(f"expected ones on the diagonal, got {reprlib.repr(np.diag(a).tolist())}")
    smallest = float(np.linalg.eigvalsh(a).min())
    if smallest < MIN_CORRELATION_EIGENVALUE:
        raise ValueError(
            f"expected a positive definite matrix with eigenvalues of at least "
            f"{MIN_CORRELATION_EIGENVALUE:g} (a fitted one has at least {CORRELATION_SHRINK:g}), "
            f"its smallest is {smallest:.3g}"
        )
    return rows


def _own_scale(v: Any) -> float | None:
    if v is None:
        return None
    x, (lo, hi) = _number(v), SCALE_RANGE
    if not lo <= x <= hi:
        raise ValueError(f"expected null or a number in [{lo:g}, {hi:g}], got {reprlib.repr(v)}")
    return x


#: What each key of an input holds per action, and how it is read.
_FIELDS: dict[str, Callable[[Any], Any]] = {
    "fixed": _sigmas,
    "own_scale": _own_scale,
    "steps": _count,
    "inside95": _share,
    "bias": _bias,
    "correlation": _correlation_matrix,
}
_REQUIRED = ("fixed", "own_scale", "steps")


def _input(c: Any, where: str) -> InputCalibration:
    """One input's calibration from its JSON object; ``where`` starts every error message."""
    if not isinstance(c, dict):
        raise ValueError(f"{where}: expected an object with keys {', '.join(_FIELDS)}, got {reprlib.repr(c)}")
    stray = sorted(set(c) - set(_FIELDS))
    if stray:
        raise ValueError(f"{where}: unknown key {stray[0]!r}; expected some of {', '.join(_FIELDS)}")
    missing = [k for k in _REQUIRED if k not in c]
    if missing:
        raise ValueError(
            f"{where}: no {missing[0]!r}; expected {', '.join(_REQUIRED)} (and optionally "
            f"{', '.join(k for k in _FIELDS if k not in _REQUIRED)})"
        )
    labels = context_labels()
    parsed = {}
    for key, parse in _FIELDS.items():
        table = c.get(key, {})
        if not isinstance(table, dict):
            raise ValueError(
                f"{where}: {key} must map actions ({', '.join(labels)}) to values, got {reprlib.repr(table)}"
            )
        parsed[key] = {}
        for action, value in table.items():
            if action not in labels:
                raise ValueError(f"{where}: {key}: unknown action {action!r}; expected some of {', '.join(labels)}")
            try:
                parsed[key][action] = parse(value)
            except (TypeError, ValueError, OverflowError) as exc:
                raise ValueError(f"{where}: {key}.{action}: {exc}") from None
    if not parsed["fixed"]:
        raise ValueError(f"{where}: fixed gives no action's sigmas")
    unfixed = sorted((set(parsed["bias"]) | set(parsed["correlation"])) - set(parsed["fixed"]))
    if unfixed:
        raise ValueError(f"{where}: bias or correlation for {unfixed[0]!r}, which has no fixed sigmas")
    return InputCalibration(**parsed)
