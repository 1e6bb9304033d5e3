"""Train DeepVO on windows of consecutive simulator frames, resumably; export the model.

    python -m odolab.learned.deepvo.train --config studies/deepvo/shipped.toml --hours 1.5

Makes the train and val data when missing (the same folders as the robust VO's recipe of the same
data config), then trains for the recipe's epochs, saving after each under ``--work`` and writing
validation curves (CSV, PNG) and ``training.json`` under ``--reports``; exports to ``--export``
when every epoch is done. Stopped at any moment (or by ``--hours``), the same command resumes.

Targets are the pairs' true planar motions from SE(3) composition, ``inv(T_prev) @ T_cur`` (never
differences of Euler angles); the loss is MSE(dx, dz) + ``rotation_weight`` x MSE(dyaw).
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from odolab.learned.deepvo.config import DeepVOTraining, load_training
from odolab.learned.deepvo.model import ACTION_INPUTS, DeepVONet, frame_tensor
from odolab.learned.deepvo.odometer import load_model, save_model
from odolab.learned.training import (
    EpochLoop,
    Execution,
    TrainingData,
    differences_from_init,
    load_init,
    make_training_data,
    require_finite,
)
from odolab.learned.training.distributed import Team, run_on_ray
from odolab.learned.training.epochs import EpochTracker
from odolab.learned.training.trainer import Trainer
from odolab.learned.training.validation import error_rows, write_report


def window_batch(
    data: TrainingData, starts: np.ndarray, window: int, cfg
) -> tuple[torch.Tensor, np.ndarray, np.ndarray]:
    """Frames (B, window, C, H, W), true (dx, dz, dyaw) (B, window - 1, 3) and actions (B, window - 1)
    of the windows starting at pair indices ``starts`` (from :meth:`TrainingData.windows`)."""
    frames = data.pairs[starts][:, None] + np.arange(window)[None]
    rgb, depth = data.frames(frames.ravel(), (cfg.width, cfg.height))
    x = frame_tensor(rgb, depth, cfg)
    x = x.reshape(len(starts), window, *x.shape[1:])
    pairs = starts[:, None] + np.arange(window - 1)[None]
    return x, data.pair_planar[pairs], data.pair_actions[pairs]


class WindowBatches:
    """What one step reads, made on the CPU (in a loader worker): :func:`window_batch` of some starts."""

    def __init__(self, data: TrainingData, window: int, cfg) -> None:
        self.data, self.window, self.cfg = data, window, cfg

    def __call__(self, starts: np.ndarray) -> tuple[torch.Tensor, np.ndarray, np.ndarray]:
        return window_batch(self.data, starts, self.window, self.cfg)

    def advise(self, starts: np.ndarray) -> None:
        """Start reading the frames of the windows at ``starts`` (see :meth:`TrainingData.prefetch`)."""
        self.data.prefetch(self.data.pairs[starts][:, None] + np.arange(self.window)[None])


def disjoint(starts: np.ndarray, pairs: int) -> np.ndarray:
    """Window starts (sorted pair indices) thinned so that windows of ``pairs`` pairs do not overlap."""
    keep, end = [], -1
    for k in np.sort(starts):
        if k >= end:
            keep.append(k)
            end = k + pairs
    return np.array(keep, np.int64)


def loss_fn(pred: torch.Tensor, target: torch.Tensor, rotation_weight: float) -> torch.Tensor:
    """MSE of (dx, dz) + ``rotation_weight`` x MSE of dyaw, over every pair of every window."""
    return (pred[..., :2] - target[..., :2]).pow(2).mean() + rotation_weight * (pred[..., 2] - target[..., 2]).pow(
        2
    ).mean()


#: Inputs a recipe's model may add to the model it starts from (``init``).
GAINABLE = ("depth", "actions")


def first_stage(cfg: DeepVOTraining, export: Path) -> tuple[dict, str] | None:
    """The weights (a state dict for ``cfg.model``) of the exported model ``cfg.init`` and its
    SHA-256 (part of the run's identity: another first stage is another run), or None without
    ``init``. Refused, before any data is made: a missing file or folder, another kind of checkpoint,
    another model shape, and the run's own ``export`` (which would overwrite the model it starts
    from). Inputs may be gained: a model without ``depth`` or ``actions`` may start a model with
    them; the new inputs start with zero weights, so the network answers as before until it learns
    to use them."""
    if not cfg.init:
        return None
    model, first, digest = load_init(cfg.init, export, load_model)
    changed = [f.name for f in dataclasses.fields(model) if getattr(model, f.name) != getattr(cfg.model, f.name)]
    gained = [name for name in changed if name in GAINABLE and not getattr(model, name)]
    if not model.depth and "max_depth" in changed:  # a model without depth never used it
        changed.remove("max_depth")
    refused = [name for name in changed if name not in gained]
    if refused:
        lost = [name for name in refused if name in GAINABLE]
        raise ValueError(
            f"init = {cfg.init!r}: its model differs from this recipe's in "
            + differences_from_init(model, cfg.model, refused)
            + (f" (a start may gain {' or '.join(GAINABLE)}, not lose it)" if lost else "")
        )
    state = dict(first.state_dict())
    if "depth" in gained:
        key = "encoder.0.0.weight"  # (out, 2 x 3, k, k) -> (out, 2 x 4, k, k): [rgb, depth] per frame
        old = state[key]
        grown = old.new_zeros((old.shape[0], 8, *old.shape[2:]))
        grown[:, [0, 1, 2, 4, 5, 6]] = old
        state[key] = grown
    if "actions" in gained:
        key = "lstm.weight_ih_l0"  # (4 hidden, features) -> (4 hidden, features + 3): one-hot last
        state[key] = torch.cat([state[key], state[key].new_zeros((state[key].shape[0], ACTION_INPUTS))], dim=1)
    return state, digest


def run(
    cfg: DeepVOTraining,
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
    """Train (or resume); export when every epoch is done. Returns True when finished. With
    ``workers`` > 1, data-parallel on Ray Train (:mod:`odolab.learned.training.distributed`)."""
    first_stage(cfg, export)  # checked before any data is made
    for dc in (cfg.train_data, cfg.val_data):
        make_training_data(dc, cfg.data_folder(dc), execution=execution)
        TrainingData(cfg.data_folder(dc)).verify(execution.progress)
    job = {
        "cfg": cfg,
        "work": work,
        "reports": reports,
        "export": export,
        "hours": hours,
        "progress": execution.progress,
        "command": command,
        "device": device,
    }
    if workers == 1:
        return bool(train_windows({**job, "team": Team()})["finished"])
    return run_on_ray(
        _team_member,
        job,
        workers=workers,
        work=work,
        export=export,
        ray_address=execution.ray_address,
        gpus_per_worker=gpus_per_worker,
    )


def _team_member(job: dict) -> dict:
    """One Ray Train worker."""
    device = torch.device("cpu")
    if torch.cuda.is_available():
        import ray.train.torch

        device = ray.train.torch.get_device()
    return train_windows({**job, "device": device})


def train_windows(job: dict) -> dict:
    """The training proper on the made data, as one worker of ``job["team"]``; ``{"finished": bool}``."""
    cfg, work, reports, export, team = job["cfg"], job["work"], job["reports"], job["export"], job["team"]
    device, progress, command = job["device"], job["progress"], job["command"]
    deadline = time.monotonic() + job["hours"] * 3600 if job["hours"] else None
    start = first_stage(cfg, export)
    train, val = (TrainingData(cfg.data_folder(dc)) for dc in (cfg.train_data, cfg.val_data))
    starts = train.windows(cfg.window)
    if not len(starts):
        raise ValueError(f"no window of {cfg.window} frames in the training data; use a shorter window")
    val_starts = disjoint(val.windows(cfg.window), cfg.window - 1)  # every val pair counted once at most
    rng = np.random.default_rng(cfg.seed)
    if len(val_starts) > cfg.val_windows:
        val_starts = np.sort(rng.choice(val_starts, cfg.val_windows, replace=False))
    compute = cfg.compute.resolve(device)
    torch.manual_seed(cfg.seed)
    net = compute.prepare(DeepVONet(cfg.model))
    recipe = json.loads(json.dumps(dataclasses.asdict(cfg)))
    # where the data live is not what they are (a moved run resumes): train_data / val_data say that
    identity = {k: v for k, v in recipe.items() if k not in ("epochs", "init", "compute", "data_root")}
    if start is not None:
        net.load_state_dict(start[0])
        identity["init_sha256"] = start[1]
    else:
        with torch.no_grad():  # start at the mean motion: the output bias is the mean target / scale
            mean = train.pair_planar.mean(axis=0)
            net.head.bias.copy_(torch.from_numpy(mean).to(torch.float32) / net.scale.cpu())
    optimizer = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    loop = EpochLoop(
        work / "deepvo.pt", {"net": net}, optimizer, cfg.epochs, cfg.seed, identity, unit="windows", team=team
    )
    loop.resume()

    def train_epoch(epoch: int, rng: np.random.Generator, tracker: EpochTracker) -> dict:
        order = rng.permutation(starts)
        if cfg.windows_per_epoch:
            order = order[: cfg.windows_per_epoch]
        batches = [
            b
            for b in (np.sort(order[k : k + cfg.batch]) for k in range(0, len(order), cfg.batch))
            if len(b) >= team.size
        ][tracker.start :]
        bar = tqdm(
            total=len(order),
            initial=tracker.samples,
            desc=f"deepvo epoch {epoch}",
            unit="window",
            disable=not (progress and team.leader),
            leave=False,
        )
        made = compute.batches([team.share(b) for b in batches], WindowBatches(train, cfg.window, cfg.model))
        for (x, target, actions), whole in zip(made, batches):
            with compute.autocast():
                pred, _ = net(x.to(device), actions=torch.from_numpy(actions).to(device))
            loss = loss_fn(pred.float(), torch.from_numpy(target).to(device, torch.float32), cfg.rotation_weight)
            require_finite(loss, epoch)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            team.average_gradients(net.parameters(), len(x))
            optimizer.step()
            team.average_buffers([net])
            bar.update(len(whole))
            tracker.add(loss.item(), len(whole))
        bar.close()
        return {}

    def validate(epoch: int) -> list[dict]:
        preds, truths, acts = [], [], []
        parts = [val_starts[k : k + 64] for k in range(0, len(val_starts), 64)]
        for x, target, actions in compute.batches(parts, WindowBatches(val, cfg.window, cfg.model)):
            preds.append(
                net(x.to(device), actions=torch.from_numpy(actions).to(device))[0].cpu().numpy().reshape(-1, 3)
            )
            truths.append(target.reshape(-1, 3))
            acts.append(actions.ravel())
        if not preds:
            return []
        return error_rows(np.concatenate(preds), np.concatenate(truths), np.concatenate(acts))

    def status() -> dict:
        return {
            "command": command,
            "compute": {**compute.describe(), "workers": team.size},
            "train_pairs": train.counts(),
            "val_pairs": val.counts(),
            "epochs_done": loop.epoch,
            "epochs": loop.epochs,
            "hours": round(loop.seconds / 3600, 3),
            "windows_seen": int(sum(r.get("windows", 0) for r in loop.curves.rows if r.get("split") == "train")),
        }

    def after(_: EpochLoop) -> None:
        write_report(reports, loop.curves.rows, status(), "DeepVO: validation error after each epoch", final=False)

    try:
        finished = loop.run(train_epoch, validate, deadline=deadline, after_epoch=after)
    finally:  # stopped or interrupted too: the figure shows every finished epoch
        if team.leader:
            write_report(reports, loop.curves.rows, status(), "DeepVO: validation error after each epoch")
    if team.leader and finished:
        save_model(export, cfg, net, status())
    return {"finished": finished}


def state_files(cfg: DeepVOTraining, work: Path) -> dict[str, Path]:
    """Where the training keeps its state (what ``--export`` must never replace): ``<work>/deepvo.pt``."""
    return {"the DeepVO training": work / "deepvo.pt"}


#: What the training command line (odolab.cli.train) needs of this trainer.
TRAINER = Trainer(
    family="deepvo",
    description=__doc__.split("\n")[0],
    load_config=load_training,
    run=run,
    state_files=state_files,
    check_start=first_stage,
    set_example="seed=1 --set lr=1e-4 --set epochs=2",
)


if __name__ == "__main__":  # python -m odolab.learned.deepvo.train: the command line is odolab.cli.train's
    import importlib

    train = importlib.import_module("odolab.cli.train")
    train.exit_process(train.command("deepvo"))
