"""Training samples of the robust VO: which pairs, which augmentation, and the tensors of a batch."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from odolab.api import FORWARD_STEP, Action, Intrinsics
from odolab.learned.robust_vo.config import ModelConfig, StageConfig
from odolab.learned.robust_vo.inputs import pair_channels
from odolab.learned.robust_vo.motion import inverse, mirror, swap_action
from odolab.learned.robust_vo.warp import warp_pairs
from odolab.learned.training import TrainingData

TURNS = (Action.TURN_LEFT, Action.TURN_RIGHT)


@dataclass(frozen=True)
class Samples:
    """Parallel arrays: pair index into the data, and whether its frames are swapped / mirrored."""

    pair: np.ndarray
    swap: np.ndarray
    flip: np.ndarray

    def __len__(self) -> int:
        return len(self.pair)

    def take(self, k: np.ndarray) -> Samples:
        return Samples(self.pair[k], self.swap[k], self.flip[k])


def stage_samples(data: TrainingData, stage: StageConfig) -> Samples:
    """Every sample of a stage: its actions' pairs, plus (``data_aug``) swapped turn pairs whose new
    action is in the stage, plus (``mirror``) mirrored ones likewise. GeoInv stages swap inside the
    batch instead, so their samples are only the (possibly mirrored) turn pairs. With
    ``blocked_repeat`` k > 1, each forward sample that moved less than half a step appears k times."""
    wanted = {a.value for a in stage.action_set}
    acts = data.pair_actions
    parts = [(np.flatnonzero(np.isin(acts, list(wanted))), False, False)]
    is_turn = np.isin(acts, [a.value for a in TURNS])
    opposite = swap_action(acts) if len(acts) else acts
    in_stage = np.isin(opposite, list(wanted))
    if stage.data_aug and not stage.geoinv:
        parts.append((np.flatnonzero(is_turn & in_stage), True, False))
    if stage.mirror:
        parts.append((np.flatnonzero(in_stage), False, True))
        if stage.data_aug and not stage.geoinv:
            parts.append((np.flatnonzero(is_turn & np.isin(acts, list(wanted))), True, True))
    pair = np.concatenate([p for p, _, _ in parts])
    swap = np.concatenate([np.full(len(p), s) for p, s, _ in parts])
    flip = np.concatenate([np.full(len(p), f) for p, _, f in parts])
    samples = Samples(pair.astype(np.int64), swap.astype(bool), flip.astype(bool))
    if stage.blocked_repeat > 1 and len(samples):
        blocked = (acts[samples.pair] == Action.MOVE_FORWARD.value) & (
            data.pair_planar[samples.pair, 1] < FORWARD_STEP / 2
        )
        extra = np.repeat(np.flatnonzero(blocked), stage.blocked_repeat - 1)
        samples = samples.take(np.concatenate([np.arange(len(samples)), extra]))
    return samples


@dataclass
class Pairs:
    """The frames of a batch as read, after swap and mirror and before the warp and psi: ``rgb``
    (B, 2, H, W, 3) uint8, ``depth`` (B, 2, H, W) float32 m, the action each sample now stands for,
    and true (dx, dz, dyaw). About a ninth of the bytes of the network inputs made from them."""

    rgb: torch.Tensor
    depth: torch.Tensor
    action: np.ndarray
    target: torch.Tensor


@dataclass
class Batch:
    """Network inputs (B, 2C, H, W), the action each sample now stands for, and true (dx, dz, dyaw)."""

    x: torch.Tensor
    action: np.ndarray
    target: torch.Tensor


def read_pairs(data: TrainingData, samples: Samples, swap_all: bool = False) -> Pairs:
    """Read the pairs of ``samples`` and swap, then mirror, them; ``swap_all`` additionally swaps
    every pair (the other half of a GeoInv step)."""
    b = data.pair_batch(samples.pair)
    rgb, depth = b["rgb"], b["depth"]
    target = torch.from_numpy(b["planar"]).to(torch.float32)
    action = b["action"].copy()
    swap = samples.swap ^ swap_all
    flip = samples.flip
    if swap.any():
        rgb[swap], depth[swap] = rgb[swap][:, ::-1], depth[swap][:, ::-1]
        target[swap] = inverse(target[swap])
        action[swap] = swap_action(action[swap])
    if flip.any():
        rgb[flip], depth[flip] = rgb[flip][:, :, :, ::-1], depth[flip][:, :, :, ::-1]
        target[flip] = mirror(target[flip])
        action[flip] = swap_action(action[flip])
    rgb_t, depth_t = torch.from_numpy(np.ascontiguousarray(rgb)), torch.from_numpy(np.ascontiguousarray(depth))
    return Pairs(rgb_t, depth_t, action, target)


def _to(t: torch.Tensor, device: torch.device) -> torch.Tensor:
    """``t`` on ``device``; a CPU tensor bound for a CUDA GPU is pinned first (copied from pinned
    memory several times faster than from ordinary memory)."""
    if device.type == "cuda" and t.device.type == "cpu" and not t.is_pinned():
        t = t.pin_memory()
    return t.to(device, non_blocking=True)


def network_inputs(pairs: Pairs, intrinsics: Intrinsics, cfg: ModelConfig, device: torch.device) -> Batch:
    """The batch of ``pairs`` computed on ``device``: the ``warp`` of the action each sample now
    stands for, then psi (:func:`odolab.learned.robust_vo.inputs.pair_channels`)."""
    rgb, depth = _to(pairs.rgb, device), _to(pairs.depth, device)
    if cfg.warp == "nominal":
        rgb, depth = warp_pairs(rgb, depth, pairs.action, intrinsics)
    x = pair_channels(rgb, depth, intrinsics, cfg)
    return Batch(x, pairs.action, _to(pairs.target, device))


def make_batch(
    data: TrainingData, samples: Samples, cfg: ModelConfig, device: torch.device, swap_all: bool = False
) -> Batch:
    """:func:`read_pairs`, then :func:`network_inputs` on ``device``."""
    return network_inputs(read_pairs(data, samples, swap_all), data.intrinsics, cfg, device)
