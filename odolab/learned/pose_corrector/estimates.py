"""X's estimates on a training-data folder's pairs, computed once and stored beside the data.

    <data folder>/estimates/<file stem of X's name>/
        estimates.json                          format, X's name and identity digest, the chunks made
        shard-<index>-<digest>.npz              one chunk per data shard (same name as the shard)

X runs on the stored frames, one episode after another (``reset`` at each episode's start, then its
pairs in order), as the runner would run it; one Ray task per data shard
(:func:`odolab.core.parallel.fan_out`), each chunk written atomically as it finishes and listed in
``estimates.json``, so an interrupted run resumes with the chunks it lacks. A chunk holds, per pair
of its shard (in the data's pair order): ``frames`` (the pair's first global frame, to check it
matches the data), ``transform`` (4x4 ``T_prev_cur`` of X; the identity where X failed), ``valid``
(X answered a rigid motion: :func:`odolab.api.failure_reason`, and did not raise) and ``reason``
(why not; "" where valid). Estimates made by another X (another name, or the same name with
another ``identity_digest``: other options or another model) are refused in one line, never mixed.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from odolab.api import Action, Estimate, Frame, Odometer, failure_reason, load_inputs
from odolab.core.parallel import Execution, fan_out
from odolab.io.atomic import atomic_open, remove_stale_temporaries, write_bytes_atomic
from odolab.io.owned import owned_path
from odolab.reporting.report import file_stem
from odolab.sim.training_data import TrainingData, making

FORMAT = 1
MANIFEST = "estimates.json"
FOLDER = "estimates"
#: The temporaries an atomic write of a chunk or the manifest leaves when its writer is killed.
_TEMPORARIES = re.compile(r"\.(shard-[0-9]+-[0-9a-f]{12}\.npz|estimates\.json)\.[A-Za-z0-9_]+\.tmp")
#: Longest failure reason kept per pair (characters).
REASON_CHARS = 40


class EstimatesError(ValueError):
    """Stored estimates that cannot be used for this X and data (the message names the file)."""


@dataclass(frozen=True)
class InnerEstimates:
    """X's estimates on every pair of a data folder, in its pair order (:attr:`TrainingData.pairs`):
    ``transform`` (P, 4, 4) ``T_prev_cur`` (identity where X failed), ``valid`` (P,) bool,
    ``reason`` (P,) str ("" where valid), made by X ``name`` of ``identity_digest``."""

    name: str
    identity_digest: str | None
    transform: np.ndarray
    valid: np.ndarray
    reason: np.ndarray


@dataclass(frozen=True)
class EstimateJob:
    """One chunk's work (a Ray task's argument): X ``name`` with its ``options_file`` on the pairs of
    shard ``shard`` of the data folder ``root``, expected to be of ``identity_digest``."""

    root: str
    shard: int
    name: str
    options_file: str
    identity_digest: str | None


def estimates_folder(root: str | Path, name: str) -> Path:
    """Where the estimates of X ``name`` on data folder ``root`` lie."""
    return Path(root) / FOLDER / file_stem(name)


def shard_pairs(data: TrainingData) -> list[np.ndarray]:
    """Per data shard, the indices into the data's pair arrays of its pairs (in order)."""
    cfg = data.config
    shard_of_pair = (data.episode[data.pairs] - cfg.first) // cfg.episodes_per_shard
    return [np.flatnonzero(shard_of_pair == s) for s in range(len(data.shards))]


def _step(inner: Odometer, prev: Frame, cur: Frame, action: Action) -> tuple[Estimate | None, str]:
    """X's answer for one pair and why it cannot be used ("" when it can); an exception X raises is
    a failure (as the runner counts it), named by its type."""
    try:
        est = inner.step(prev, cur, action)
    except Exception as exc:  # noqa: BLE001 - any failure of X is a failed step, as in the runner
        return None, f"raised {type(exc).__name__}"
    if not isinstance(est, Estimate):
        return None, "not-an-estimate"
    reason = failure_reason(est)
    return (est, "") if reason is None else (None, reason)


def _frame(data: TrainingData, f: int, start: int, oracle: bool) -> Frame:
    """Global frame ``f`` as the runner hands it to X: read-only arrays, its place in its episode
    (from ``start``, the episode's first frame) as the timestamp (s), ground truth for an oracle only."""
    rgb, depth = data.frames(np.array([f]))
    rgb, depth = rgb[0], depth[0]
    rgb.flags.writeable = False
    depth.flags.writeable = False
    return Frame(rgb, depth, timestamp=float(f - start), gt_pose=data.poses[f].copy() if oracle else None)


def estimate_shard(job: EstimateJob) -> dict[str, np.ndarray]:
    """X's estimates on one shard's pairs (a Ray task): ``frames``, ``transform``, ``valid``,
    ``reason`` (module docstring)."""
    data = TrainingData(job.root)
    inner = load_inputs("corrected", [job.name], job.options_file)[job.name]
    if inner.identity_digest != job.identity_digest:
        raise EstimatesError(
            f"{job.name}: this process built it with identity digest {inner.identity_digest}, the driver "
            f"with {job.identity_digest} (workers of another odolab or other files?)"
        )
    idx = shard_pairs(data)[job.shard]
    frames = data.pairs[idx]
    out = {
        "frames": frames,
        "transform": np.tile(np.eye(4), (len(idx), 1, 1)),
        "valid": np.zeros(len(idx), bool),
        "reason": np.full(len(idx), "", dtype=f"<U{REASON_CHARS}"),
    }
    episode_start: dict[int, int] = {}
    last: tuple[int, Frame] | None = None  # the last frame read (a pair's current is the next one's previous)
    for k, (i, f) in enumerate(zip(idx, frames)):
        ep = int(data.episode[f])
        if ep not in episode_start:
            episode_start[ep] = int(np.flatnonzero(data.episode == ep)[0])
            inner.reset(data.intrinsics)
            last = None
        start = episode_start[ep]
        prev = last[1] if last is not None and last[0] == f else _frame(data, f, start, inner.oracle)
        cur = _frame(data, f + 1, start, inner.oracle)
        last = (int(f) + 1, cur)
        est, reason = _step(inner, prev, cur, Action(int(data.pair_actions[i])))
        if est is not None:
            out["transform"][k] = np.asarray(est.transform, np.float64)
            out["valid"][k] = True
        out["reason"][k] = reason[:REASON_CHARS]
    return out


