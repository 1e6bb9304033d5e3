"""Train the pose corrector on X's estimates of the training pairs, resumably; export the model.

    python -m odolab.learned.pose_corrector.train --config studies/pose_corrector/shipped.toml --hours 1

Makes the train and val data when missing (at the camera's size: X runs on the stored frames), then
X's estimates on their pairs when missing (:mod:`odolab.learned.pose_corrector.estimates`: one Ray task per
shard, stored beside the data, resumable), then trains for the recipe's epochs on random pairs,
saving after each under ``--work`` and writing validation curves (CSV, PNG) and ``training.json``
under ``--reports``; exports to ``--export`` when every epoch is done. Stopped at any moment (or by
``--hours``), the same command resumes.

Each pair's current frame is warped by X's estimate (by the action prior's where X failed) and the
target is the truth's planar motion minus that estimate's. Validation (:func:`correction_rows`),
per action (and the forward steps a collision stopped) and component: the mean absolute error of
corrected(X), of X alone (where X failed: the action prior, as the runner counts it) and of the
action prior, against the truth.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from odolab.api import MOTION_ACTIONS, Action, load_inputs, load_odometer, transform_to_planar, wrap_angle
from odolab.learned.pose_corrector.checkpoint import save_model
from odolab.learned.pose_corrector.config import PoseCorrectorModel, PoseCorrectorTraining, load_training
from odolab.learned.pose_corrector.estimates import InnerEstimates, make_estimates
from odolab.learned.pose_corrector.model import PoseCorrectorNet, pair_inputs, residual_targets
from odolab.learned.training import Curves, EpochLoop, Execution, TrainingData, make_training_data, require_finite
from odolab.learned.training.epochs import EpochTracker
from odolab.learned.training.trainer import Trainer

COMPONENTS = ("dx", "dz", "dyaw")
#: The label of the forward steps a collision stopped, in the validation rows.
COLLIDED = "move_forward (collided)"


@dataclasses.dataclass(frozen=True)
class PairTargets:
    """What a data folder's pairs are trained on: ``base`` (P, 4, 4) the motion the current frame is
    warped by (X's estimate, or the action prior's where X failed), ``failed`` (P,) bool, ``planar``
    (P, 3) the base's (dx, dz, dyaw) and ``residual`` (P, 3) the truth minus it (m, m, rad)."""

    base: np.ndarray
    failed: np.ndarray
    planar: np.ndarray
    residual: np.ndarray


def pair_targets(data: TrainingData, estimates: InnerEstimates) -> PairTargets:
    """The warp motions and targets of ``data``'s pairs from X's ``estimates`` of them."""
    prior = load_odometer("action-prior")
    prior_T = {a.value: prior.step(None, None, a).transform for a in MOTION_ACTIONS}
    failed = ~np.asarray(estimates.valid, bool)
    base = np.array(estimates.transform, np.float64, copy=True)
    for k in np.flatnonzero(failed):
        base[k] = prior_T[int(data.pair_actions[k])]
    planar = np.stack([transform_to_planar(T) for T in base]) if len(base) else np.zeros((0, 3))
    return PairTargets(base, failed, planar, residual_targets(data.pair_planar, planar))


