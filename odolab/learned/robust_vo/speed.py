"""Training throughput of a robust-VO recipe, against the bare network step from the same run.

``bare``: one network (the forward one), a batch of the recipe's first stage of random inputs
resident in the device's memory, forward + MSE + backward + Adam, in the chosen precision and memory
format and in fp32 beside it. ``end_to_end``: the trainer's own epoch
(:meth:`StageRunner.train_epoch`: shard reads, swaps and mirrors, the nominal warp, psi, the batch
made by the loader workers or, on a GPU, its inputs made on the GPU, the step) on a few real
episodes, worker start-up included. The end-to-end rate over the bare one says how much the
rest of training costs (at least 0.7 is wanted). Beside them, one network's forward pass at batch 1
(what the odometer's speed is bound by) in fp32 and bf16, and the input normaliser's batch moments
(:func:`odolab.learned.robust_vo.model.batch_moments`) against ``Tensor.mean`` and ``Tensor.var``.
"""

from __future__ import annotations

import dataclasses
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import torch

from odolab.learned.robust_vo.batches import stage_samples
from odolab.learned.robust_vo.config import TrainConfig
from odolab.learned.robust_vo.model import VONet, batch_moments
from odolab.learned.training import SERIAL, Compute, EpochLoop, TrainingData, make_training_data
from odolab.learned.training.epochs import EpochTracker


def bare_pairs_per_s(cfg: TrainConfig, compute: Compute, steps: int = 6) -> float:
    """Pairs per second of the bare training step (module docstring); the median of ``steps``
    timed steps after one warm-up step."""
    model, batch = cfg.model, cfg.stages[0].batch
    torch.manual_seed(0)
    net = compute.prepare(VONet(model))
    net.train()
    opt = torch.optim.Adam(net.parameters(), lr=1e-4)
    x = compute.inputs(torch.rand(batch, model.input_channels, model.height, model.width))
    y = torch.rand(batch, 3, device=compute.device)
    times = []
    for _ in range(steps + 1):
        started = time.perf_counter()
        with compute.autocast():
            pred = net(x)
        loss = (pred.float() - y).pow(2).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if compute.device.type == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - started)
    return batch / float(np.median(times[1:]))


def inference_steps_per_s(cfg: TrainConfig, compute: Compute, steps: int = 20) -> float:
    """Pairs per second of one network's forward pass at batch 1 (the odometer's network alone,
    without resizing, warp or psi), in ``compute``'s precision; median of ``steps`` calls."""
    torch.manual_seed(0)
    net = compute.prepare(VONet(cfg.model)).eval()
    x = torch.rand(1, cfg.model.input_channels, cfg.model.height, cfg.model.width)

    def forward() -> None:
        with compute.autocast():
            net(compute.inputs(x))

    return calls_per_s(forward, steps)


def calls_per_s(call: Callable[[], object], calls: int = 20, warmup: int = 2) -> float:
    """Calls per second of ``call()`` under ``torch.inference_mode``: the median of ``calls`` timed
    calls after ``warmup`` untimed ones."""
    with torch.inference_mode():
        for _ in range(warmup):
            call()
        times = []
        for _ in range(calls):
            started = time.perf_counter()
            call()
            times.append(time.perf_counter() - started)
    return 1.0 / float(np.median(times))


def moments_ms(cfg: TrainConfig, repeats: int = 5) -> dict[str, float]:
    """Milliseconds (median of ``repeats``) for one training batch's per-channel mean and variance:
    the normaliser's ``batch_moments`` and ``Tensor.mean`` + ``Tensor.var``, on random inputs."""
    model = cfg.model
    x = torch.rand(cfg.stages[0].batch, model.input_channels, model.height, model.width)
    ways = {
        "normaliser_moments_ms": lambda: batch_moments(x),
        "tensor_var_moments_ms": lambda: (x.mean(dim=(0, 2, 3)), x.var(dim=(0, 2, 3), unbiased=False)),
    }
    times: dict[str, list[float]] = {k: [] for k in ways}
    for _ in range(repeats):
        for k, way in ways.items():
            started = time.perf_counter()
            way()
            times[k].append(time.perf_counter() - started)
    return {k: 1e3 * float(np.median(t)) for k, t in times.items()}


def bench_data(cfg: TrainConfig, folder: Path, episodes: int = 20) -> TrainingData:
    """A few val episodes at the recipe's size, made in ``folder`` (in this process)."""
    small = dataclasses.replace(cfg.val_data, episodes=episodes)
    make_training_data(small, folder, execution=SERIAL)
    return TrainingData(folder)


