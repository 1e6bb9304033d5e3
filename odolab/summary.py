"""Turn runner results into the comparison tables (one row per odometer).

Definitions (each metric's formula lives in :mod:`odolab.metrics`):

* ``dx, dz, dyaw``: the paper's per-step error, mean absolute error over all steps of all
  sequences pooled, x 1e-2 (m, m, rad); ``*_std``: standard deviation of the per-sequence means.
* ``fps``: steps per second of the odometer's ``step`` calls alone (total steps / total time).
* ``failures``: steps that raised or returned ``valid=False`` (the action prior was used instead).
* ``ate_m``: mean over sequences of the ATE RMSE (m) with *no* alignment: every trajectory starts
  at the true first pose, so this is the drift a robot would suffer. ``drift_m``: mean final
  position error (m). ``trans_mm`` / ``rot_deg``: mean per-frame relative pose error (real data).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from odolab.geometry import transform_to_planar
from odolab.metrics import ate, per_step_abs_error, relative_motion_errors
from odolab.types import MOTION_ACTIONS
from odolab.runner import SequenceResult


@dataclass(frozen=True)
class Row:
    """One odometer's line of the comparison table (see the module docstring for definitions)."""

    odometer: str
    oracle: bool
    dx: float
    dz: float
    dyaw: float
    dx_std: float
    dz_std: float
    dyaw_std: float
    trans_mm: float
    rot_deg: float
    ate_m: float
    drift_m: float
    fps: float
    failures: int
    steps: int
    sequences: int


@dataclass(frozen=True)
class ActionRow:
    """Per-step error (x 1e-2) of one odometer for one action, and its failed steps."""

    odometer: str
    action: str
    dx: float
    dz: float
    dyaw: float
    steps: int
    failures: int


def _planar(T: np.ndarray) -> np.ndarray:
    return np.stack([transform_to_planar(t) for t in T]) if len(T) else np.zeros((0, 3))


def step_errors(r: SequenceResult) -> np.ndarray:
    """(N, 3) absolute planar errors (m, m, rad) of a result with ground truth."""
    return per_step_abs_error(_planar(r.estimates), _planar(r.truth))


def by_odometer(results: list[SequenceResult]) -> dict[str, list[SequenceResult]]:
    """Results with ground truth grouped by odometer, in first-seen order."""
    groups: dict[str, list[SequenceResult]] = {}
    for r in results:
        if r.truth is not None:
            groups.setdefault(r.odometer, []).append(r)
    return groups


def summarize(results: list[SequenceResult]) -> list[Row]:
    """One :class:`Row` per odometer, in first-seen order. Needs ground truth."""
    rows = []
    for name, mine in by_odometer(results).items():
        errs = [step_errors(r) for r in mine]
        pooled = np.concatenate(errs) * 100.0
        per_seq = np.array([e.mean(axis=0) for e in errs if len(e)]) * 100.0
        rel = [relative_motion_errors(r.gt_poses, r.poses) for r in mine]
        seconds = sum(float(r.step_seconds.sum()) for r in mine)
        steps = len(pooled)
        rows.append(Row(
            odometer=name, oracle=mine[0].oracle,
            dx=float(pooled[:, 0].mean()), dz=float(pooled[:, 1].mean()), dyaw=float(pooled[:, 2].mean()),
            dx_std=float(per_seq[:, 0].std()), dz_std=float(per_seq[:, 1].std()),
            dyaw_std=float(per_seq[:, 2].std()),
            trans_mm=float(np.concatenate([t for t, _ in rel]).mean() * 1e3),
            rot_deg=float(np.concatenate([a for _, a in rel]).mean()),
            ate_m=float(np.mean([ate(r.gt_poses, r.poses).rmse for r in mine])),
            drift_m=float(np.mean([np.linalg.norm(r.poses[-1, :3, 3] - r.gt_poses[-1, :3, 3]) for r in mine])),
            fps=steps / seconds if seconds > 0 else float("inf"),
            failures=sum(r.failures for r in mine), steps=steps, sequences=len(mine),
        ))
    return rows


def summarize_actions(results: list[SequenceResult]) -> list[ActionRow]:
    """Per-step error (x 1e-2) per odometer and motion action."""
    rows = []
    for name, mine in by_odometer(results).items():
        errs = np.concatenate([step_errors(r) for r in mine]) * 100.0
        acts = np.concatenate([r.actions for r in mine])
        valid = np.concatenate([r.valid for r in mine])
        for a in MOTION_ACTIONS:
            sel = acts == a.value
            if sel.any():
                e = errs[sel].mean(axis=0)
                rows.append(ActionRow(name, a.label, float(e[0]), float(e[1]), float(e[2]), int(sel.sum()),
                                      int((~valid[sel]).sum())))
    return rows
