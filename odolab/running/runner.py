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

What a step returns is copied at the step (transform and covariance), so an odometer that reuses
one output array, or changes an answer afterwards, cannot change what was recorded.

Attributes the runner reads (``oracle``, ``batch_size``, ``threads``) are read once per sequence
inside a guard: one that raises or holds an unusable value (``batch_size = nan``) fails every step
of that sequence (``bad-attribute``), with one line naming it in ``errors``.

Time limit: with ``step_timeout`` (s, :data:`DEFAULT_STEP_TIMEOUT` unless told otherwise) the
odometer's ``reset`` and ``step_batch`` calls run in a worker thread (a daemon) and the runner waits
at most ``step_timeout`` per pair; a call past it fails its steps (``timed-out``). Python cannot stop
a thread, so the call is abandoned, not killed: it may go on in the background until it returns
(or the process ends), and the next call gets a fresh worker. After
:data:`MAX_TIMEOUTS` timed-out calls (in all, not only in a row) the odometer is stopped for the rest of the
sequence (its remaining steps fail as ``timed-out`` without being asked). ``reset`` and the steps of
one sequence share one thread, so thread-local state an odometer sets in ``reset`` holds in its
steps. A ``step_batch`` that yields without end is read for at most one item more than it was given
pairs (``batch-length``). Answers are copied as they are read, so a generator may reuse one array;
answers of a returned list that share one transform array fail (``shared-array``: by the time the
list returns they all hold the last pair's motion). ``step_timeout=None`` runs every call in the
calling thread, unlimited.

Timing: the wall time of a ``step_batch`` call divided by the number of pairs it answered is each
pair's ``step_seconds``, measured in the thread that makes the call; frame copies, answer copies
and checks are outside the timed region. A timed-out call counts the time waited.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any, Protocol, Self

import numpy as np

from odolab.core.geometry import integrate, invert, planar_to_transform
from odolab.core.types import Action, Estimate, Frame, Sequence
from odolab.odometry.action_prior import ActionPrior
from odolab.odometry.odometer import Odometer, own_copy
from odolab.running.threads import MAX_THREADS, torch_threads

NO_ACTION = -1

#: Longest translation (m) a single step may claim; far beyond any robot or hand-held camera
#: between two frames (0.25 m per PointNav step, ~0.05 m between TUM frames at 30 Hz).
MAX_STEP_TRANSLATION = 100.0
#: Largest entry of ``|R^T R - I|`` and ``|det R - 1|`` accepted for a rotation block.
ROTATION_TOLERANCE = 1e-3
#: Seconds one step (one pair; a batch gets this per pair) may take before it counts as failed
#: (``timed-out``): generous, as the slowest odometer here takes well under a second per step.
DEFAULT_STEP_TIMEOUT = 60.0
#: Timed-out calls after which an odometer is stopped for the rest of its sequence (in all: one that
#: hangs on every other step is stopped too, so a sequence waits at most this many time limits).
MAX_TIMEOUTS = 3
#: The largest ``batch_size`` an odometer may declare (far above any sequence here).
MAX_BATCH_SIZE = 1_000_000
#: The :class:`Frame` fields only oracle odometers see (removed for the others, :func:`guarded_frame`).
ORACLE_ONLY_FIELDS = ("gt_pose", "clean_depth")

#: Why a step failed, as counted in :attr:`SequenceResult.failure_reasons`.
FAILURE_REASONS = {
    "raised": "step or step_batch raised an exception",
    "reset-raised": "reset(intrinsics) raised, so no step of the sequence was tried",
    "bad-attribute": "an attribute the runner reads (oracle, batch_size, threads) raised or is unusable",
    "timed-out": "the step took longer than the step time limit, or its odometer was stopped after timing out",
    "not-valid": "the odometer returned valid=False",
    "bad-shape": "Estimate.transform is not 4x4",
    "non-finite": "the transform has NaN or inf entries",
    "bad-bottom-row": "the transform's bottom row is not [0, 0, 0, 1]",
    "not-a-rotation": "the rotation block is not a rotation (reflection, scale, shear)",
    "absurd-translation": f"the translation is longer than {MAX_STEP_TRANSLATION:g} m",
    "batch-length": "step_batch returned (or kept yielding) a different number of estimates than pairs",
    "shared-array": "step_batch answered several pairs with one transform array (each answer must own its own)",
}


@dataclass(frozen=True, kw_only=True)
class SequenceResult:
    """One odometer on one sequence of N + 1 frames (N steps).

    ``estimates`` (N, 4, 4): the ``T_prev_cur`` used (after fallback); ``truth`` (N, 4, 4) the true
    ones or None; ``poses`` (N + 1, 4, 4) integrated ``T_world_cam``, starting at the true first pose
    (identity without ground truth); ``gt_poses`` likewise or None. ``actions`` (N,) int8 Action
    values, -1 when unknown. ``valid`` (N,) False where the step failed; ``step_seconds`` (N,) wall
    time per step (a batch's time shared equally by its pairs; 0 for a step never asked). ``asked``
    (N,) bool: the odometer was asked for the step (False after a failed reset, a bad attribute or
    being stopped; None: not recorded, every step counts as asked). ``errors``: messages of the
    first few exceptions. ``raw`` (N,): a copy of the odometer's own :class:`Estimate` of each step
    (covariance included), None where it raised or never ran. ``failure_reasons``: failed steps per
    reason (keys of :data:`FAILURE_REASONS`). ``empty_depth``: frames read whose every depth pixel
    is 0 (no reading at all).
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
    asked: np.ndarray | None = None
    empty_depth: int = 0

    @property
    def failures(self) -> int:
        return int((~self.valid).sum())


class RunObserver(Protocol):
    """Progress reporting, kept out of the runner: called as steps finish."""

    def start(self, total_steps: int | None) -> None:
        """``total_steps``: steps summed over odometers and sequences, or None when unknown."""

    def advance(self, odometer: str, steps: int, seconds: float | None = None) -> None:
        """``steps`` more steps of ``odometer`` are done; 0 steps: ``odometer`` starts a sequence
        (its time counts from here). ``seconds``: the steps' own time, where they ran elsewhere
        (in a Ray task) and the time since the last call is not theirs."""

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


def _oracle_fields(frame: Frame, oracle: bool) -> dict[str, np.ndarray | None]:
    """The oracle-only fields of ``frame`` (:data:`ORACLE_ONLY_FIELDS`) as one odometer gets them:
    read-only copies for an oracle, None (removed) for any other."""
    return {name: _read_only(getattr(frame, name)) if oracle else None for name in ORACLE_ONLY_FIELDS}


def guarded_frame(frame: Frame, oracle: bool) -> Frame:
    """The frame as one odometer sees it: read-only private arrays, ground truth only for oracles."""
    return dataclasses.replace(
        frame, rgb=_read_only(frame.rgb), depth=_read_only(frame.depth), **_oracle_fields(frame, oracle)
    )


def has_no_depth(frame: Frame) -> bool:
    """Whether every depth pixel of ``frame`` is 0 (no reading anywhere in the image)."""
    return not np.any(frame.depth)


@dataclass(frozen=True)
class Attributes:
    """What the runner reads from an odometer, checked: ``oracle``, ``batch_size`` (pairs per
    ``step_batch`` call) and ``threads`` (torch threads, or None)."""

    oracle: bool
    batch_size: int
    threads: int | None


class AttributeProblem(ValueError):
    """An odometer attribute the runner reads raised or holds a value it cannot use; the message is
    one line naming the attribute, what was expected and what was got."""


def _attribute(odometer: Odometer, name: str) -> Any:
    """``odometer.<name>``; :class:`AttributeProblem` when reading it raises."""
    try:
        return getattr(odometer, name)
    except KeyboardInterrupt:
        raise
    except BaseException as exc:  # noqa: BLE001 - a property of a plug-in may raise anything, sys.exit too
        raise AttributeProblem(f"reading {name} raised {type(exc).__name__}: {_text(exc)}") from None


def _text(exc: BaseException) -> str:
    """An exception's message; a placeholder where its ``__str__`` itself raises."""
    try:
        return str(exc)
    except Exception:  # noqa: BLE001 - a plug-in's exception class may be broken
        return "(its message could not be read)"


def _whole(name: str, value: Any, lo: int, hi: int) -> int:
    """``value`` as an int in [lo, hi] (an integral float such as 4.0 too); :class:`AttributeProblem` otherwise."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise AttributeProblem(f"{name} must be a whole number in [{lo}, {hi}], got {value!r}")
    if not (math.isfinite(value) and float(value).is_integer() and lo <= value <= hi):
        raise AttributeProblem(f"{name} must be a whole number in [{lo}, {hi}], got {value!r}")
    return int(value)


def read_attributes(odometer: Odometer) -> Attributes:
    """``oracle`` (a bool, or 0 / 1), ``batch_size`` (a whole number >= 1) and ``threads`` (None or a
    whole number in [1, MAX_THREADS]) of ``odometer``, each read once; :class:`AttributeProblem`."""
    oracle = _attribute(odometer, "oracle")
    if not isinstance(oracle, (bool, np.bool_)) and not (isinstance(oracle, (int, np.integer)) and oracle in (0, 1)):
        raise AttributeProblem(f"oracle must be True or False, got {oracle!r}")
    threads = _attribute(odometer, "threads")
    return Attributes(
        oracle=bool(oracle),
        batch_size=_whole("batch_size", _attribute(odometer, "batch_size"), 1, MAX_BATCH_SIZE),
        threads=None if threads is None else _whole("threads", threads, 1, MAX_THREADS),
    )


@dataclass
class _Call:
    """One call made for the runner: its result or exception and its wall time (s)."""

    fn: Callable[[], Any] | None
    done: threading.Event = field(default_factory=threading.Event)
    value: Any = None
    error: BaseException | None = None
    seconds: float = 0.0

    def make(self) -> None:
        """Run ``fn`` once, timed, keeping its value or the exception it raised. ``fn`` is let go
        before the caller hears, so what it holds (an odometer and its tensors) is freed by the
        caller's thread, never by a worker thread that may still be running when the interpreter
        exits (torch aborts the process when it frees tensors there)."""
        fn, self.fn = self.fn, None
        t0 = time.perf_counter()
        try:
            self.value = fn()  # type: ignore[misc]
        except BaseException as exc:  # noqa: BLE001 - handed to the runner's thread, which decides
            self.error = exc
        del fn
        self.seconds = time.perf_counter() - t0
        self.done.set()


#: The name of every runner worker thread begins so (:func:`calls_still_running`).
_WORKER_NAME = "odolab runner: "


def calls_still_running() -> bool:
    """Whether a worker thread still runs an odometer call the runner stopped waiting for (past its
    time limit). Letting the interpreter exit then can abort the process: a torch call that returns
    into a finalising interpreter ends its thread by unwinding through C++ that may not be unwound.
    A command leaves with ``os._exit`` instead (:func:`odolab.cli.args.exit_process`)."""
    return any(t.name.startswith(_WORKER_NAME) and t.is_alive() for t in threading.enumerate())


class _Worker:
    """A daemon thread that makes the calls it is handed, one at a time, until :meth:`close`."""

    def __init__(self, name: str) -> None:
        self._calls: queue.SimpleQueue[_Call | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._serve, name=f"{_WORKER_NAME}{name}", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while (call := self._calls.get()) is not None:
            call.make()
            del call  # not held while waiting for the next: the caller's thread frees it

    def submit(self, call: _Call) -> None:
        self._calls.put(call)

    def close(self) -> None:
        """Let the thread end once its current call (if any) returns."""
        self._calls.put(None)


class _Caller:
    """Makes an odometer's calls with a time limit (see the module docstring): in a worker thread
    when ``timeout`` (s per pair) is set, replaced after a call it stopped waiting for; else in the
    calling thread. :meth:`close` lets the worker go."""

    def __init__(self, name: str, timeout: float | None) -> None:
        self.name, self.timeout = name, timeout
        self._worker: _Worker | None = None

    def close(self) -> None:
        """Let the worker thread end (once its current call, if any, returns)."""
        if self._worker is not None:
            self._worker.close()
            self._worker = None

    def call(self, fn: Callable[[], Any], pairs: int = 1) -> _Call | None:
        """``fn`` made and timed; None when it ran past ``timeout * pairs`` s (abandoned). A
        ``KeyboardInterrupt`` is raised here; any other exception (``SystemExit`` and
        ``GeneratorExit`` included) is the call's error. A call stuck in C code that holds the
        interpreter lock is only abandoned once it lets go of it."""
        call = _Call(fn)
        if self.timeout is None:
            call.make()
        else:
            if self._worker is None:
                self._worker = _Worker(self.name)
            self._worker.submit(call)
            if not call.done.wait(self.timeout * pairs):
                self._worker.close()  # still busy with the call; it ends when (if) the call returns
                self._worker = None
                return None
        if isinstance(call.error, KeyboardInterrupt):
            raise call.error
        return call


#: What :func:`_ask` puts in place of an answer whose transform array another answer of its batch shares.
SHARED = object()


def _ask(odometer: Odometer, chunk: list) -> list:
    """``odometer.step_batch(chunk)`` read into a list, at most one item more than ``chunk`` has
    pairs (a ``step_batch`` that yields without end is not read to its end). Each answer is copied
    as it is read, so a generator may reuse one array; in a returned list or tuple, answers that
    share one transform array are :data:`SHARED` (by then they hold only the last pair's motion)."""
    answers = odometer.step_batch(chunk)
    if isinstance(answers, (list, tuple)):
        items = list(answers[: len(chunk) + 1])
        shared = _sharing(items)
        return [SHARED if k in shared else own_copy(a) for k, a in enumerate(items)]
    return [own_copy(a) for a in itertools.islice(answers, len(chunk) + 1)]


@dataclass
class _StepLog:
    """What one odometer answered on one sequence of ``n`` steps, filled in as it runs."""

    n: int
    max_errors: int = 5
    raw: list = field(default_factory=list)
    reasons: list = field(default_factory=list)
    seconds: np.ndarray = field(default_factory=lambda: np.zeros(0))
    asked: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    errors: list[str] = field(default_factory=list)
    stamps: list[float] = field(default_factory=list)
    empty_depth: int = 0

    def __post_init__(self) -> None:
        self.raw = [None] * self.n
        self.reasons = ["reset-raised"] * self.n
        self.seconds = np.zeros(self.n)
        self.asked = np.zeros(self.n, bool)

    def note(self, where: str, exc: BaseException | str) -> None:
        """Keep the message of ``exc`` (or the text ``exc``) raised at ``where``, up to ``max_errors``."""
        if len(self.errors) < self.max_errors:
            self.errors.append(
                f"{where}: {exc}" if isinstance(exc, str) else f"{where}: {type(exc).__name__}: {_text(exc)}"
            )

    def fail(self, first: int, count: int, reason: str, seconds: float = 0.0) -> None:
        """Steps ``first .. first + count - 1`` failed for ``reason``, ``seconds`` spent on them in all."""
        self.reasons[first : first + count] = [reason] * count
        self.seconds[first : first + count] = seconds / count if count else 0.0

    def answer(self, first: int, count: int, answers: list | None, seconds: float) -> None:
        """Record the answers (copies, from :func:`_ask`; None: the call raised) to steps ``first .. first + count - 1``."""
        self.seconds[first : first + count] = seconds / count
        self.asked[first : first + count] = True
        for k, i in enumerate(range(first, first + count)):
            if answers is not None and len(answers) == count and answers[k] is not SHARED:
                self.raw[i] = answers[k]  # a copy already (:func:`_ask`)
            self.reasons[i] = self.checked(answers, k, count, f"step {i}")

    def checked(self, answers: list | None, k: int, count: int, where: str) -> str | None:
        """Why the ``k``-th of the ``answers`` to ``count`` pairs (None: the call raised) cannot be
        used (a key of :data:`FAILURE_REASONS`), or None; an answer that is no Estimate at all is
        noted at ``where``."""
        if answers is None:
            return "raised"
        if len(answers) != count:
            return "batch-length"
        if answers[k] is SHARED:
            return "shared-array"
        try:
            return failure_reason(answers[k])
        except Exception as exc:  # noqa: BLE001 - not an Estimate at all
            self.note(where, exc)
            return "raised"


def _sharing(answers: list) -> set[int]:
    """Indices of the answers whose transform shares memory with another answer's: one array
    reused for a whole batch holds only the last pair's motion by the time the batch returns."""
    arrays = [getattr(a, "transform", None) for a in answers]
    arrays = [t if isinstance(t, np.ndarray) else None for t in arrays]
    shared = set()
    for k, t in enumerate(arrays):
        for j in range(k + 1, len(arrays)):
            if t is not None and arrays[j] is not None and np.shares_memory(t, arrays[j]):
                shared |= {k, j}
    return shared


def _step_chunks(seq: Sequence, oracle: bool, size: int, log: _StepLog) -> Iterator[tuple[int, list]]:
    """``(first index, [(prev, cur, action), ...])`` chunks of ``size`` pairs; each frame's
    timestamp goes to ``log.stamps`` as it is read, and a frame without any depth is counted."""
    frame = seq[0]
    prev = guarded_frame(frame, oracle)
    log.stamps.append(prev.timestamp)
    log.empty_depth += has_no_depth(frame)
    chunk: list[tuple[Frame, Frame, Action | None]] = []
    first = 0
    for i in range(log.n):
        frame = seq[i + 1]
        cur = guarded_frame(frame, oracle)
        log.stamps.append(cur.timestamp)
        log.empty_depth += has_no_depth(frame)
        chunk.append((prev, cur, seq.action(i)))
        prev = cur
        if len(chunk) == size or i == log.n - 1:
            yield first, chunk
            first, chunk = i + 1, []


def _steps_text(first: int, count: int) -> str:
    return f"step {first}" if count == 1 else f"steps {first}-{first + count - 1}"


def _run_steps(
    odometer: Odometer,
    name: str,
    seq: Sequence,
    attrs: Attributes,
    log: _StepLog,
    caller: _Caller,
    observer: RunObserver | None,
) -> None:
    """Ask the odometer about every pair, one ``step_batch`` call per chunk, timed and time-limited;
    after :data:`MAX_TIMEOUTS` timed-out calls, the remaining pairs are not asked."""
    timeouts = 0
    for first, chunk in _step_chunks(seq, attrs.oracle, attrs.batch_size, log):
        count = len(chunk)
        if timeouts >= MAX_TIMEOUTS:
            log.fail(first, count, "timed-out")
        else:
            call = caller.call(lambda chunk=chunk: _ask(odometer, chunk), count)
            if call is None:
                timeouts += 1
                log.asked[first : first + count] = True
                log.fail(first, count, "timed-out", caller.timeout * count)
                stopped = "; stopped for the rest of the sequence" if timeouts == MAX_TIMEOUTS else ""
                log.note(_steps_text(first, count), f"timed out after {caller.timeout * count:g} s{stopped}")
            else:
                if call.error is not None:
                    log.note(_steps_text(first, count), call.error)
                log.answer(first, count, None if call.error is not None else call.value, call.seconds)
        if observer is not None:
            observer.advance(name, count)


def _start(odometer: Odometer, seq: Sequence, caller: _Caller, log: _StepLog) -> bool:
    """``odometer.reset(seq.intrinsics)`` within the time limit; False (every step failed, the reason
    noted) when it raised or timed out."""
    call = caller.call(lambda: odometer.reset(seq.intrinsics))
    if call is None:
        log.fail(0, log.n, "timed-out")
        log.note("reset", f"timed out after {caller.timeout:g} s")
        return False
    if call.error is not None:
        log.note("reset", call.error)  # the reasons stay "reset-raised"
        return False
    return True


def run_sequence(
    odometer: Odometer,
    seq: Sequence,
    name: str,
    prior: ActionPrior,
    observer: RunObserver | None = None,
    max_errors: int = 5,
    step_timeout: float | None = DEFAULT_STEP_TIMEOUT,
) -> SequenceResult:
    """Run one odometer over one sequence (see the module docstring for failure handling and the
    time limit ``step_timeout``, seconds per pair, None for none). ``ValueError`` for a sequence
    without frames; one frame is zero steps."""
    if len(seq) < 1:
        raise ValueError(f"sequence {seq.name!r} has no frames; a sequence needs at least one")
    n = len(seq) - 1
    log = _StepLog(n, max_errors)
    actions = np.array([NO_ACTION if a is None else a.value for a in (seq.action(i) for i in range(n))], np.int8)
    try:
        attrs: Attributes | None = read_attributes(odometer)
    except AttributeProblem as exc:
        attrs = None
        log.fail(0, n, "bad-attribute")
        log.note("attributes", str(exc))
    stepped = False
    if observer is not None:
        observer.advance(name, 0)
    if attrs is not None:
        caller = _Caller(name, step_timeout)
        try:
            with torch_threads(attrs.threads):
                if _start(odometer, seq, caller, log):
                    _run_steps(odometer, name, seq, attrs, log, caller, observer)
                    stepped = True
        finally:
            caller.close()
    if not stepped:
        frames = [seq[i] for i in range(n + 1)]
        log.stamps = [f.timestamp for f in frames]
        log.empty_depth = sum(has_no_depth(f) for f in frames)
        if observer is not None:
            observer.advance(name, n)

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
        oracle=False if attrs is None else attrs.oracle,
        estimates=estimates,
        truth=truth,
        poses=poses,
        gt_poses=gt_poses,
        actions=actions,
        valid=valid,
        step_seconds=log.seconds,
        collisions=None if collisions is None else np.asarray(collisions),
        timestamps=np.array(log.stamps),
        errors=log.errors,
        raw=tuple(log.raw),
        failure_reasons=dict(Counter(r for r in log.reasons if r is not None)),
        asked=log.asked,
        empty_depth=int(log.empty_depth),
    )


def run(
    odometers: dict[str, Odometer],
    sequences: Iterable[Sequence],
    prior: ActionPrior | None = None,
    observer: RunObserver | None = None,
    total_steps: int | None = None,
    step_timeout: float | None = DEFAULT_STEP_TIMEOUT,
) -> list[SequenceResult]:
    """Every odometer on every sequence, one sequence at a time (so ``sequences`` may be a stream
    that holds one episode in memory). ``observer`` hears of progress; ``total_steps`` (steps per
    odometer, summed over sequences) tells it the total when ``sequences`` has no length;
    ``step_timeout``: seconds a step may take (None: no limit; see the module docstring)."""
    prior = prior or ActionPrior.shipped()
    if total_steps is None and hasattr(sequences, "__len__"):
        total_steps = sum(len(s) - 1 for s in sequences)
    results = []
    if observer is not None:
        observer.start(None if total_steps is None else len(odometers) * total_steps)
    try:
        for seq in sequences:
            for name, odo in odometers.items():
                results.append(run_sequence(odo, seq, name, prior, observer, step_timeout=step_timeout))
    finally:
        if observer is not None:
            observer.close()
    return results


class StepByStep:
    """One odometer asked one pair at a time as its caller decides (closed-loop navigation, probes),
    under the runner's guards: its attributes read once (unusable: every step fails), ``reset`` and
    each ``step`` time-limited (``step_timeout`` s per pair, None: none), stopped after
    :data:`MAX_TIMEOUTS` timed-out steps, each answer copied and checked.
    :meth:`frame` guards a frame as the runner does (ground truth only for oracles); :meth:`step`
    answers the copied :class:`Estimate` or None, the reason counted in ``reasons`` and the first
    few messages in ``errors``. Use as a context manager (:meth:`close` lets the worker thread go)."""

    def __init__(
        self, odometer: Odometer, name: str, step_timeout: float | None = DEFAULT_STEP_TIMEOUT, max_errors: int = 5
    ) -> None:
        self.odometer = odometer
        self._caller = _Caller(name, step_timeout)
        self._log = _StepLog(0, max_errors)
        self.reasons: Counter[str] = Counter()
        self._timeouts = 0
        self._steps = 0  # pairs asked for so far: the next one's index in the messages
        try:
            self.attributes: Attributes | None = read_attributes(odometer)
        except AttributeProblem as exc:
            self.attributes = None
            self._log.note("attributes", str(exc))
        self._broken = "bad-attribute" if self.attributes is None else None

    @property
    def errors(self) -> list[str]:
        """The first few messages: what raised, timed out or was unusable, and where."""
        return self._log.errors

    def frame(self, frame: Frame) -> Frame:
        """``frame`` as this odometer may see it (:func:`guarded_frame`)."""
        return guarded_frame(frame, bool(self.attributes and self.attributes.oracle))

    def _call(self, fn: Callable[[], Any]) -> _Call | None:
        with torch_threads(self.attributes.threads if self.attributes else None):
            return self._caller.call(fn)

    def reset(self, intrinsics: Any) -> bool:
        """``odometer.reset(intrinsics)``; False (and every later step fails) when it raised or timed out."""
        if self._broken is not None:
            return False
        call = self._call(lambda: self.odometer.reset(intrinsics))
        if call is None or call.error is not None:
            self._broken = "timed-out" if call is None else "reset-raised"
            self._log.note("reset", f"timed out after {self._caller.timeout:g} s" if call is None else call.error)
            return False
        return True

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate | None:
        """The odometer's answer for one pair of guarded frames (:meth:`frame`), asked as the runner
        asks (``step_batch`` of the one pair: an odometer may define either), or None (failed)."""
        where = f"step {self._steps}"
        self._steps += 1
        if self._broken is None and self._timeouts >= MAX_TIMEOUTS:
            self._broken = "timed-out"
        if self._broken is not None:
            self.reasons[self._broken] += 1
            return None
        call = self._call(lambda: _ask(self.odometer, [(prev, cur, action)]))
        if call is None:
            self._timeouts += 1
            self.reasons["timed-out"] += 1
            stopped = "; stopped" if self._timeouts == MAX_TIMEOUTS else ""
            self._log.note(where, f"timed out after {self._caller.timeout:g} s{stopped}")
            return None
        if call.error is not None:
            self._log.note(where, call.error)
        reason = self._log.checked(None if call.error is not None else call.value, 0, 1, where)
        if reason is not None:
            self.reasons[reason] += 1
            return None
        return call.value[0]

    def close(self) -> None:
        """Let the worker thread go (a step it stopped waiting for may still be running)."""
        self._caller.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
