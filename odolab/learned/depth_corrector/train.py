"""Train the depth corrector on frames whose noiseless depth the simulator kept, resumably; export
the model.

    python -m odolab.learned.depth_corrector.train --config studies/depth_corrector/shipped.toml --hours 1

Makes the train and val data when missing (``clean_depth = true``: the noisy frame and the
simulator's depth of the same view), then trains for the recipe's epochs on random crops, saving
after each under ``--work`` and writing validation curves (CSV, PNG) and ``training.json`` under
``--reports``; exports to ``--export`` when every epoch is done. Stopped at any moment (or by
``--hours``), the same command resumes.

Validation (:func:`depth_error_rows`): the mean absolute error (m) of the noisy and of the corrected
depth against the noiseless depth, over the pixels where both the noisy and the true depth have a
reading, by true distance (0-1, 1-2, ..., 5+ m) and on depth edges (:func:`depth_edges`).
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from odolab.learned.depth_corrector.checkpoint import save_model
from odolab.learned.depth_corrector.config import CorrectorTraining, load_training
from odolab.learned.depth_corrector.model import DepthCorrectorNet, pixel_place
from odolab.learned.training import Curves, EpochLoop, Execution, TrainingData, make_training_data, require_finite
from odolab.learned.training.epochs import EpochTracker
from odolab.learned.training.trainer import Trainer

#: Upper edges (m) of the true-distance bins of the validation rows; the last bin is open.
BIN_EDGES = (1.0, 2.0, 3.0, 4.0, 5.0)
#: A pixel is on a depth edge when a 4-neighbour's true depth differs by more than this share.
EDGE_SHARE = 0.05


def bin_labels() -> list[str]:
    """``["0-1 m", "1-2 m", ..., "5+ m"]``."""
    lows = (0.0,) + BIN_EDGES
    return [f"{lo:g}-{hi:g} m" for lo, hi in zip(lows, BIN_EDGES)] + [f"{BIN_EDGES[-1]:g}+ m"]


def depth_edges(depth: np.ndarray) -> np.ndarray:
    """(..., H, W) bool: pixels whose true depth differs from a 4-neighbour's by more than
    :data:`EDGE_SHARE` of their own, or that border a pixel with no reading."""
    d = np.asarray(depth, np.float32)
    edge = np.zeros(d.shape, bool)
    for axis in (-1, -2):
        a = np.take(d, np.arange(d.shape[axis] - 1), axis=axis)
        b = np.take(d, np.arange(1, d.shape[axis]), axis=axis)
        jump = (np.abs(a - b) > EDGE_SHARE * np.maximum(np.minimum(a, b), 1e-6)) | ((a > 0) != (b > 0))
        lo = [slice(None)] * d.ndim
        hi = [slice(None)] * d.ndim
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        edge[tuple(lo)] |= jump
        edge[tuple(hi)] |= jump
    return edge


def depth_error_rows(noisy: np.ndarray, corrected: np.ndarray, clean: np.ndarray) -> list[dict]:
    """Rows ``{"where", "pixels", "mae_noisy", "mae_corrected"}`` (m) over the pixels where both the
    noisy and the true depth have a reading: ``where`` is ``all``, each distance bin
    (:func:`bin_labels`, by true depth) and ``edges`` (:func:`depth_edges` of the true depth)."""
    ok = (noisy > 0) & (clean > 0)
    e_noisy, e_corr = np.abs(noisy - clean), np.abs(corrected - clean)
    bins = np.digitize(clean, BIN_EDGES)
    masks = {"all": ok, **{label: ok & (bins == k) for k, label in enumerate(bin_labels())}}
    masks["edges"] = ok & depth_edges(clean)
    rows = []
    for where, mask in masks.items():
        n = int(mask.sum())
        if n:
            rows.append(
                {
                    "where": where,
                    "pixels": n,
                    "mae_noisy": float(e_noisy[mask].mean()),
                    "mae_corrected": float(e_corr[mask].mean()),
                }
            )
    return rows


def loss_fn(
    corrected: torch.Tensor, spread: torch.Tensor, noisy: torch.Tensor, clean: torch.Tensor, spread_weight: float
) -> torch.Tensor:
    """Mean absolute error of ``corrected`` against ``clean`` (m) + ``spread_weight`` x the Laplace
    negative log-likelihood of the (detached) error under ``spread``, over pixels where both ``noisy``
    and ``clean`` have a reading."""
    ok = (noisy > 0) & (clean > 0)
    err = (corrected - clean).abs()[ok]
    b = spread[ok]
    return err.mean() + spread_weight * (err.detach() / b + torch.log(b)).mean()


def write_report(folder: Path, rows: list[dict], status: dict, final: bool = True) -> None:
    """``curves.csv`` (every row), ``curves.png`` (validation MAE of the noisy and corrected depth per
    distance bin and on edges, mm) and ``training.json``, each written atomically into ``folder``;
    ``final=False`` (after an epoch) keeps a figure drawn less than a minute ago (:meth:`Curves.plot`)."""
    from odolab.io.atomic import write_bytes_atomic

    folder = Path(folder)
    curves = Curves(rows)
    curves.to_csv(folder / "curves.csv")
    curves.plot(
        folder / "curves.png",
        x="epoch",
        series={
            "mae_noisy": {"label": "noisy depth", "color": "0.5", "linestyle": "--"},
            "mae_corrected": {"label": "corrected", "color": "C0"},
        },
        rows="split",
        cols="where",
        where={"split": "val"},
        ylabel={k: "mean abs. error [mm]" for k in ["all", *bin_labels(), "edges"]},
        scale={k: 1000.0 for k in ["all", *bin_labels(), "edges"]},
        title="Depth corrector: validation depth error after each epoch (val split)",
        wrap=4,
        final=final,
    )
    write_bytes_atomic(folder / "training.json", (json.dumps(status, indent=1) + "\n").encode())


def crop_batch(
    data: TrainingData, frames: np.ndarray, top: int, left: int, height: int, width: int
) -> tuple[torch.Tensor, ...]:
    """RGB (B, h, w, 3) uint8, noisy and true depth (B, h, w) m, and the pixels' place (B, 2, h, w)
    of the window (``top``, ``left``, ``height``, ``width``) of ``frames``."""
    rgb, depth = data.frames(frames)
    clean = data.clean_depths(frames)
    window = (slice(None), slice(top, top + height), slice(left, left + width))
    full = depth.shape[1:]
    place = pixel_place(height, width, top, left, full)[None].expand(len(frames), -1, -1, -1)
    return (
        torch.from_numpy(np.ascontiguousarray(rgb[window])),
        torch.from_numpy(np.ascontiguousarray(depth[window])),
        torch.from_numpy(np.ascontiguousarray(clean[window])),
        place,
    )


def run(
    cfg: CorrectorTraining,
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
        raise ValueError(f"--workers {workers}: the depth corrector trains in one process; leave --workers out")
    if cfg.init:
        raise ValueError("recipe: init: the depth corrector starts from fresh weights; set init = ''")
    for dc in (cfg.train_data, cfg.val_data):
        make_training_data(dc, cfg.data_folder(dc), execution=execution)
        TrainingData(cfg.data_folder(dc)).verify(execution.progress)
    deadline = time.monotonic() + hours * 3600 if hours else None
    train, val = (TrainingData(cfg.data_folder(dc)) for dc in (cfg.train_data, cfg.val_data))
    rng = np.random.default_rng(cfg.seed)
    val_frames = np.arange(len(val.poses))
    if len(val_frames) > cfg.val_frames:
        val_frames = np.sort(rng.choice(val_frames, cfg.val_frames, replace=False))
    compute = cfg.compute.resolve(device)
    torch.manual_seed(cfg.seed)
    net = compute.prepare(DepthCorrectorNet(cfg.model)).to(device)
    recipe = json.loads(json.dumps(dataclasses.asdict(cfg)))
    identity = {k: v for k, v in recipe.items() if k not in ("epochs", "init", "compute", "data_root")}
    optimizer = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    loop = EpochLoop(
        work / "depth-corrector.pt", {"net": net}, optimizer, cfg.epochs, cfg.seed, identity, unit="frames"
    )
    loop.resume()
    H, W = cfg.model.height, cfg.model.width

    def train_epoch(epoch: int, rng: np.random.Generator, tracker: EpochTracker) -> dict:
        order = rng.integers(0, len(train.poses), cfg.frames_per_epoch)
        tops = rng.integers(0, H - cfg.crop_height + 1, len(order))
        lefts = rng.integers(0, W - cfg.crop_width + 1, len(order))
        starts = list(range(0, len(order), cfg.batch))[tracker.start :]
        bar = tqdm(
            total=len(order),
            initial=tracker.samples,
            desc=f"depth corrector epoch {epoch}",
            unit="frame",
            disable=not execution.progress,
            leave=False,
        )
        for k in starts:
            frames = np.sort(order[k : k + cfg.batch])
            rgb, noisy, clean, place = (
                t.to(device)
                for t in crop_batch(train, frames, int(tops[k]), int(lefts[k]), cfg.crop_height, cfg.crop_width)
            )
            with compute.autocast():
                corrected, spread = net(rgb, noisy, place)
            loss = loss_fn(corrected.float(), spread.float(), noisy, clean, cfg.spread_weight)
            require_finite(loss, epoch)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            bar.update(len(frames))
            tracker.add(loss.item(), len(frames))
        bar.close()
        return {}

    def validate(epoch: int) -> list[dict]:
        noisy_all, corr_all, clean_all = [], [], []
        for k in range(0, len(val_frames), 8):
            frames = val_frames[k : k + 8]
            rgb, noisy, clean, place = crop_batch(val, frames, 0, 0, H, W)
            corrected, _ = net(rgb.to(device), noisy.to(device), place.to(device))
            noisy_all.append(noisy.numpy())
            corr_all.append(corrected.float().cpu().numpy())
            clean_all.append(clean.numpy())
        return depth_error_rows(*(np.concatenate(a) for a in (noisy_all, corr_all, clean_all)))

    def status() -> dict:
        return {
            "command": command,
            "compute": compute.describe(),
            "train_frames": len(train.poses),
            "val_frames": len(val_frames),
            "epochs_done": loop.epoch,
            "epochs": loop.epochs,
            "hours": round(loop.seconds / 3600, 3),
            "frames_seen": int(sum(r.get("frames", 0) for r in loop.curves.rows if r.get("split") == "train")),
        }

    def after(_: EpochLoop) -> None:
        write_report(reports, loop.curves.rows, status(), final=False)

    try:
        finished = loop.run(train_epoch, validate, deadline=deadline, after_epoch=after)
    finally:  # stopped or interrupted too: the figure shows every finished epoch
        write_report(reports, loop.curves.rows, status())
    if finished:
        save_model(export, cfg, net.cpu(), status())
    return finished


def state_files(cfg: CorrectorTraining, work: Path) -> dict[str, Path]:
    """Where the training keeps its state (what ``--export`` must never replace)."""
    return {"the depth corrector's training": work / "depth-corrector.pt"}


#: What the training command line (odolab.cli.train) needs of this trainer.
TRAINER = Trainer(
    family="depth-corrector",
    description=__doc__.split("\n")[0],
    load_config=load_training,
    run=run,
    state_files=state_files,
    set_example="seed=1 --set epochs=2",
)


if __name__ == "__main__":  # python -m odolab.learned.depth_corrector.train: the command line is odolab.cli.train's
    import importlib

    train = importlib.import_module("odolab.cli.train")
    train.exit_process(train.command("depth-corrector"))
