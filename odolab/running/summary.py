"""Turn runner results into the comparison tables (one row per odometer), and format any table.

Definitions (each metric's formula lives in :mod:`odolab.core.metrics`):

* ``dx, dz, dyaw``: the paper's per-step error *as used*: mean absolute error over all steps of
  all sequences pooled, x 1e-2 (m, m, rad), where a failed step is scored with the action prior's
  motion that replaced it (what a robot would have used); ``*_std``: standard deviation of the
  per-sequence means.
* ``dx_own, dz_own, dyaw_own``: the same error on the steps the odometer answered itself (failed
  steps left out); read it together with ``failure_share``.
* ``dx_raw, dz_raw, dyaw_raw``: the paper's protocol: the same error over every step with the
  odometer's own motion, the unverified one where it refused a step (``Estimate.unverified``);
  ``raw_missing``: steps with no motion of its own at all (it raised, answered no rigid motion or
  refused with nothing computed), scored with the action prior's motion and counted here.
* ``dx_bias, dz_bias, dyaw_bias``: the signed mean error per step as used (estimate minus truth,
  x 1e-2): a bias, which integrates into drift where an absolute error of the same size may cancel.
* ``failure_share``: share of steps that raised or returned ``valid=False``; ``failures``: their
  number (the action prior was used instead).
* ``fps``: steps per second of the odometer's ``step`` calls alone (steps asked / their total time;
  steps never asked, after a failed ``reset``, are left out); not applicable (NaN, shown as -) for
  the reference rows, which only look numbers up, and for an odometer never asked a step.
* ``ate_m``: mean over sequences of the ATE RMSE (m) with *no* alignment: every trajectory starts
  at the true first pose, so this is the drift a robot would suffer (``python -m odolab.evaluate``
  aligns by default, SE(3) as ``evo_ape -a``; pass ``--align none`` to get these figures).
  ``drift_m``: mean final position error (m). ``*_std``: standard deviation over sequences.
* ``trans_mm`` / ``rot_deg``: mean per-frame relative pose error, as used (real data);
  ``trans_mm_own`` / ``rot_deg_own``: the same on the answered steps.

Reference rows (``ground-truth``, ``action-prior``) come first, then the odometers in the order
they were given. Sequences of one frame (zero steps) give NaN figures (shown as -), not an error.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from odolab.core.geometry import transform_to_planar
from odolab.core.metrics import ate, per_step_abs_error, per_step_signed_error, relative_motion_errors
from odolab.core.types import MOTION_ACTIONS, Action, Estimate
from odolab.running.runner import SequenceResult, failure_reason

#: Rows that bracket every real odometer: zero error (an oracle) and the paper's ``sys_error``.
REFERENCE_ODOMETERS = ("action-prior", "ground-truth")


@dataclass(frozen=True)
class Row:
    """One odometer's line of the comparison table (see the module docstring for definitions)."""

    odometer: str
    oracle: bool
    reference: bool
    dx: float
    dz: float
    dyaw: float
    dx_std: float
    dz_std: float
    dyaw_std: float
    dx_own: float
    dz_own: float
    dyaw_own: float
    dx_raw: float
    dz_raw: float
    dyaw_raw: float
    raw_missing: int
    dx_bias: float
    dz_bias: float
    dyaw_bias: float
    trans_mm: float
    rot_deg: float
    trans_mm_own: float
    rot_deg_own: float
    ate_m: float
    ate_std: float
    drift_m: float
    drift_std: float
    fps: float
    failures: int
    failure_share: float
    steps: int
    sequences: int


@dataclass(frozen=True)
class ActionRow:
    """Per-step error (x 1e-2) of one odometer for one action, as used and on the answered steps
    (``*_own``, NaN when every step failed), its failed steps, its signed mean error as used
    (``*_bias``) and its error under the paper's protocol (``*_raw``, ``raw_missing``)."""

    odometer: str
    action: str
    dx: float
    dz: float
    dyaw: float
    dx_own: float
    dz_own: float
    dyaw_own: float
    steps: int
    failures: int
    dx_bias: float
    dz_bias: float
    dyaw_bias: float
    dx_raw: float
    dz_raw: float
    dyaw_raw: float
    raw_missing: int


