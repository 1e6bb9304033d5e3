"""Every metric odolab reports, with its exact definition. Pure math: no files, no plots.

Per-step error (the paper's tables, Zhao et al. ICCV 2021, Table S4)
---------------------------------------------------------------------
For each step t with estimated planar motion ``(dx, dz, dyaw)_t`` and the true one (conventions in
:mod:`odolab.geometry`)::

    e_t = ( |dx_t - dx*_t|, |dz_t - dz*_t|, |wrap(dyaw_t - dyaw*_t)| )      (m, m, rad)

The paper reports the mean of ``e_t`` over steps, multiplied by 100 ("x 1e-2").
"""
from __future__ import annotations

import numpy as np

from odolab.geometry import wrap_angle

__all__ = ["per_step_abs_error"]


def per_step_abs_error(est_planar: np.ndarray, gt_planar: np.ndarray) -> np.ndarray:
    """Absolute planar errors (N, 3): |dx| m, |dz| m, |dyaw| rad (wrapped) per step."""
    est = np.asarray(est_planar, dtype=np.float64).reshape(-1, 3)
    gt = np.asarray(gt_planar, dtype=np.float64).reshape(-1, 3)
    if est.shape != gt.shape:
        raise ValueError(f"per_step_abs_error: shapes differ, {est.shape} vs {gt.shape}")
    err = np.abs(est - gt)
    err[:, 2] = np.abs(wrap_angle(est[:, 2] - gt[:, 2]))
    return err
