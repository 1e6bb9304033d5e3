"""A resumable epoch loop: after every epoch the models, the optimiser, the epoch number and the
curves are saved atomically, so a killed run loses at most the epoch in progress and a rerun goes on
from the last saved epoch with the same numbers (each epoch's randomness is seeded by (seed, epoch))."""
from __future__ import annotations

import os
import time
from typing import Any, Callable

import numpy as np
import torch
from torch import nn

from odolab.learning.checkpoints import load_checkpoint, save_checkpoint
from odolab.learning.curves import Curves

STATE_KIND = "odolab-training-state"
STATE_FORMAT = 1


_ABSENT = object()


def differences(saved: Any, now: Any, where: str = "") -> list[str]:
    """Dotted paths where two plain-data documents differ, as ``path (saved X, now Y)``; a key one
    side lacks shows as ``unset`` (a switch at its default is left out of identities)."""
    if isinstance(saved, dict) and isinstance(now, dict):
        return [d for k in sorted(set(saved) | set(now), key=str)
                for d in differences(saved.get(k, _ABSENT), now.get(k, _ABSENT), f"{where}.{k}" if where else str(k))]
    if isinstance(saved, list) and isinstance(now, list) and len(saved) == len(now):
        return [d for i, (a, b) in enumerate(zip(saved, now)) for d in differences(a, b, f"{where}[{i}]")]

    def show(v: Any) -> str:
        return "unset" if v is _ABSENT else repr(v)

    return [] if saved == now else [f"{where or 'all'} (saved {show(saved)}, now {show(now)})"]


def require_finite(loss: torch.Tensor, epoch: int) -> None:
    """``ValueError`` when a training loss is NaN or infinite (a learning rate too high, a bad
    weight): the epoch in progress is dropped, the last saved one is kept."""
    if not torch.isfinite(loss).all():
        raise ValueError(f"the training loss became {loss.item()} in epoch {epoch}; nothing of that epoch was "
                         "saved (is the learning rate or a loss weight too large?)")


class StopRequested(Exception):
    """Raised inside an epoch to stop training cleanly (the epoch in progress is not saved)."""


class EpochLoop:
    """Train ``modules`` with ``optimizer`` for ``epochs`` epochs, saving to ``path`` after each.

    ``identity``: plain data describing the run (config, data); a saved state made for another
    identity is refused, so a changed config never silently continues an old run.
    """

    def __init__(self, path: str | os.PathLike, modules: dict[str, nn.Module], optimizer: torch.optim.Optimizer,
                 epochs: int, seed: int, identity: dict[str, Any]) -> None:
        self.path, self.modules, self.optimizer = path, modules, optimizer
        self.epochs, self.seed, self.identity = int(epochs), int(seed), identity
        self.curves = Curves()
        self.epoch = 0  # epochs done
        self.seconds = 0.0  # training time spent so far, over all chunks

    def resume(self) -> int:
        """Load the saved state if there is one; returns the number of epochs already done."""
        if not os.path.exists(self.path):
            return 0
        try:
            doc = load_checkpoint(self.path, STATE_KIND, STATE_FORMAT)
        except ValueError as exc:
            raise ValueError(f"{exc}; delete it to start this training over") from None
        if doc["identity"] != self.identity:
            changed = differences(doc["identity"], self.identity)
            raise ValueError(f"{self.path}: saved training state belongs to another run (differs in: "
                             f"{'; '.join(changed[:4])}); delete it or use another work folder")
        for name, module in self.modules.items():
            module.load_state_dict(doc["modules"][name])
        self.optimizer.load_state_dict(doc["optimizer"])
        self.epoch, self.seconds = int(doc["epoch"]), float(doc["seconds"])
        self.curves = Curves(doc["curves"])
        return self.epoch

    def save(self) -> None:
        save_checkpoint(self.path, STATE_KIND, STATE_FORMAT, {
            "identity": self.identity, "epoch": self.epoch, "seconds": self.seconds, "curves": self.curves.rows,
            "modules": {n: m.state_dict() for n, m in self.modules.items()}, "optimizer": self.optimizer.state_dict()})

    @property
    def finished(self) -> bool:
        return self.epoch >= self.epochs

    def run(self, train_epoch: Callable[[int, np.random.Generator], dict[str, Any]],
            validate: Callable[[int], list[dict[str, Any]]], *, deadline: float | None = None,
            after_epoch: Callable[["EpochLoop"], None] | None = None) -> bool:
        """Run the remaining epochs; ``train_epoch(epoch, rng)`` returns training numbers (one curve
        row), ``validate(epoch)`` validation rows. Stops before an epoch that would start after
        ``deadline`` (``time.monotonic()`` seconds). Returns True when all epochs are done."""
        while not self.finished:
            if deadline is not None and time.monotonic() >= deadline:
                return False
            epoch = self.epoch + 1
            torch.manual_seed(self.seed * 100_003 + epoch)
            rng = np.random.default_rng([self.seed, epoch])
            started = time.monotonic()
            for m in self.modules.values():
                m.train()
            try:
                train_row = train_epoch(epoch, rng)
            except StopRequested:
                return False
            for m in self.modules.values():
                m.eval()
            with torch.inference_mode():
                val_rows = validate(epoch)
            self.seconds += time.monotonic() - started
            self.curves.add([{"epoch": epoch, "split": "train", **train_row}] + [{"epoch": epoch, "split": "val", **r}
                                                                                  for r in val_rows])
            self.epoch = epoch
            self.save()
            if after_epoch is not None:
                after_epoch(self)
        return True