def _planar(T: np.ndarray) -> np.ndarray:
    return np.stack([transform_to_planar(t) for t in T]) if len(T) else np.zeros((0, 3))


def step_errors(r: SequenceResult) -> np.ndarray:
    """(N, 3) absolute planar errors (m, m, rad) of a result with ground truth."""
    return per_step_abs_error(_planar(r.estimates), _planar(r.truth))


def raw_estimates(r: SequenceResult) -> tuple[np.ndarray, np.ndarray]:
    """The paper's protocol: (N, 4, 4) ``T_prev_cur`` of every step as the odometer computed it (its
    answer, or the unverified motion of a step it refused: ``Estimate.unverified``) and (N,) bool,
    True where it has none (it raised, answered no rigid motion or refused with nothing computed;
    such a step keeps the action prior's motion it was run with)."""
    out, missing = np.array(r.estimates, np.float64, copy=True), ~np.asarray(r.valid, bool)
    for i in np.flatnonzero(missing):
        mine = _unverified(r.raw[i] if i < len(r.raw) else None)
        if mine is not None:
            out[i], missing[i] = mine, False
    return out, missing


def _raw_errors(results: list[SequenceResult]) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) absolute planar errors x 1e-2 under the paper's protocol (:func:`raw_estimates`) of the
    steps of ``results`` pooled, and (N,) bool: the steps with no motion of the odometer's own."""
    raws = [raw_estimates(r) for r in results]
    errs = [per_step_abs_error(_planar(T), _planar(r.truth)) for (T, _), r in zip(raws, results)]
    return np.concatenate(errs) * 100.0, np.concatenate([m for _, m in raws])


def _unverified(answer: object) -> np.ndarray | None:
    """The refused motion ``answer.unverified`` as a float 4x4 when it is a rigid motion the runner
    would accept as an answer; None otherwise (a plug-in may put anything there, even an array-like
    whose conversion raises: no complex, object or bool arrays, no other shape)."""
    try:
        mine = np.asarray(getattr(answer, "unverified", None))
        if mine.dtype.kind not in "iuf" or mine.shape != (4, 4):
            return None
        mine = mine.astype(np.float64)
    except Exception:  # noqa: BLE001 - whatever it raised, the step has no motion of its own
        return None
    return mine if failure_reason(Estimate(mine)) is None else None


def step_signed_errors(r: SequenceResult) -> np.ndarray:
    """(N, 3) signed planar errors (m, m, rad; estimate minus truth) of a result with ground truth."""
    return per_step_signed_error(_planar(r.estimates), _planar(r.truth))


def by_odometer(results: list[SequenceResult]) -> dict[str, list[SequenceResult]]:
    """Results with ground truth grouped by odometer: reference rows first, then first-seen order."""
    groups: dict[str, list[SequenceResult]] = {}
    for r in results:
        if r.truth is not None:
            groups.setdefault(r.odometer, []).append(r)
    order = sorted(groups, key=lambda n: n not in REFERENCE_ODOMETERS)  # stable: given order kept
    return {n: groups[n] for n in order}


def _mean(x: np.ndarray) -> float:
    """The mean of ``x``, NaN when it is empty."""
    return float(x.mean()) if len(x) else float("nan")


def _std(x: np.ndarray) -> float:
    """The (population) standard deviation of ``x``, NaN when it is empty."""
    return float(x.std()) if len(x) else float("nan")


def _asked(r: SequenceResult) -> int:
    """Steps of ``r`` its odometer was asked (every step when the runner did not record it)."""
    return len(r.valid) if r.asked is None else int(np.count_nonzero(r.asked))