def open_bench_data(folder: str, recipes: Sequence[tuple[str, TrainConfig]]) -> Path:
    """The training-data folder ``folder`` checked for timing ``recipes`` (name, recipe) end to end:
    one frame size for all, every shard intact, pairs for each recipe's first stage. Returns its
    absolute path; ``ValueError`` naming the folder and what is wrong."""
    if not folder.strip():
        raise ValueError("expected a training-data folder (python -m odolab.training_data --out FOLDER), got ''")
    path = Path(folder)
    if not path.is_dir():
        raise ValueError(f"{folder}: {'not a folder' if path.exists() else 'no such folder'}")
    sizes = dict.fromkeys(f"{c.model.width} x {c.model.height}" for _, c in recipes)
    if len(sizes) > 1:
        raise ValueError(f"one data folder serves recipes of one frame size; these take {' and '.join(sizes)}")
    data = TrainingData(path)
    try:
        data.config.require_size(recipes[0][1].model.width, recipes[0][1].model.height)
    except ValueError as exc:
        raise ValueError(f"{folder}: {exc}") from None
    data.verify()
    for name, cfg in recipes:
        stage = cfg.stages[0]
        if not len(stage_samples(data, stage)):
            raise ValueError(
                f"{folder}: no pairs for the first stage ({stage.name!r}: {', '.join(stage.actions)}) of recipe {name}"
            )
    return path.absolute()


def end_to_end_pairs_per_s(cfg: TrainConfig, compute: Compute, data: TrainingData, steps: int = 24) -> float:
    """Pairs per second of the trainer's own epoch over ``steps`` batches of the first stage (the
    stage's samples repeated in order where ``data`` holds fewer)."""
    from odolab.learned.robust_vo.model import build_networks
    from odolab.learned.robust_vo.train import StageRunner

    stage = dataclasses.replace(cfg.stages[0], pairs_per_epoch=steps * cfg.stages[0].batch)
    torch.manual_seed(0)
    nets = compute.prepare(build_networks(cfg.model))
    runner = StageRunner(cfg, stage, data, data, nets, compute, progress=False)
    runner.samples = runner.samples.take(np.resize(np.arange(len(runner.samples)), stage.pairs_per_epoch))
    loop = EpochLoop(
        Path(tempfile.gettempdir()) / "unused.pt", dict(nets), runner.optimizer, 1, 0, {}, save_every=float("inf")
    )
    tracker = EpochTracker(loop, "pairs", None, None)
    nets.train()
    runner.train_epoch(1, np.random.default_rng(0), tracker)
    return tracker.samples / tracker.seconds


def training_speed(
    cfg: TrainConfig, name: str, device: torch.device, steps: int = 24, data_folder: Path | None = None
) -> dict:
    """One row of ``python -m odolab.bench --only training`` for recipe ``cfg`` (called ``name``), its
    end-to-end part on ``data_folder`` (training data of the recipe's frame size) or, by default, on
    20 val episodes rendered for it."""
    from odolab.learned.training import choose_compute

    compute = cfg.compute.resolve(device)
    fp32 = choose_compute(device, "fp32", compute.memory_format)
    with tempfile.TemporaryDirectory(prefix="odolab-bench-") as tmp:
        if data_folder is None:
            data = bench_data(cfg, Path(tmp))
        else:
            data = TrainingData(data_folder)  # checked by open_bench_data
            data.config.require_size(cfg.model.width, cfg.model.height)
        distinct = len(stage_samples(data, cfg.stages[0]))
        fp32_bare = bare_pairs_per_s(cfg, fp32)
        bare = fp32_bare if compute == fp32 else bare_pairs_per_s(cfg, compute)
        end_to_end = end_to_end_pairs_per_s(cfg, compute, data, steps)
        # the batches made in the training process, between steps and in a thread beside the step
        ways = {t: dataclasses.replace(compute, loader_workers=0, loader_thread=t) for t in (False, True)}
        in_process = {
            t: end_to_end if c == compute else end_to_end_pairs_per_s(cfg, c, data, steps) for t, c in ways.items()
        }
        infer = {p: inference_steps_per_s(cfg, choose_compute(device, p)) for p in ("fp32", "bf16")}
        moments = moments_ms(cfg)
    m = cfg.model
    return {
        "config": name,
        "input": f"{m.width}x{m.height}",
        "base_planes": m.base_planes,
        "batch": cfg.stages[0].batch,
        "device": str(device),
        "device_name": torch.cuda.get_device_name(device) if device.type == "cuda" else "",
        "data": "20 rendered val episodes" if data_folder is None else str(data_folder),
        "data_pairs": distinct,  # the first stage's samples in the data (repeated where fewer than timed)
        "threads": torch.get_num_threads(),
        "precision": compute.precision,
        "memory_format": compute.memory_format,
        "loader_workers": compute.loader_workers,
        "loader_thread": compute.loader_thread,
        "bare_pairs_per_s": bare,
        "end_to_end_pairs_per_s": end_to_end,
        "end_to_end_between_steps_pairs_per_s": in_process[False],
        "end_to_end_thread_pairs_per_s": in_process[True],
        "fp32_bare_pairs_per_s": fp32_bare,
        "end_to_end_over_bare": end_to_end / bare,
        "params_per_network": sum(p.numel() for p in VONet(m).parameters()),
        "net_batch1_fp32_steps_per_s": infer["fp32"],
        "net_batch1_bf16_steps_per_s": infer["bf16"],
        **moments,
    }
