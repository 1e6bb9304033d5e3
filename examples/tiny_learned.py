"""A tiny learned odometer, trained on simulator episodes through ``odolab.api`` only.

A 4.5k-parameter CNN sees the previous and current depth and grey images, average-pooled to
24 x 40, and the action; it predicts the planar motion ``(dx, dz, dyaw)`` as the action's nominal
motion plus a learned correction. It is a demonstration of the API (episodes, pair dataset,
checkpoints, options, batched steps), not a good odometer: trained for seconds on a few episodes.

Train (from the repository root), then compare it with the built-ins::

    python -m examples.tiny_learned --episodes 8 --max-steps 40 --iterations 300 --out runs/tiny.pt
    python -m odolab.compare --odometers action-prior,examples.tiny_learned:TinyLearnedOdometer \\
        --odometer-option examples.tiny_learned:TinyLearnedOdometer.checkpoint=runs/tiny.pt

The checkpoint is ``{"format": 1, "config": {...}, "state_dict": {...}}`` written with
``torch.save`` and read with ``torch.load(weights_only=True)`` (no pickled code is executed).
"""

from __future__ import annotations

import argparse
import io
import os
import sys
from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn

from odolab.api import (
    DEFAULT_CACHE,
    MOTION_ACTIONS,
    SERIAL,
    Action,
    EpisodeCache,
    Estimate,
    Frame,
    Odometer,
    PairDataset,
    episode_specs,
    generate_episodes,
    nominal_planar,
    write_bytes_atomic,
)

CHECKPOINT_FORMAT = 1
#: Scale of the learned correction: (dx m, dz m, dyaw rad) per unit of network output.
CORRECTION_SCALE = (0.1, 0.1, 0.2)


@dataclass(frozen=True)
class TinyConfig:
    """Network shape: pooled image size (pixels) and convolution width; ``max_depth`` (m) scales depth."""

    height: int = 24
    width: int = 40
    channels: int = 8
    max_depth: float = 10.0


