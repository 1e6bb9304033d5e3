"""Validation as every learned odometer reports it: mean absolute error per action and component
(dx m, dz m, dyaw rad, the paper's per-step error) beside the action prior's on the same pairs, kept
per epoch as CSV, drawn as small multiples (PNG) and summarised in ``training.json``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from odolab.api import MOTION_ACTIONS, load_odometer, write_bytes_atomic
from odolab.learning.curves import Curves

COMPONENTS = ("dx", "dz", "dyaw")


def error_rows(pred: np.ndarray, truth: np.ndarray, actions: np.ndarray, **labels: Any) -> list[dict[str, Any]]:
    """One row per (action present, component): ``pairs``, ``mae`` of ``pred`` (N, 3) against
    ``truth`` (N, 3) and ``prior_mae`` of the action prior (the train-split mean motion of each
    action) on the same pairs; ``actions`` (N,) :class:`Action` values; ``labels`` are copied in."""
    prior = load_odometer("action-prior")
    err = np.abs(np.asarray(pred, np.float64) - truth)
    rows = []
    for action in MOTION_ACTIONS:
        mask = np.asarray(actions) == action.value
        if not mask.any():
            continue
        prior_err = np.abs(truth[mask] - prior.step(None, None, action).planar)
        for c, name in enumerate(COMPONENTS):
            rows.append(
                {
                    **labels,
                    "action": action.label,
                    "component": name,
                    "pairs": int(mask.sum()),
                    "mae": float(err[mask, c].mean()),
                    "prior_mae": float(prior_err[:, c].mean()),
                }
            )
    return rows


def write_report(
    folder: str | Path, rows: list[dict[str, Any]], status: dict[str, Any], title: str, x: str = "epoch"
) -> None:
    """``curves.csv`` (every row), ``curves.png`` (validation rows: one panel per action and
    component, the model against the action prior, yaw in degrees) and ``training.json``
    (``status``), each written atomically into ``folder``."""
    folder = Path(folder)
    curves = Curves(rows)
    curves.to_csv(folder / "curves.csv")
    curves.plot(
        folder / "curves.png",
        x=x,
        rows="action",
        cols="component",
        where={"split": "val"},
        series={
            "mae": {"label": "model (val)", "color": "C0"},
            "prior_mae": {
                "label": "action prior (val)",
                "color": "0.5",
                "linestyle": "--",
                "marker": "_",
                "markersize": 8,
            },
        },
        scale={"dyaw": 180 / np.pi},
        title=title,
        ylabel={"dx": "mean |error|, m", "dz": "mean |error|, m", "dyaw": "mean |error|, deg"},
    )
    write_bytes_atomic(folder / "training.json", json.dumps(status, indent=1).encode())
