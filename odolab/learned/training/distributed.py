"""Data-parallel training on Ray Train: N workers (processes on one machine or on a cluster's
nodes) each take an equal share of every global batch, their gradients are averaged, so N workers
follow the one-worker run up to floating-point order. Ray Train's ``TorchTrainer`` starts the workers
and the process group (gloo on CPUs, nccl on GPUs); the trainers' own loop does the rest.

Every worker reads the same data and state folders, so on a cluster they must be on storage that
all nodes share. Worker 0 (the leader) validates, saves the states and writes the reports.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch


@dataclass(frozen=True)
class Team:
    """This process's place among ``size`` data-parallel workers (``rank`` 0 leads); the default
    is training alone."""

    rank: int = 0
    size: int = 1

    @property
    def leader(self) -> bool:
        return self.rank == 0

    def share(self, items: np.ndarray) -> np.ndarray:
        """This worker's part of a global batch: every ``size``-th item from ``rank`` on."""
        return items[self.rank :: self.size]

    def sum(self, t: torch.Tensor) -> torch.Tensor:
        """``t`` summed over the workers (in place; ``t`` alone when training alone)."""
        if self.size > 1:
            torch.distributed.all_reduce(t)
        return t

    def any(self, flag: bool) -> bool:
        """Whether any worker says ``flag`` (every worker gets the same answer)."""
        if self.size == 1:
            return flag
        return bool(self.sum(torch.tensor([float(flag)])).item() > 0)

    def average_gradients(self, params: Iterable[torch.nn.Parameter], local: int) -> None:
        """Gradients of the mean loss over the global batch, from each worker's gradients of its mean
        over ``local`` samples (weighted by ``local``: shares may differ by one; a parameter this
        worker did not use counts as a zero gradient)."""
        if self.size == 1:
            return
        params = list(params)
        grads = [p.grad if p.grad is not None else torch.zeros_like(p) for p in params]
        flat = torch.cat([g.reshape(-1) for g in grads] + [torch.tensor([1.0], device=grads[0].device)]) * local
        self.sum(flat)
        total = flat[-1]
        offset = 0
        for p, g in zip(params, grads):
            n = g.numel()
            p.grad = (flat[offset : offset + n] / total).view_as(g).clone()
            offset += n

    def average_buffers(self, modules: Iterable[torch.nn.Module]) -> None:
        """Floating-point buffers (running input statistics) averaged over the workers, so that every
        worker normalises alike (the average of each worker's running merge of its own shares)."""
        if self.size == 1:
            return
        buffers = [b for m in modules for b in m.buffers() if b.is_floating_point()]
        flat = self.sum(torch.cat([b.reshape(-1) for b in buffers])) / self.size
        offset = 0
        for b in buffers:
            b.copy_(flat[offset : offset + b.numel()].view_as(b))
            offset += b.numel()


def run_on_ray(
    loop: Callable[[dict[str, Any]], Any],
    config: dict[str, Any],
    *,
    workers: int,
    work: Path,
    export: Path,
    ray_address: str | None = None,
    gpus_per_worker: float = 0.0,
) -> bool:
    """Run ``loop(config)`` in ``workers`` Ray Train workers (``config["team"]`` set to each one's
    :class:`Team`), on the cluster at ``ray_address`` or a local instance; Ray Train's own records go
    under ``work/ray``. Returns whether the leader wrote ``export`` (the training finished); a
    worker's error is raised here."""
    import ray
    from ray.train import RunConfig, ScalingConfig
    from ray.train.torch import TorchConfig, TorchTrainer

    from odolab.core.parallel import shutdown_ray, start_ray

    started = start_ray(ray_address, log_to_driver=True)
    use_gpu = gpus_per_worker > 0
    if started and ray_address is None and not os.environ.get("RAY_ADDRESS"):  # a local instance cannot grow
        have = ray.cluster_resources()
        short = [
            f"{need:g} {kind}s, it has {have.get(kind, 0):g}"
            for kind, need in (("CPU", workers), ("GPU", workers * gpus_per_worker))
            if need > have.get(kind, 0) + 1e-9
        ]
        if short:
            shutdown_ray()
            raise ValueError(
                f"{workers} training workers need {'; '.join(short)} on this machine's Ray instance "
                "(Ray Train would wait for them forever); use fewer workers or a cluster"
            )
    resources = {"CPU": 1, **({"GPU": gpus_per_worker} if use_gpu else {})}
    trainer = TorchTrainer(
        _worker,
        train_loop_config={"loop": loop, "config": config},
        torch_config=TorchConfig(backend="nccl" if use_gpu else "gloo"),
        scaling_config=ScalingConfig(num_workers=workers, use_gpu=use_gpu, resources_per_worker=resources),
        run_config=RunConfig(storage_path=str((work / "ray").resolve()), name="train"),
    )
    before = _stamp(export)
    try:
        trainer.fit()
    finally:
        if started:
            shutdown_ray()
    return _stamp(export) not in (None, before)


def _stamp(path: Path) -> int | None:
    try:
        return path.stat().st_mtime_ns
    except OSError:
        return None


def _worker(payload: dict[str, Any]) -> None:
    import ray.train

    ctx = ray.train.get_context()
    payload["loop"]({**payload["config"], "team": Team(ctx.get_world_rank(), ctx.get_world_size())})