class TinyNet(nn.Module):
    """(B, 4, H, W) images + (B, 3) action one-hot -> (B, 3) correction to the nominal motion."""

    def __init__(self, cfg: TinyConfig) -> None:
        super().__init__()
        c = cfg.channels
        self.features = nn.Sequential(
            nn.Conv2d(4, c, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(c, 2 * c, 3, stride=2, padding=1),
            nn.ReLU(),
            nn.Conv2d(2 * c, 2 * c, 3, stride=2, padding=1),
            nn.ReLU(),
            nn.AdaptiveAvgPool2d(1),
            nn.Flatten(),
        )
        self.head = nn.Sequential(nn.Linear(2 * c + len(MOTION_ACTIONS), 32), nn.ReLU(), nn.Linear(32, 3))

    def forward(self, images: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        return self.head(torch.cat([self.features(images), actions], dim=1))


def network_inputs(
    pairs: list[tuple[Frame, Frame, Action | None]], cfg: TinyConfig
) -> tuple[torch.Tensor, torch.Tensor]:
    """Pooled (B, 4, H, W) inputs [depth prev, depth cur, grey prev, grey cur] in [0, 1] and (B, 3) one-hots."""

    def planes(frame: Frame) -> list[np.ndarray]:
        depth = np.clip(np.asarray(frame.depth, np.float32) / cfg.max_depth, 0.0, 1.0)
        grey = np.asarray(frame.rgb, np.float32).mean(axis=2) / 255.0
        return [depth, grey]

    stacked = np.stack([np.stack([a for pair in zip(planes(p), planes(c)) for a in pair]) for p, c, _ in pairs])
    images = nn.functional.adaptive_avg_pool2d(torch.from_numpy(stacked), (cfg.height, cfg.width))
    onehot = torch.zeros(len(pairs), len(MOTION_ACTIONS))
    for k, (_, _, action) in enumerate(pairs):
        if action in MOTION_ACTIONS:
            onehot[k, MOTION_ACTIONS.index(action)] = 1.0
    return images, onehot


def planar_from_output(out: torch.Tensor, actions: list[Action | None]) -> torch.Tensor:
    """(B, 3) network outputs -> (B, 3) planar motions (m, m, rad): nominal + scaled correction."""
    nominal = torch.tensor([nominal_planar(a) for a in actions], dtype=out.dtype)
    return nominal + out * torch.tensor(CORRECTION_SCALE, dtype=out.dtype)


class TinyLearnedOdometer(Odometer):
    """The tiny CNN as an odometer. Options: ``checkpoint`` (path, required), ``threads`` (torch
    threads while it runs, default 1: see :mod:`odolab.running.threads`), ``batch_size`` (pairs per forward pass)."""

    def __init__(self, checkpoint: str, threads: int = 1, batch_size: int = 8) -> None:
        if int(threads) < 1 or int(batch_size) < 1:
            raise ValueError(f"threads and batch_size must be >= 1, got {threads} and {batch_size}")
        self.threads, self.batch_size = int(threads), int(batch_size)
        self.config, self.net = load_checkpoint(checkpoint)

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate:
        return self.step_batch([(prev, cur, action)])[0]

    def step_batch(self, pairs: list[tuple[Frame, Frame, Action | None]]) -> list[Estimate]:
        with torch.inference_mode():
            planar = planar_from_output(self.net(*network_inputs(pairs, self.config)), [a for _, _, a in pairs])
        return [Estimate.from_planar(*map(float, row)) for row in planar]


def save_checkpoint(path: str | os.PathLike, cfg: TinyConfig, net: TinyNet) -> None:
    """Write the weights and the config (plain tensors, numbers and strings) atomically."""
    buffer = io.BytesIO()
    torch.save({"format": CHECKPOINT_FORMAT, "config": asdict(cfg), "state_dict": net.state_dict()}, buffer)
    write_bytes_atomic(path, buffer.getvalue())


def load_checkpoint(path: str | os.PathLike) -> tuple[TinyConfig, TinyNet]:
    """Read a checkpoint with ``torch.load(weights_only=True)``; ``ValueError`` names what is wrong."""
    doc = torch.load(path, map_location="cpu", weights_only=True)
    if not isinstance(doc, dict) or doc.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{path}: not a tiny_learned checkpoint of format {CHECKPOINT_FORMAT}")
    cfg = TinyConfig(**doc["config"])
    net = TinyNet(cfg)
    net.load_state_dict(doc["state_dict"])
    return cfg, net.eval()


class TorchPairs(torch.utils.data.Dataset):
    """A :class:`~odolab.api.PairDataset` as a torch ``Dataset`` of (images, action one-hot, planar target)."""

    def __init__(self, pairs: PairDataset, cfg: TinyConfig) -> None:
        self.pairs, self.cfg = pairs, cfg

    def __len__(self) -> int:
        return len(self.pairs)

    def __getitem__(self, k: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, int]:
        p = self.pairs[k]
        images, onehot = network_inputs([(p.prev, p.cur, p.action)], self.cfg)
        return images[0], onehot[0], torch.tensor(p.planar, dtype=torch.float32), p.action.value


def train(
    dataset: PairDataset, cfg: TinyConfig, iterations: int, batch: int = 32, lr: float = 3e-3, seed: int = 0
) -> TinyNet:
    """Fit the network to the true planar motions of ``dataset`` (L1 on the scaled correction)."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    data = TorchPairs(dataset, cfg)
    # a few episodes: every pooled input fits in memory, so read each pair once
    images, onehot, target, action_values = torch.utils.data.default_collate([data[k] for k in range(len(data))])
    actions = [Action(int(v)) for v in action_values]
    net = TinyNet(cfg)
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    scale = torch.tensor(CORRECTION_SCALE)
    for _ in range(iterations):
        idx = rng.integers(len(data), size=min(batch, len(data)))
        pred = planar_from_output(net(images[idx], onehot[idx]), [actions[i] for i in idx])
        loss = ((pred - target[idx]).abs() / scale).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return net.eval()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m examples.tiny_learned", description="Train the tiny learned odometer.")
    ap.add_argument("--episodes", type=int, default=8, help="train-split episodes (default 8)")
    ap.add_argument("--max-steps", type=int, default=40, help="steps per episode (default 40)")
    ap.add_argument("--iterations", type=int, default=300, help="optimiser steps (default 300)")
    ap.add_argument("--seed", type=int, default=0, help="episode and training seed (default 0)")
    ap.add_argument("--cache", default=str(DEFAULT_CACHE), help=f"episode cache folder (default {DEFAULT_CACHE})")
    ap.add_argument("--out", default="runs/tiny.pt", help="checkpoint path (default runs/tiny.pt)")
    args = ap.parse_args(argv)
    for option, value, top in (
        ("--episodes", args.episodes, 1000),
        ("--max-steps", args.max_steps, 500),
        ("--iterations", args.iterations, 1_000_000),
    ):
        if not 1 <= value <= top:
            ap.error(f"{option} must be in [1, {top}], got {value}")
    if not 0 <= args.seed <= 2**32 - 1:
        ap.error(f"--seed must be in [0, 4294967295], got {args.seed}")
    torch.set_num_threads(1)
    specs = episode_specs("train", args.episodes, seed=args.seed, max_steps=args.max_steps)
    cache = EpisodeCache(args.cache)
    generate_episodes(specs, cache, execution=SERIAL)
    dataset = PairDataset(specs, cache)
    cfg = TinyConfig()
    net = train(dataset, cfg, args.iterations, seed=args.seed)
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    save_checkpoint(args.out, cfg, net)
    print(
        f"trained on {len(dataset)} pairs of {args.episodes} episodes, "
        f"{sum(p.numel() for p in net.parameters())} parameters; wrote {args.out}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
