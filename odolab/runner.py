"""Feed identical frame pairs to every odometer, time each step, and integrate trajectories.

For each sequence and odometer: ``reset(intrinsics)``, then ``step_batch`` on ``batch_size``
consecutive ``(frame[i], frame[i + 1], action[i])`` pairs at a time (``batch_size`` 1, the
default, is one ``step`` per pair). Every odometer gets its own read-only copies of the frames:
one that writes into them fails its own step and cannot change what the next odometer sees.
Non-oracle odometers get frames with ``gt_pose`` removed.

A step is a *failure*, counted under a reason (:data:`FAILURE_REASONS`), when it raises, returns
``valid=False``, or returns a transform that is not a rigid motion: a wrong shape, non-finite
entries, a bottom row other than ``[0, 0, 0, 1]``, a rotation block that is not a rotation
(a reflection or a scaled matrix; tolerance :data:`ROTATION_TOLERANCE`), or a translation longer
than :data:`MAX_STEP_TRANSLATION` m. A ``reset`` that raises fails every step of that sequence.
The runner then substitutes the action prior's mean motion (identity when no action is known),
records the failure, and goes on. The substituted motion is what gets scored and integrated, as
it is what a robot would have used; the odometer's own answers are kept in ``raw`` (covariances
included) for fusion and for scoring raw estimates.

Timing: the wall time of a ``step_batch`` call divided by the number of pairs it answered is each
pair's ``step_seconds``; frame copies and checks are outside the timed region.
"""

from __future__ import annotations

import dataclasses
import time
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from odolab.action_prior import ActionPrior
from odolab.geometry import integrate, invert, planar_to_transform
from odolab.odometer import Odometer
from odolab.threads import odometer_threads
from odolab.types import Action, Estimate, Frame, Sequence

NO_ACTION = -1

#: Longest translation (m) a single step may claim; far beyond any robot or hand-held camera
#: between two frames (0.25 m per PointNav step, ~0.05 m between TUM frames at 30 Hz).
MAX_STEP_TRANSLATION = 100.0
#: Largest entry of ``|R^T R - I|`` and ``|det R - 1|`` accepted for a rotation block.
ROTATION_TOLERANCE = 1e-3

#: Why a step failed, as counted in :attr:`SequenceResult.failure_reasons`.
FAILURE_REASONS = {
    "raised": "step or step_batch raised an exception",
    "reset-raised": "reset(intrinsics) raised, so no step of the sequence was tried",
    "not-valid": "the odometer returned valid=False",
    "bad-shape": "Estimate.transform is not 4x4",
    "non-finite": "the transform has NaN or inf entries",
    "bad-bottom-row": "the transform's bottom row is not [0, 0, 0, 1]",
    "not-a-rotation": "the rotation block is not a rotation (reflection, scale, shear)",
    "absurd-translation": f"the translation is longer than {MAX_STEP_TRANSLATION:g} m",
    "batch-length": "step_batch returned a different number of estimates than pairs",
}