def summarize(results: list[SequenceResult]) -> list[Row]:
    """One :class:`Row` per odometer (reference rows first). Needs ground truth."""
    rows = []
    for name, mine in by_odometer(results).items():
        errs = [step_errors(r) for r in mine]
        pooled = np.concatenate(errs) * 100.0
        raw, raw_missing = _raw_errors(mine)
        signed = np.concatenate([step_signed_errors(r) for r in mine]) * 100.0
        valid = np.concatenate([r.valid for r in mine])
        per_seq = np.array([e.mean(axis=0) for e in errs if len(e)]).reshape(-1, 3) * 100.0
        rel = [relative_motion_errors(r.gt_poses, r.poses) for r in mine]
        trans = np.concatenate([t for t, _ in rel]) * 1e3
        rot = np.concatenate([a for _, a in rel])
        ates = np.array([ate(r.gt_poses, r.poses).rmse for r in mine])
        drifts = np.array([np.linalg.norm(r.poses[-1, :3, 3] - r.gt_poses[-1, :3, 3]) for r in mine])
        seconds = sum(float(r.step_seconds.sum()) for r in mine)
        asked = sum(_asked(r) for r in mine)
        steps = len(pooled)
        reference = name in REFERENCE_ODOMETERS
        rows.append(
            Row(
                odometer=name,
                oracle=mine[0].oracle,
                reference=reference,
                dx=_mean(pooled[:, 0]),
                dz=_mean(pooled[:, 1]),
                dyaw=_mean(pooled[:, 2]),
                dx_std=_std(per_seq[:, 0]),
                dz_std=_std(per_seq[:, 1]),
                dyaw_std=_std(per_seq[:, 2]),
                dx_own=_mean(pooled[valid, 0]),
                dz_own=_mean(pooled[valid, 1]),
                dyaw_own=_mean(pooled[valid, 2]),
                dx_raw=_mean(raw[:, 0]),
                dz_raw=_mean(raw[:, 1]),
                dyaw_raw=_mean(raw[:, 2]),
                raw_missing=int(raw_missing.sum()),
                dx_bias=_mean(signed[:, 0]),
                dz_bias=_mean(signed[:, 1]),
                dyaw_bias=_mean(signed[:, 2]),
                trans_mm=_mean(trans),
                rot_deg=_mean(rot),
                trans_mm_own=_mean(trans[valid]),
                rot_deg_own=_mean(rot[valid]),
                ate_m=float(ates.mean()),
                ate_std=float(ates.std()),
                drift_m=float(drifts.mean()),
                drift_std=float(drifts.std()),
                fps=asked / seconds if asked and seconds > 0 and not reference else float("nan"),
                failures=int((~valid).sum()),
                failure_share=float((~valid).mean()) if steps else 0.0,
                steps=steps,
                sequences=len(mine),
            )
        )
    return rows


#: The label of the extra per-action row: the forward steps that collided (the simulator's flag: the
#: agent stopped at contact, short of the commanded step; a subset of the move_forward row).
COLLIDED_FORWARD = "move_forward_collided"


def action_groups(actions: np.ndarray, collisions: np.ndarray | None) -> list[tuple[str, np.ndarray]]:
    """(label, step mask) of each motion action's steps, and of the forward steps that collided
    (:data:`COLLIDED_FORWARD`) when ``collisions`` is known."""
    acts = np.asarray(actions)
    groups = [(a.label, acts == a.value) for a in MOTION_ACTIONS]
    if collisions is not None:
        groups.append((COLLIDED_FORWARD, (acts == Action.MOVE_FORWARD.value) & np.asarray(collisions, bool)))
    return groups