def _read_manifest(folder: Path) -> dict | None:
    path = folder / MANIFEST
    if not path.exists():
        return None
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise EstimatesError(f"{path}: not a readable estimates manifest ({exc}); delete {folder} to make them again")
    if not isinstance(doc, dict) or doc.get("format") != FORMAT or not isinstance(doc.get("chunks"), dict):
        raise EstimatesError(
            f"{path}: expected an odolab estimates manifest of format {FORMAT}; delete {folder} to make them again"
        )
    return doc


def _check_owner(folder: Path, doc: dict, name: str, identity_digest: str | None) -> None:
    """:class:`EstimatesError` unless the estimates in ``folder`` were made by X ``name`` of ``identity_digest``."""
    made = (doc.get("inner"), doc.get("identity_digest"))
    if made != (name, identity_digest):
        raise EstimatesError(
            f"{folder / MANIFEST}: estimates of {made[0]!r} (identity digest {made[1]}), not of {name!r} "
            f"(identity digest {identity_digest}): its options or model changed; delete {folder} to make them again"
        )


def make_estimates(
    root: str | Path, name: str, options_file: str = "", *, execution: Execution = Execution()
) -> InnerEstimates:
    """X's estimates on the pairs of data folder ``root``: the chunks not yet stored are computed
    (one task per data shard, each stored as it finishes) and all are returned. X ``name`` is built
    with its options from ``options_file``; estimates stored by another X are refused
    (:class:`EstimatesError`)."""
    data = TrainingData(root)
    inner = load_inputs("corrected", [name], options_file)[name]
    folder = estimates_folder(root, name)
    relative = folder.relative_to(Path(root))
    owned_path(root, relative / MANIFEST)  # the folders on the way, made and checked
    with making(folder):
        doc = _read_manifest(folder) or {
            "format": FORMAT,
            "inner": name,
            "identity_digest": inner.identity_digest,
            "chunks": {},
        }
        _check_owner(folder, doc, name, inner.identity_digest)
        remove_stale_temporaries(folder, _TEMPORARIES)
        todo = [
            s for s, shard in enumerate(data.shards) if shard not in doc["chunks"] or not (folder / shard).is_file()
        ]

        def done(k: int, arrays: dict[str, np.ndarray]) -> None:
            shard = data.shards[todo[k]]
            with atomic_open(owned_path(root, relative / shard), "wb") as f:
                np.savez(f, **arrays)
            doc["chunks"][shard] = {"pairs": int(len(arrays["valid"])), "failed": int((~arrays["valid"]).sum())}
            write_bytes_atomic(folder / MANIFEST, (json.dumps(doc, indent=1) + "\n").encode())

        write_bytes_atomic(folder / MANIFEST, (json.dumps(doc, indent=1) + "\n").encode())
        jobs = [EstimateJob(str(root), s, name, options_file, inner.identity_digest) for s in todo]
        fan_out(estimate_shard, jobs, on_result=done, execution=execution, desc=f"{name} on {data.config.split} pairs")
    return load_estimates(data, name, inner.identity_digest)


def load_estimates(data: TrainingData, name: str, identity_digest: str | None) -> InnerEstimates:
    """The stored estimates of X ``name`` (of ``identity_digest``) on ``data``'s pairs;
    :class:`EstimatesError` naming the file when they are missing, of another X, or do not match
    the data's pairs."""
    folder = estimates_folder(data.root, name)
    doc = _read_manifest(folder)
    if doc is None:
        raise EstimatesError(f"{folder}: no {MANIFEST}; make the estimates first (make_estimates)")
    _check_owner(folder, doc, name, identity_digest)
    parts: dict[str, list[np.ndarray]] = {"transform": [], "valid": [], "reason": []}
    for shard, idx in zip(data.shards, shard_pairs(data)):
        path = folder / shard
        if shard not in doc["chunks"] or not path.is_file():
            raise EstimatesError(f"{path}: missing; run the training again to make it")
        try:
            with np.load(path, allow_pickle=False) as z:
                chunk = {k: np.array(z[k]) for k in ("frames", "transform", "valid", "reason")}
        except (OSError, ValueError, KeyError, EOFError) as exc:
            raise EstimatesError(f"{path}: unreadable estimates ({exc}); delete it to make it again") from None
        if not np.array_equal(chunk["frames"], data.pairs[idx]) or chunk["transform"].shape != (len(idx), 4, 4):
            raise EstimatesError(
                f"{path}: expected estimates of the {len(idx)} pairs of data shard {shard}, found "
                f"{len(chunk['frames'])} of other frames; delete it to make it again"
            )
        for k, kept in parts.items():
            kept.append(chunk[k])
    return InnerEstimates(
        name,
        identity_digest,
        np.concatenate(parts["transform"]) if parts["transform"] else np.zeros((0, 4, 4)),
        np.concatenate(parts["valid"]).astype(bool) if parts["valid"] else np.zeros(0, bool),
        np.concatenate(parts["reason"]) if parts["reason"] else np.zeros(0, "<U1"),
    )
