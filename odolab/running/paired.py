"""Paired differences: how much one odometer's per-step error differs from another's on the same
steps, with a 95 % interval and the verdict it allows.

Definitions, for odometer A against B (both run on the same sequences), per component c of
(dx, dz, dyaw) and per group of steps (every step, or one action's):

* ``diff``: mean over sequences of (A's mean absolute error of c on the group's steps of that
  sequence minus B's), x 1e-2 (m, m, rad), errors *as used* (a failed step scored with the action
  prior that replaced it, as in ``table.csv``). Negative: A's error is lower.
* ``low, high``: its 95 % interval, Student t over the per-sequence differences (a sequence is the
  unit: steps within one are not independent); none with fewer than two sequences.
* ``verdict``: ``lower`` (the whole interval below zero), ``higher`` (above) or ``undecided``.

The pairs a comparison reports by default are each composite row against each of its inputs that
ran too (``denoised(icp)`` against ``icp``): what the composite adds over what it is built on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from odolab.core.stats import mean_ci, verdict
from odolab.core.types import MOTION_ACTIONS
from odolab.odometry.odometer import COMPOSITE, split_odometer_names
from odolab.running.runner import SequenceResult
from odolab.running.summary import COLLIDED_FORWARD, action_groups, step_errors

COMPONENTS = ("dx", "dz", "dyaw")
#: The groups of steps, in the order the rows list them.
GROUPS = ("all", *(a.label for a in MOTION_ACTIONS), COLLIDED_FORWARD)


@dataclass(frozen=True)
class PairedRow:
    """One component's paired difference of ``odometer`` against ``against`` on one group of steps
    (``action``: ``all`` or an action's label); figures x 1e-2 (module docstring)."""

    odometer: str
    against: str
    action: str
    component: str
    diff: float
    low: float
    high: float
    verdict: str
    sequences: int
    steps: int


def default_pairs(names: list[str]) -> list[tuple[str, str]]:
    """(composite, input) for every composite among ``names`` whose inputs are among them too."""
    pairs = []
    for name in names:
        match = COMPOSITE.fullmatch(name)
        if match:
            pairs += [(name, i) for i in split_odometer_names(match["inputs"]) if i in names and i != name]
    return pairs


def _groups(result: SequenceResult) -> list[tuple[str, np.ndarray]]:
    """(label, step mask) of every step, then of each action (:func:`odolab.running.summary.action_groups`)."""
    return [("all", np.ones(len(result.actions), bool)), *action_groups(result.actions, result.collisions)]


def paired_differences(results: list[SequenceResult], pairs: list[tuple[str, str]]) -> list[PairedRow]:
    """The rows of each (odometer, against) pair, per group of steps with at least one step and
    component, on the sequences both ran with ground truth (``ValueError`` where the two saw
    different actions on one sequence: not the same steps)."""
    by_key = {(r.odometer, r.sequence): r for r in results if r.truth is not None}
    rows = []
    for a, b in pairs:
        shared = [s for (o, s) in by_key if o == a and (b, s) in by_key]
        diffs: dict[str, list[np.ndarray]] = {}
        steps: dict[str, int] = {}
        for s in shared:
            ra, rb = by_key[(a, s)], by_key[(b, s)]
            if not np.array_equal(ra.actions, rb.actions):
                raise ValueError(f"paired differences: {a} and {b} saw different steps on {s}")
            ea, eb = step_errors(ra) * 100.0, step_errors(rb) * 100.0
            for label, sel in _groups(ra):
                if sel.any():
                    diffs.setdefault(label, []).append(ea[sel].mean(0) - eb[sel].mean(0))
                    steps[label] = steps.get(label, 0) + int(sel.sum())
        for label in [g for g in GROUPS if g in diffs]:
            d = np.stack(diffs[label])
            for k, component in enumerate(COMPONENTS):
                ci = mean_ci(d[:, k])
                rows.append(
                    PairedRow(a, b, label, component, ci.mean, ci.low, ci.high, verdict(ci), ci.n, steps[label])
                )
    return rows


def paired_verdicts(rows: list[PairedRow]) -> list[str]:
    """One console line per pair, on every step: ``denoised(icp) against icp, paired on 225 steps:
    dx -0.99 (-1.3 to -0.66) lower, ...`` (x 1e-2)."""
    lines: dict[tuple[str, str], list[PairedRow]] = {}
    for r in rows:
        if r.action == "all":
            lines.setdefault((r.odometer, r.against), []).append(r)
    out = []
    for (a, b), mine in lines.items():
        parts = [
            f"{r.component} {r.diff:+.2f}"
            + (f" ({r.low:+.2f} to {r.high:+.2f})" if np.isfinite(r.low) else "")
            + f" {r.verdict}"
            for r in mine
        ]
        out.append(f"{a} against {b}, paired on {mine[0].steps} steps, x 1e-2: " + ", ".join(parts))
    return out
