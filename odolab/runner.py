"""Feed identical frame pairs to every odometer, time each ``step``, and integrate trajectories.

For each sequence and odometer: ``reset(intrinsics)``, then ``step(frame[i], frame[i + 1],
action[i])`` for every consecutive pair. Non-oracle odometers get frames with ``gt_pose`` removed.
A step that raises or returns ``valid=False`` is a *failure*: the runner substitutes the action
prior's mean motion (identity when no action is known), records the failure, and goes on. The
substituted motion is what gets scored and integrated, as it is what a robot would have used.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Iterable

import numpy as np
from tqdm.auto import tqdm

from odolab.action_prior import ActionPrior
from odolab.geometry import integrate, invert, planar_to_transform
from odolab.odometer import Odometer, Sequence

NO_ACTION = -1


@dataclass(frozen=True)
class SequenceResult:
    """One odometer on one sequence of N + 1 frames (N steps).

    ``estimates`` (N, 4, 4): the ``T_prev_cur`` used (after fallback); ``truth`` (N, 4, 4) the true
    ones or None; ``poses`` (N + 1, 4, 4) integrated ``T_world_cam``, starting at the true first pose
    (identity without ground truth); ``gt_poses`` likewise or None. ``actions`` (N,) int8 Action
    values, -1 when unknown. ``valid`` (N,) False where the step failed; ``step_seconds`` (N,) wall
    time of each ``step`` call. ``errors``: messages of the first few exceptions.
    """

    odometer: str
    sequence: str
    oracle: bool
    estimates: np.ndarray
    truth: np.ndarray | None
    poses: np.ndarray
    gt_poses: np.ndarray | None
    actions: np.ndarray
    valid: np.ndarray
    step_seconds: np.ndarray
    collisions: np.ndarray | None = None
    timestamps: np.ndarray | None = None  # (N + 1,) seconds
    errors: list[str] = field(default_factory=list)

    @property
    def failures(self) -> int:
        return int((~self.valid).sum())


def run_sequence(odometer: Odometer, seq: Sequence, name: str, prior: ActionPrior,
                 progress: tqdm | None = None, max_errors: int = 5) -> SequenceResult:
    """Run one odometer over one sequence (see the module docstring for failure handling)."""
    n = len(seq) - 1
    odometer.reset(seq.intrinsics)
    estimates = np.empty((n, 4, 4))
    valid = np.ones(n, dtype=bool)
    seconds = np.empty(n)
    actions = np.full(n, NO_ACTION, dtype=np.int8)
    errors: list[str] = []
    oracle = bool(getattr(odometer, "oracle", False))
    frames = (seq[i] if oracle else dataclasses.replace(seq[i], gt_pose=None) for i in range(n + 1))
    prev = next(frames)
    stamps = [prev.timestamp]
    for i, cur in enumerate(frames):
        stamps.append(cur.timestamp)
        action = seq.action(i)
        if action is not None:
            actions[i] = action.value
        t0 = time.perf_counter()
        try:
            est = odometer.step(prev, cur, action)
            T = np.asarray(est.transform, dtype=np.float64)
            if T.shape != (4, 4):
                raise ValueError(f"Estimate.transform has shape {T.shape}; expected (4, 4)")
            ok = bool(est.valid) and bool(np.all(np.isfinite(T)))
        except Exception as exc:  # an odometer's bug must not end the comparison
            ok = False
            if len(errors) < max_errors:
                errors.append(f"step {i}: {type(exc).__name__}: {exc}")
        seconds[i] = time.perf_counter() - t0
        estimates[i] = T if ok else planar_to_transform(*prior.motion(action))
        valid[i] = ok
        prev = cur
        if progress is not None:
            progress.update(1)

    gt = [seq.gt_pose(i) for i in range(n + 1)]
    has_gt = all(g is not None for g in gt)
    gt_poses = np.stack(gt) if has_gt else None
    truth = invert(gt_poses[:-1]) @ gt_poses[1:] if has_gt else None
    poses = integrate(estimates, start=gt_poses[0] if has_gt else None)
    collisions = getattr(seq, "collisions", None)
    return SequenceResult(name, getattr(seq, "name", "sequence"), oracle, estimates, truth, poses, gt_poses,
                          actions, valid, seconds, None if collisions is None else np.asarray(collisions),
                          np.array(stamps), errors)


def run(odometers: dict[str, Odometer], sequences: Iterable[Sequence], prior: ActionPrior | None = None,
        progress: bool = True, total_steps: int | None = None) -> list[SequenceResult]:
    """Every odometer on every sequence, one sequence at a time (so ``sequences`` may be a stream
    that holds one episode in memory), with one progress bar over steps. ``total_steps`` (steps
    per odometer, summed over sequences) sizes the bar when ``sequences`` has no length."""
    prior = prior or ActionPrior.shipped()
    if total_steps is None and hasattr(sequences, "__len__"):
        total_steps = sum(len(s) - 1 for s in sequences)
    total = None if total_steps is None else len(odometers) * total_steps
    results = []
    with tqdm(total=total, desc="odometry steps", unit="step", disable=not progress) as bar:
        for seq in sequences:
            for name, odo in odometers.items():
                bar.set_postfix_str(name)
                results.append(run_sequence(odo, seq, name, prior, bar))
    return results
