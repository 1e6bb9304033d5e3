"""Validation as every learned odometer reports it: mean absolute error per action and component
(dx m, dz m, dyaw rad, the paper's per-step error) beside the action prior's on the same pairs, kept
per epoch as CSV, drawn as small multiples (PNG) and summarised in ``training.json``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from odolab.api import MOTION_ACTIONS, load_odometer, write_bytes_atomic
from odolab.learned.training.curves import Curves

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
    folder: str | Path,
    rows: list[dict[str, Any]],
    status: dict[str, Any],
    title: str,
    x: str = "epoch",
    final: bool = True,
) -> None:
    """``curves.csv`` (every row), ``curves.png`` (validation rows: one panel per action and
    component, the model against the action prior, yaw in degrees) and ``training.json``
    (``status``), each written atomically into ``folder``; ``final=False`` (after an epoch, the
    training goes on) keeps a figure drawn less than a minute ago (:meth:`Curves.plot`)."""
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
        final=final,
    )
    write_bytes_atomic(folder / "training.json", json.dumps(status, indent=1).encode())


def _recipe_of(command: str) -> tuple[str, tuple[str, ...]] | None:
    """A training command's recipe: its ``--config`` as ``folder/name`` and its ``--set`` changes
    (but those of :data:`_WHERE_NOT_WHAT` and of epochs: more epochs go on with the same training)."""
    import shlex

    try:
        words = shlex.split(command)
    except ValueError:
        return None
    config, changes = None, []
    for k, word in enumerate(words):
        value = word.split("=", 1)[1] if "=" in word and word.startswith("--") else None
        if word.startswith("--config"):
            config = value if value is not None else (words[k + 1] if k + 1 < len(words) else None)
        elif word.startswith("--set"):
            changes.append(value if value is not None else (words[k + 1] if k + 1 < len(words) else ""))
    if config is None:
        return None
    path = Path(config)
    keys = [c.split("=", 1)[0].strip() for c in changes]
    kept = [c for c, k in zip(changes, keys) if not (k.startswith(_WHERE_NOT_WHAT) or k.split(".")[-1] == "epochs")]
    return f"{path.parent.name}/{path.stem}", tuple(sorted(kept))


#: ``--set`` paths that say where or how a run computes, not what it trains (not in its identity).
_WHERE_NOT_WHAT = ("data_root", "compute")


def other_training(reports: Path, command: str) -> str | None:
    """Why ``reports`` holds the reports of another training than ``command``'s (its
    ``training.json`` records another recipe: ``--config`` folder and name, ``--set`` changes), or
    None (no summary there, or the same recipe)."""
    path = Path(reports) / "training.json"
    if not path.is_file():
        return None
    try:
        status = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return f"{path}: not a readable training summary"
    recorded = status.get("command") if isinstance(status, dict) else None
    if not isinstance(recorded, str) or _recipe_of(recorded) != _recipe_of(command):
        shown = str(recorded) if len(str(recorded)) <= 120 else str(recorded)[:120] + "..."
        return f"{path} is the summary of another training ({shown!r})"
    return None