@dataclass(frozen=True, kw_only=True)
class SequenceResult:
    """One odometer on one sequence of N + 1 frames (N steps).

    ``estimates`` (N, 4, 4): the ``T_prev_cur`` used (after fallback); ``truth`` (N, 4, 4) the true
    ones or None; ``poses`` (N + 1, 4, 4) integrated ``T_world_cam``, starting at the true first pose
    (identity without ground truth); ``gt_poses`` likewise or None. ``actions`` (N,) int8 Action
    values, -1 when unknown. ``valid`` (N,) False where the step failed; ``step_seconds`` (N,) wall
    time per step (a batch's time shared equally by its pairs). ``errors``: messages of the first
    few exceptions. ``raw`` (N,): the odometer's own :class:`Estimate` of each step as returned
    (covariance included), None where it raised or never ran. ``failure_reasons``: failed steps
    per reason (keys of :data:`FAILURE_REASONS`).
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
    raw: tuple[Estimate | None, ...] = ()
    failure_reasons: dict[str, int] = field(default_factory=dict)

    @property
    def failures(self) -> int:
        return int((~self.valid).sum())


class RunObserver(Protocol):
    """Progress reporting, kept out of the runner: called as steps finish."""

    def start(self, total_steps: int | None) -> None:
        """``total_steps``: steps summed over odometers and sequences, or None when unknown."""

    def advance(self, odometer: str, steps: int) -> None:
        """``steps`` more steps of ``odometer`` are done; 0 steps: ``odometer`` starts a sequence
        (its time counts from here)."""

    def close(self) -> None:
        """The run ended (also after an exception)."""


def failure_reason(est: Estimate) -> str | None:
    """Why ``est`` cannot be used as a step (a key of :data:`FAILURE_REASONS`), or None if it can."""
    if not bool(est.valid):
        return "not-valid"
    T = np.asarray(est.transform, dtype=np.float64)
    if T.shape != (4, 4):
        return "bad-shape"
    if not np.all(np.isfinite(T)):
        return "non-finite"
    if np.any(np.abs(T[3] - (0.0, 0.0, 0.0, 1.0)) > 1e-9):
        return "bad-bottom-row"
    R = T[:3, :3]
    if np.max(np.abs(R.T @ R - np.eye(3))) > ROTATION_TOLERANCE or abs(np.linalg.det(R) - 1.0) > ROTATION_TOLERANCE:
        return "not-a-rotation"
    t = T[:3, 3]
    if np.max(np.abs(t)) > MAX_STEP_TRANSLATION or np.linalg.norm(t) > MAX_STEP_TRANSLATION:
        return "absurd-translation"
    return None


def _read_only(a: np.ndarray | None) -> np.ndarray | None:
    """A private copy of ``a`` that cannot be written through (``flags.writeable`` False)."""
    if a is None:
        return None
    out = np.array(a, copy=True)
    out.flags.writeable = False
    return out


def guarded_frame(frame: Frame, oracle: bool) -> Frame:
    """The frame as one odometer sees it: read-only private arrays, ``gt_pose`` only for oracles."""
    return dataclasses.replace(
        frame,
        rgb=_read_only(frame.rgb),
        depth=_read_only(frame.depth),
        gt_pose=_read_only(frame.gt_pose) if oracle else None,
    )


def _step_chunks(odometer: Odometer, seq: Sequence, oracle: bool, n: int, stamps: list[float]):
    """``(first index, [(prev, cur, action), ...])`` chunks of ``odometer.batch_size`` pairs;
    appends each frame's timestamp to ``stamps`` as it is read."""
    size = max(1, int(odometer.batch_size))
    prev = guarded_frame(seq[0], oracle)
    stamps.append(prev.timestamp)
    chunk: list[tuple[Frame, Frame, Action | None]] = []
    first = 0
    for i in range(n):
        cur = guarded_frame(seq[i + 1], oracle)
        stamps.append(cur.timestamp)
        chunk.append((prev, cur, seq.action(i)))
        prev = cur
        if len(chunk) == size or i == n - 1:
            yield first, chunk
            first, chunk = i + 1, []


@dataclass
class _StepLog:
    """What one odometer answered on one sequence of ``n`` steps, filled in as it runs."""

    n: int
    max_errors: int = 5
    raw: list = field(default_factory=list)
    reasons: list = field(default_factory=list)
    seconds: np.ndarray = field(default_factory=lambda: np.zeros(0))
    errors: list[str] = field(default_factory=list)
    stamps: list[float] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.raw = [None] * self.n
        self.reasons = ["reset-raised"] * self.n
        self.seconds = np.zeros(self.n)

    def note(self, where: str, exc: Exception) -> None:
        if len(self.errors) < self.max_errors:
            self.errors.append(f"{where}: {type(exc).__name__}: {exc}")

    def answer(self, first: int, count: int, answers: list | None, seconds: float) -> None:
        """Record the answers (None: the call raised) to steps ``first .. first + count - 1``."""
        self.seconds[first : first + count] = seconds / count
        for k, i in enumerate(range(first, first + count)):
            if answers is None:
                self.reasons[i] = "raised"
            elif len(answers) != count:
                self.reasons[i] = "batch-length"
            else:
                self.raw[i] = answers[k]
                try:
                    self.reasons[i] = failure_reason(answers[k])
                except Exception as exc:  # noqa: BLE001 - not an Estimate at all
                    self.note(f"step {i}", exc)
                    self.reasons[i] = "raised"


