"""6x6 covariances of rigid fits, over (rx, ry, rz, tx, ty, tz): a small motion ``exp(delta)``
applied on the left, in the frame the fitted points are expressed in (for ``T_prev_cur`` that is
the previous camera)."""

from __future__ import annotations

import numpy as np


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


#: An information matrix worse conditioned than this leaves a direction unconstrained.
MAX_CONDITION = 1e12


def covariance_from_information(info: np.ndarray, sigma2: float) -> np.ndarray | None:
    """``sigma2 * inv(info)`` for a 6x6 information matrix of unit-variance residuals.

    ``sigma2``: residual variance per coordinate (m^2). None when ``info`` is singular (the
    geometry leaves a direction unconstrained, e.g. a single plane).
    """
    info = np.asarray(info, dtype=np.float64)
    if not np.all(np.isfinite(info)) or np.linalg.cond(info) > MAX_CONDITION:
        return None
    return sigma2 * np.linalg.inv(info)