def summarize_actions(results: list[SequenceResult]) -> list[ActionRow]:
    """Per-step error (x 1e-2) per odometer and motion action (reference rows first); when every
    result knows its collisions and some forward step collided, also a row ``COLLIDED_FORWARD`` of
    just those steps (a subset of the move_forward row: how an odometer sees a step that did not go
    as commanded)."""
    rows = []
    for name, mine in by_odometer(results).items():
        errs = np.concatenate([step_errors(r) for r in mine]) * 100.0
        signed = np.concatenate([step_signed_errors(r) for r in mine]) * 100.0
        raw, raw_missing = _raw_errors(mine)
        acts = np.concatenate([r.actions for r in mine])
        valid = np.concatenate([r.valid for r in mine])
        known = all(r.collisions is not None for r in mine)
        collided = np.concatenate([np.asarray(r.collisions, bool) for r in mine]) if known else None
        for label, sel in action_groups(acts, collided):
            if sel.any():
                e, own = errs[sel], errs[sel & valid]
                rows.append(
                    ActionRow(
                        name,
                        label,
                        *(_mean(e[:, k]) for k in range(3)),
                        *(_mean(own[:, k]) for k in range(3)),
                        int(sel.sum()),
                        int((~valid[sel]).sum()),
                        *(_mean(signed[sel, k]) for k in range(3)),
                        *(_mean(raw[sel, k]) for k in range(3)),
                        int(raw_missing[sel].sum()),
                    )
                )
    return rows


def failed_steps_text(failed: int, steps: float) -> str:
    """How many of ``steps`` steps failed, for a console line: ``"failed steps 3 of 40 (7.5 %)"``,
    ``"failed steps: every one of 40"`` or ``"no failed steps"``."""
    total = int(round(steps)) if np.isfinite(steps) else 0
    if not failed:
        return "no failed steps"
    if total and failed >= total:
        return f"failed steps: every one of {total}"
    share = f" ({100 * failed / total:.1f} %)" if total else ""
    return f"failed steps {failed} of {total}{share}" if total else f"failed steps {failed}"


def every_step_failed(rows: Sequence[Row]) -> list[str]:
    """One console line per row whose every step failed: its figures are the action prior's."""
    return [
        f"{r.odometer}: {failed_steps_text(r.failures, r.steps)}; its figures are the action prior's, "
        "which stood in for each"
        for r in rows
        if r.steps and r.failures >= r.steps
    ]


#: Magnitude from which :func:`fmt` writes a number in e-notation (no figure here comes near it:
#: a fixed-point 1e300 would be a 300-digit cell).
HUGE = 1e9


def fmt(value: float, spec: str, std: float | None = None) -> str:
    """``value`` formatted by ``spec``, ``"-"`` when it is None or NaN (does not apply), ``"inf"`` /
    ``"-inf"`` when it overflowed, in e-notation (``"1e+300"``) when its magnitude is at least
    :data:`HUGE`, and `` +- std`` when ``std`` is given and finite."""
    if value is None or np.isnan(value):
        return "-"
    if not np.isfinite(value):
        return str(float(value))
    text = _number(value, spec)
    return text if std is None or not np.isfinite(std) else f"{text} +- {_number(std, spec)}"


def _number(value: float, spec: str) -> str:
    """Finite ``value`` by ``spec``, or in e-notation (4 significant digits) from :data:`HUGE` on."""
    return format(value, ".4g") if abs(value) >= HUGE else format(value, spec)


def text_table(header: Sequence[str], rows: Sequence[Sequence[str]], markdown: bool = False) -> str:
    """The one table formatter of odolab: cells are strings; the first column is left-aligned,
    the others right-aligned. ``markdown`` gives a ``| a | b |`` table, else fixed-width text with
    a dashed rule under the header."""
    if markdown:
        lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows])
    widths = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]

    def line(cells: Sequence[str]) -> str:
        return "  ".join(
            str(c).ljust(w) if i == 0 else str(c).rjust(w) for i, (c, w) in enumerate(zip(cells, widths))
        ).rstrip()

    head = line(header)
    return "\n".join([head, "-" * len(head), *(line(r) for r in rows)])