def make_batch(
    data: TrainingData, targets: PairTargets, idx: np.ndarray, model: PoseCorrectorModel
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Network inputs (images, vector) and targets (B, 3) of pairs ``idx`` (indices into the pair
    arrays), the frames resized to the model's size as the odometer resizes them."""
    idx = np.asarray(idx, np.int64)
    f = data.pairs[idx]
    rgb, depth = data.frames(np.stack([f, f + 1], axis=1).ravel(), size=(model.width, model.height))
    rgb = torch.from_numpy(rgb).reshape(len(idx), 2, *rgb.shape[1:])
    depth = torch.from_numpy(depth).reshape(len(idx), 2, *depth.shape[1:])
    images, vector = pair_inputs(
        rgb[:, 0],
        depth[:, 0],
        rgb[:, 1],
        depth[:, 1],
        torch.from_numpy(targets.base[idx]),
        data.pair_actions[idx],
        torch.from_numpy(targets.failed[idx]),
        data.intrinsics.resized(model.width, model.height),
        model,
    )
    return images, vector, torch.from_numpy(targets.residual[idx]).to(torch.float32)


def loss_fn(
    correction: torch.Tensor, log_variance: torch.Tensor, target: torch.Tensor, nll_weight: float
) -> torch.Tensor:
    """Mean absolute error of ``correction`` against ``target`` (B, 3: m, m, rad, counted alike) +
    ``nll_weight`` x the Gaussian negative log-likelihood of the (detached) error under
    ``log_variance``."""
    err = correction - target
    nll = 0.5 * (err.detach().pow(2) * torch.exp(-log_variance) + log_variance)
    return err.abs().mean() + nll_weight * nll.mean()


def correction_rows(
    corrected: np.ndarray,
    inner: np.ndarray,
    truth: np.ndarray,
    actions: np.ndarray,
    collisions: np.ndarray,
    failed: np.ndarray,
    std: np.ndarray,
) -> list[dict]:
    """One row per (action present, component), and for the forward steps a collision stopped
    (:data:`COLLIDED`): ``pairs``, ``mae`` of ``corrected`` (N, 3), ``inner_mae`` of X alone
    (``inner``: the action prior where X failed), ``prior_mae`` of the action prior, ``inner_failed``
    (pairs where X failed) and ``std`` (the root mean predicted variance, the spread ``mae`` should
    match), against ``truth`` (N, 3); yaw errors wrapped."""
    prior = load_odometer("action-prior")
    actions = np.asarray(actions)
    groups = [(a.label, actions == a.value, a) for a in MOTION_ACTIONS]
    forward = actions == Action.MOVE_FORWARD.value
    groups.insert(1, (COLLIDED, forward & np.asarray(collisions, bool), Action.MOVE_FORWARD))

    def errors(pred: np.ndarray, mask: np.ndarray) -> np.ndarray:
        e = np.asarray(pred, np.float64) - truth[mask]
        e[:, 2] = wrap_angle(e[:, 2])
        return np.abs(e)

    rows = []
    for label, mask, action in groups:
        if not mask.any():
            continue
        err, inner_err = errors(corrected[mask], mask), errors(inner[mask], mask)
        prior_err = errors(np.broadcast_to(prior.step(None, None, action).planar, (int(mask.sum()), 3)), mask)
        for c, name in enumerate(COMPONENTS):
            rows.append(
                {
                    "action": label,
                    "component": name,
                    "pairs": int(mask.sum()),
                    "mae": float(err[:, c].mean()),
                    "inner_mae": float(inner_err[:, c].mean()),
                    "prior_mae": float(prior_err[:, c].mean()),
                    "inner_failed": int(np.asarray(failed)[mask].sum()),
                    "std": float(np.sqrt(np.mean(np.square(std[mask, c])))),
                }
            )
    return rows


def write_report(folder: Path, rows: list[dict], status: dict, inner: str, final: bool = True) -> None:
    """``curves.csv`` (every row), ``curves.png`` (validation MAE per action and component of
    corrected(X), X alone and the action prior; yaw in degrees) and ``training.json``, each written
    atomically into ``folder``; ``final=False`` (after an epoch) keeps a figure drawn less than a
    minute ago (:meth:`Curves.plot`)."""
    from odolab.io.atomic import write_bytes_atomic

    folder = Path(folder)
    curves = Curves(rows)
    curves.to_csv(folder / "curves.csv")
    dashed = {"linestyle": "--", "marker": "_", "markersize": 8}
    curves.plot(
        folder / "curves.png",
        x="epoch",
        rows="action",
        cols="component",
        where={"split": "val"},
        series={
            "mae": {"label": f"corrected({inner}) (val)", "color": "C0"},
            "inner_mae": {"label": f"{inner} alone (val)", "color": "C1", **dashed},
            "prior_mae": {"label": "action prior (val)", "color": "0.5", **dashed},
        },
        scale={"dyaw": 180 / np.pi},
        title=f"Pose corrector of {inner}: validation error after each epoch (val split)",
        ylabel={"dx": "mean |error|, m", "dz": "mean |error|, m", "dyaw": "mean |error|, deg"},
        final=final,
    )
    write_bytes_atomic(folder / "training.json", (json.dumps(status, indent=1) + "\n").encode())


def _failures(estimates: InnerEstimates) -> dict[str, int]:
    """How often X failed on a data set, by reason."""
    reasons, counts = np.unique(estimates.reason[~estimates.valid], return_counts=True)
    return {str(r): int(n) for r, n in zip(reasons, counts)}


def run(
    cfg: PoseCorrectorTraining,
    *,
    work: Path,
    reports: Path,
    export: Path,
    device: torch.device,
    hours: float | None,
    execution: Execution = Execution(),
    command: str = "",
    workers: int = 1,
    gpus_per_worker: float = 0.0,
) -> bool:
    """Train (or resume); export when every epoch is done. Returns True when finished."""
    if workers != 1:
        raise ValueError(f"--workers {workers}: the pose corrector trains in one process; leave --workers out")
    if cfg.init:
        raise ValueError("recipe: init: the pose corrector starts from fresh weights; set init = ''")
    try:  # X and its options checked before any data is made (hours of rendering for the shipped recipe)
        load_inputs("corrected", [cfg.inner], cfg.options_file)
    except (KeyError, TypeError, ValueError) as exc:
        said = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        raise ValueError(f"recipe: inner = {cfg.inner!r}: {said}") from None
    folders = [cfg.data_folder(dc) for dc in (cfg.train_data, cfg.val_data)]
    for dc, folder in zip((cfg.train_data, cfg.val_data), folders):
        make_training_data(dc, folder, execution=execution)
        TrainingData(folder).verify(execution.progress)
    estimates = [make_estimates(folder, cfg.inner, cfg.options_file, execution=execution) for folder in folders]
    deadline = time.monotonic() + hours * 3600 if hours else None
    train, val = (TrainingData(folder) for folder in folders)
    train_targets, val_targets = (pair_targets(d, e) for d, e in zip((train, val), estimates))
    rng = np.random.default_rng(cfg.seed)
    val_pairs = np.arange(len(val))
    if len(val_pairs) > cfg.val_pairs:
        val_pairs = np.sort(rng.choice(val_pairs, cfg.val_pairs, replace=False))
    compute = cfg.compute.resolve(device)
    torch.manual_seed(cfg.seed)
    net = compute.prepare(PoseCorrectorNet(cfg.model)).to(device)
    recipe = json.loads(json.dumps(dataclasses.asdict(cfg)))
    identity = {k: v for k, v in recipe.items() if k not in ("epochs", "init", "compute", "data_root")}
    identity["inner_identity_digest"] = estimates[0].identity_digest
    optimizer = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    loop = EpochLoop(work / "pose-corrector.pt", {"net": net}, optimizer, cfg.epochs, cfg.seed, identity)
    loop.resume()

    def train_epoch(epoch: int, rng: np.random.Generator, tracker: EpochTracker) -> dict:
        order = rng.integers(0, len(train), cfg.pairs_per_epoch)
        parts = [np.sort(order[k : k + cfg.batch]) for k in range(0, len(order), cfg.batch)][tracker.start :]
        bar = tqdm(
            total=len(order),
            initial=tracker.samples,
            desc=f"pose corrector epoch {epoch}",
            unit="pair",
            disable=not execution.progress,
            leave=False,
        )
        for images, vector, target in compute.batches(parts, lambda p: make_batch(train, train_targets, p, cfg.model)):
            with compute.autocast():
                correction, log_variance = net(compute.inputs(images), vector.to(device))
            loss = loss_fn(correction.float(), log_variance.float(), target.to(device), cfg.nll_weight)
            require_finite(loss, epoch)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            bar.update(len(target))
            tracker.add(loss.item(), len(target))
        bar.close()
        return {}

    def validate(epoch: int) -> list[dict]:
        corrections, stds = [], []
        for k in range(0, len(val_pairs), 32):
            images, vector, _ = make_batch(val, val_targets, val_pairs[k : k + 32], cfg.model)
            correction, log_variance = net(compute.inputs(images), vector.to(device))
            corrections.append(correction.double().cpu().numpy())
            stds.append(np.sqrt(np.exp(log_variance.double().cpu().numpy())))
        inner = val_targets.planar[val_pairs]
        corrected = inner + np.concatenate(corrections)
        corrected[:, 2] = wrap_angle(corrected[:, 2])
        return correction_rows(
            corrected,
            inner,
            val.pair_planar[val_pairs],
            val.pair_actions[val_pairs],
            val.pair_collisions[val_pairs],
            val_targets.failed[val_pairs],
            np.concatenate(stds),
        )

    def status() -> dict:
        return {
            "command": command,
            "compute": compute.describe(),
            "inner": cfg.inner,
            "inner_identity_digest": estimates[0].identity_digest,
            "inner_failures": {"train": _failures(estimates[0]), "val": _failures(estimates[1])},
            "train_pairs": len(train),
            "val_pairs": len(val_pairs),
            "epochs_done": loop.epoch,
            "epochs": loop.epochs,
            "hours": round(loop.seconds / 3600, 3),
            "pairs_seen": int(sum(r.get("pairs", 0) for r in loop.curves.rows if r.get("split") == "train")),
        }

    def after(_: EpochLoop) -> None:
        write_report(reports, loop.curves.rows, status(), cfg.inner, final=False)

    try:
        finished = loop.run(train_epoch, validate, deadline=deadline, after_epoch=after)
    finally:  # stopped or interrupted too: the figure shows every finished epoch
        write_report(reports, loop.curves.rows, status(), cfg.inner)
    if finished:
        save_model(export, cfg, net.cpu(), status())
    return finished


def state_files(cfg: PoseCorrectorTraining, work: Path) -> dict[str, Path]:
    """Where the training keeps its state (what ``--export`` must never replace)."""
    return {"the pose corrector's training": work / "pose-corrector.pt"}


#: What the training command line (odolab.cli.train) needs of this trainer.
TRAINER = Trainer(
    family="pose-corrector",
    description=__doc__.split("\n")[0],
    load_config=load_training,
    run=run,
    state_files=state_files,
    set_example="seed=1 --set inner=icp",
)


if __name__ == "__main__":  # python -m odolab.learned.pose_corrector.train: the command line is odolab.cli.train's
    import importlib

    train = importlib.import_module("odolab.cli.train")
    train.exit_process(train.command("pose-corrector"))
