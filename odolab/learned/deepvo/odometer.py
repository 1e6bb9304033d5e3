"""The DeepVO baseline as an :class:`~odolab.api.Odometer`, registered as ``deepvo`` (the shipped
model, ``odolab/data/deepvo/deepvo.pt``, made by the first command)::

    python -m odolab.learned.deepvo.train --config studies/deepvo/shipped.toml
    python -m odolab.compare --odometers action-prior,deepvo
    python -m odolab.compare --odometers deepvo --odometer-option deepvo.checkpoint=runs/deepvo/shipped/model.pt

Frames are resized to the model's input (:func:`odolab.learned.training.resize_frame`, as its training data
was); the LSTM state carries from one ``step`` to the next within a sequence and ``reset`` clears
it. DeepVO sees no action (unless its model was trained with ``actions``): it answers on real data
too. A STOP step is answered with no motion (and leaves the state as it is), as the other
odometers do; a model with ``actions`` answers ``valid=False`` where no action is given.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from odolab.api import MAX_THREADS, Action, Estimate, Frame, Intrinsics, Odometer, check, configure, setting
from odolab.learned.deepvo.config import DeepVOModel, DeepVOTraining
from odolab.learned.deepvo.model import DeepVONet, frame_tensor
from odolab.learned.training import checkpoints, pick_device, resize_frame

KIND = "odolab-deepvo"
SHIPPED = Path(__file__).resolve().parents[2] / "data" / "deepvo" / "deepvo.pt"
#: The SHA-256 of the shipped file's bytes, which it must match: it was written before model files
#: carried a checksum inside (re-saving it would change every saved result keyed by its digest).
SHIPPED_SHA256 = "bf1be1d02f97fe2d93ab6aa632c3e5d05900af6d555720ae33854f5ae3acd19a"


def save_model(path, cfg: DeepVOTraining, net: DeepVONet, training: dict) -> None:
    """The network's weights with its model config, the recipe and the training status."""
    checkpoints.save_model(path, KIND, cfg, {"deepvo": net}, training)


def load_model(path) -> tuple[DeepVOModel, DeepVONet, dict]:
    """(model config, network in eval mode, the checkpoint's recipe and training info), read with
    ``weights_only=True``; :class:`~odolab.learned.training.CheckpointError` names the file and problem (a
    damaged file: contents that do not match its checksum, or the shipped model's :data:`SHIPPED_SHA256`)."""
    cfg, nets, info = checkpoints.load_model(
        path, KIND, DeepVOModel, lambda c: {"deepvo": DeepVONet(c)}, checkpoints.Shipped(SHIPPED, SHIPPED_SHA256)
    )
    return cfg, nets["deepvo"], info


@dataclass(frozen=True)
class DeepVOOptions:
    """The options of ``deepvo``; the network itself comes from ``checkpoint``."""

    checkpoint: str = setting("", doc="DeepVO model file (default: the shipped model)")
    threads: int = setting(1, range=(1, MAX_THREADS), doc="torch threads while it runs")
    device: str = setting("", doc="torch device (default cpu)")

    def __post_init__(self) -> None:
        check(self)


class DeepVOOdometer(Odometer):
    """DeepVO. Options: the fields of :class:`DeepVOOptions`."""

    Config = DeepVOOptions  # its options: every field (odolab.odometry.configured)

    def __init__(self, config: DeepVOOptions | None = None, **overrides) -> None:
        opts = configure(DeepVOOptions, config, **overrides)
        self.cfg, self.net, self.info = load_model(opts.checkpoint or SHIPPED)
        self.identity_digest = self.info["sha256"]
        self.device = pick_device(opts.device or "cpu")
        self.net.to(self.device)
        self.threads = int(opts.threads)
        self._state: tuple[torch.Tensor, torch.Tensor] | None = None
        self._last: tuple[np.ndarray, torch.Tensor] | None = None  # (the last frame's pixels, its tensor)
        self.needs_action = self.cfg.actions

    def reset(self, intrinsics: Intrinsics) -> None:
        super().reset(intrinsics)
        self._state, self._last = None, None

    def _frame(self, frame: Frame) -> torch.Tensor:
        if self._last is not None and self._last[0] is frame.rgb:  # the previous step's current frame
            return self._last[1]
        rgb, depth = resize_frame(frame.rgb, frame.depth, self.cfg.width, self.cfg.height)
        x = frame_tensor(rgb, depth, self.cfg)
        self._last = (frame.rgb, x)
        return x

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate:
        if action is Action.STOP:
            return Estimate(np.eye(4))
        if action is None and self.needs_action:
            return Estimate.invalid()
        frames = torch.stack([self._frame(prev), self._frame(cur)])[None].to(self.device)
        actions = torch.tensor([[action.value]], device=self.device) if self.needs_action else None
        with torch.inference_mode():
            out, self._state = self.net(frames, self._state, actions)
        dx, dz, dyaw = (float(v) for v in out[0, 0].cpu())
        return Estimate.from_planar(dx, dz, dyaw)