def _run_steps(
    odometer: Odometer, name: str, seq: Sequence, oracle: bool, log: _StepLog, observer: RunObserver | None
) -> None:
    """Ask the odometer about every pair, one ``step_batch`` call per chunk, timed."""
    for first, chunk in _step_chunks(odometer, seq, oracle, log.n, log.stamps):
        t0 = time.perf_counter()
        try:
            answers = list(odometer.step_batch(chunk))
        except (Exception, SystemExit) as exc:  # noqa: BLE001 - a bug (even sys.exit) must not end the comparison
            answers = None
            log.note(f"step {first}" if len(chunk) == 1 else f"steps {first}-{first + len(chunk) - 1}", exc)
        log.answer(first, len(chunk), answers, time.perf_counter() - t0)
        if observer is not None:
            observer.advance(name, len(chunk))


def run_sequence(
    odometer: Odometer,
    seq: Sequence,
    name: str,
    prior: ActionPrior,
    observer: RunObserver | None = None,
    max_errors: int = 5,
) -> SequenceResult:
    """Run one odometer over one sequence (see the module docstring for failure handling)."""
    n = len(seq) - 1
    log = _StepLog(n, max_errors)
    actions = np.array([NO_ACTION if a is None else a.value for a in (seq.action(i) for i in range(n))], np.int8)
    oracle = bool(odometer.oracle)
    with odometer_threads(odometer):
        if observer is not None:
            observer.advance(name, 0)
        try:
            odometer.reset(seq.intrinsics)
        except (Exception, SystemExit) as exc:  # noqa: BLE001 - a broken odometer fails this sequence, not the comparison
            log.note("reset", exc)
            if observer is not None:
                observer.advance(name, n)
        else:
            _run_steps(odometer, name, seq, oracle, log, observer)
    stamps = log.stamps or [seq[i].timestamp for i in range(n + 1)]

    valid = np.array([r is None for r in log.reasons], dtype=bool)
    estimates = np.empty((n, 4, 4))
    for i in range(n):
        action = None if actions[i] == NO_ACTION else Action(int(actions[i]))
        estimates[i] = (
            np.asarray(log.raw[i].transform, np.float64) if valid[i] else planar_to_transform(*prior.motion(action))
        )
    gt = [seq.gt_pose(i) for i in range(n + 1)]
    has_gt = all(g is not None for g in gt)
    gt_poses = np.stack(gt).astype(np.float64) if has_gt else None
    truth = invert(gt_poses[:-1]) @ gt_poses[1:] if has_gt else None
    poses = integrate(estimates, start=gt_poses[0] if has_gt else None)
    collisions = seq.collisions
    return SequenceResult(
        odometer=name,
        sequence=seq.name,
        oracle=oracle,
        estimates=estimates,
        truth=truth,
        poses=poses,
        gt_poses=gt_poses,
        actions=actions,
        valid=valid,
        step_seconds=log.seconds,
        collisions=None if collisions is None else np.asarray(collisions),
        timestamps=np.array(stamps),
        errors=log.errors,
        raw=tuple(log.raw),
        failure_reasons=dict(Counter(r for r in log.reasons if r is not None)),
    )


def run(
    odometers: dict[str, Odometer],
    sequences: Iterable[Sequence],
    prior: ActionPrior | None = None,
    observer: RunObserver | None = None,
    total_steps: int | None = None,
) -> list[SequenceResult]:
    """Every odometer on every sequence, one sequence at a time (so ``sequences`` may be a stream
    that holds one episode in memory). ``observer`` hears of progress; ``total_steps`` (steps per
    odometer, summed over sequences) tells it the total when ``sequences`` has no length."""
    prior = prior or ActionPrior.shipped()
    if total_steps is None and hasattr(sequences, "__len__"):
        total_steps = sum(len(s) - 1 for s in sequences)
    results = []
    if observer is not None:
        observer.start(None if total_steps is None else len(odometers) * total_steps)
    try:
        for seq in sequences:
            for name, odo in odometers.items():
                results.append(run_sequence(odo, seq, name, prior, observer))
    finally:
        if observer is not None:
            observer.close()
    return results
