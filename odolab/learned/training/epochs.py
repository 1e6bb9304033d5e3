"""A resumable epoch loop: after every epoch the models, the optimiser, the epoch number and the
curves are saved atomically, and within an epoch every ``save_every`` seconds too (the batches done,
the running sums and torch's random state), so a killed run loses at most that much and a rerun goes
on from the last save with the same numbers on the same machine (each epoch's randomness is seeded by
(seed, epoch); the batches of an epoch are made in a fixed order from that seed)."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from torch import nn

from odolab.learned.training.checkpoints import load_checkpoint, save_checkpoint
from odolab.learned.training.curves import Curves
from odolab.learned.training.distributed import Team

STATE_KIND = "odolab-training-state"
#: The layout of a saved state, its identity included; a state of another format is refused.
STATE_FORMAT = 2


_ABSENT = object()


def differences(saved: Any, now: Any, where: str = "") -> list[str]:
    """Dotted paths where two plain-data documents differ, as ``path (saved X, now Y)``; a key one
    side lacks shows as ``unset`` (a switch at its default is left out of identities)."""
    if isinstance(saved, dict) and isinstance(now, dict):
        return [
            d
            for k in sorted(set(saved) | set(now), key=str)
            for d in differences(saved.get(k, _ABSENT), now.get(k, _ABSENT), f"{where}.{k}" if where else str(k))
        ]
    if isinstance(saved, list) and isinstance(now, list) and len(saved) == len(now):
        return [d for i, (a, b) in enumerate(zip(saved, now)) for d in differences(a, b, f"{where}[{i}]")]

    def show(v: Any) -> str:
        return "unset" if v is _ABSENT else repr(v)

    return [] if saved == now else [f"{where or 'all'} (saved {show(saved)}, now {show(now)})"]


def require_finite(loss: torch.Tensor, epoch: int) -> None:
    """``ValueError`` when a training loss is NaN or infinite (a learning rate too high, a bad
    weight): the epoch in progress is dropped, the last saved one is kept."""
    if not torch.isfinite(loss).all():
        raise ValueError(
            f"the training loss became {loss.item()} in epoch {epoch}; nothing of that epoch was "
            "saved (is the learning rate or a loss weight too large?)"
        )


class StopRequested(Exception):
    """Raised inside an epoch to stop training cleanly (what the last save holds is kept)."""


class EpochTracker:
    """The running numbers of the epoch in progress, handed to ``train_epoch``: ``start`` batches
    are already done (skip them), call :meth:`add` after each batch; it saves the loop's state every
    ``save_every`` seconds and stops (:class:`StopRequested`) at the deadline, after saving."""

    def __init__(self, loop: EpochLoop, unit: str, partial: dict[str, Any] | None, deadline: float | None) -> None:
        self.loop, self.unit, self.deadline = loop, unit, deadline
        partial = partial or {}
        self.start = self.batches = int(partial.get("batches", 0))
        self.loss_sum, self.samples = float(partial.get("loss_sum", 0.0)), int(partial.get("samples", 0))
        self.seconds_before = float(partial.get("seconds", 0.0))
        self.started = self.last_save = time.monotonic()

    @property
    def seconds(self) -> float:
        """Training seconds of this epoch so far, over every chunk."""
        return self.seconds_before + time.monotonic() - self.started

    def add(self, loss: float, samples: int) -> None:
        """One batch done: its mean ``loss`` over ``samples`` samples."""
        self.batches += 1
        self.loss_sum += float(loss) * samples
        self.samples += samples
        now = time.monotonic()
        stop = self.loop.team.any(self.deadline is not None and now >= self.deadline)
        if stop or now - self.last_save >= self.loop.save_every:
            self.loop.save(partial=self.partial())
            self.last_save = now
        if stop:
            raise StopRequested()

    def partial(self) -> dict[str, Any]:
        return {
            "batches": self.batches,
            "loss_sum": self.loss_sum,
            "samples": self.samples,
            "seconds": self.seconds,
            "torch_rng": torch.get_rng_state(),
        }

    def row(self) -> dict[str, Any]:
        """The epoch's training numbers: mean loss, samples and samples per second (``unit`` names them)."""
        return {
            "loss": self.loss_sum / max(self.samples, 1),
            self.unit: self.samples,
            f"{self.unit}_per_s": self.samples / max(self.seconds, 1e-9),
        }


class EpochLoop:
    """Train ``modules`` with ``optimizer`` for ``epochs`` epochs, saving to ``path`` after each.

    ``identity``: plain data describing the run (config, data); a saved state made for another
    identity is refused, so a changed config never silently continues an old run. ``unit`` names
    the samples in the curves (``pairs``, ``windows``); ``save_every``: seconds between saves within
    an epoch. ``team``: data-parallel workers (:class:`odolab.learned.training.distributed.Team`): they stop
    together, and only the leader saves and validates.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        modules: dict[str, nn.Module],
        optimizer: torch.optim.Optimizer,
        epochs: int,
        seed: int,
        identity: dict[str, Any],
        unit: str = "pairs",
        save_every: float = 600.0,
        team: Team = Team(),
    ) -> None:
        self.path, self.modules, self.optimizer, self.team = path, modules, optimizer, team
        self.epochs, self.seed, self.identity = int(epochs), int(seed), identity
        self.unit, self.save_every = unit, float(save_every)
        self.curves = Curves()
        self.epoch = 0  # epochs done
        self.seconds = 0.0  # training time spent so far, over all chunks
        self._partial: dict[str, Any] | None = None  # the epoch in progress at the last save

    def resume(self) -> int:
        """Load the saved state if there is one; returns the number of epochs already done. A state
        that is a link to nothing is refused (saving would write through it, outside the work folder)."""
        if os.path.islink(self.path) and not os.path.exists(self.path):
            raise ValueError(f"{self.path}: is a link to nothing ({os.readlink(self.path)}); remove it")
        if not os.path.exists(self.path):
            return 0
        try:
            doc = load_checkpoint(self.path, STATE_KIND, STATE_FORMAT)
        except ValueError as exc:
            raise ValueError(f"{exc}; delete it to start this training over") from None
        if doc["identity"] != self.identity:
            changed = differences(doc["identity"], self.identity)
            raise ValueError(
                f"{self.path}: saved training state belongs to another run (differs in: "
                f"{'; '.join(changed[:4])}); delete it or use another work folder"
            )
        for name, module in self.modules.items():
            module.load_state_dict(doc["modules"][name])
        self.epoch, self.seconds = int(doc["epoch"]), float(doc["seconds"])
        if "optimizer" in doc:
            self.optimizer.load_state_dict(doc["optimizer"])
        elif not self.finished:
            raise ValueError(
                f"{self.path}: field optimizer: expected the optimiser's state of a training to go on "
                f"(epoch {self.epoch} of {self.epochs}), got none (a finished stage drops it once the next "
                "stage starts); delete it and the later stages' states to train them again"
            )
        self.curves = Curves(doc["curves"])
        self._partial = doc.get("partial")
        return self.epoch

    def save(self, partial: dict[str, Any] | None = None) -> None:
        """Write the state (the leader only); ``partial``: the epoch in progress (:meth:`EpochTracker.partial`)."""
        if not self.team.leader:
            return
        doc = {
            "identity": self.identity,
            "epoch": self.epoch,
            "seconds": self.seconds,
            "curves": self.curves.rows,
            "modules": {n: m.state_dict() for n, m in self.modules.items()},
            "optimizer": self.optimizer.state_dict(),
        }
        if partial is not None:
            doc["partial"] = partial
        save_checkpoint(self.path, STATE_KIND, STATE_FORMAT, doc)

    def compact(self) -> None:
        """Rewrite a finished training's saved state without the optimiser's (Adam's moments, twice
        the weights' size): for a stage that a later stage follows, or the last one once the model is
        exported (the leader only). Its networks,
        epochs and curves stay; it can no longer be trained on for more epochs. A link or a read-only
        file is left as it is."""
        if not self.team.leader or not os.path.isfile(self.path) or os.path.islink(self.path):
            return
        if not os.stat(self.path).st_mode & 0o222:  # a file made read-only is kept as it is
            return
        doc = load_checkpoint(self.path, STATE_KIND, STATE_FORMAT)
        if int(doc["epoch"]) >= self.epochs and "partial" not in doc and doc.pop("optimizer", None) is not None:
            save_checkpoint(self.path, STATE_KIND, STATE_FORMAT, doc)

    @property
    def started(self) -> bool:
        """Whether any training was saved (a whole epoch or part of one)."""
        return self.epoch > 0 or self._partial is not None

    @property
    def finished(self) -> bool:
        return self.epoch >= self.epochs

    def run(
        self,
        train_epoch: Callable[[int, np.random.Generator, EpochTracker], dict[str, Any]],
        validate: Callable[[int], list[dict[str, Any]]],
        *,
        deadline: float | None = None,
        after_epoch: Callable[[EpochLoop], None] | None = None,
    ) -> bool:
        """Run the remaining epochs; ``train_epoch(epoch, rng, tracker)`` skips ``tracker.start``
        batches, calls ``tracker.add`` after each batch and returns extra training numbers (with
        ``tracker.row()`` they make one curve row); ``validate(epoch)`` returns validation rows. Stops at
        ``deadline`` (``time.monotonic()`` seconds), within an epoch too, after saving. Returns True
        when all epochs are done."""
        while not self.finished:
            if self.team.any(deadline is not None and time.monotonic() >= deadline):
                return False
            epoch = self.epoch + 1
            torch.manual_seed(self.seed * 100_003 + epoch)
            rng = np.random.default_rng([self.seed, epoch])
            partial, self._partial = self._partial, None
            if partial is not None:
                torch.set_rng_state(partial["torch_rng"])
            tracker = EpochTracker(self, self.unit, partial, deadline)
            for m in self.modules.values():
                m.train()
            try:
                extra = train_epoch(epoch, rng, tracker)
            except StopRequested:
                return False
            train_row = {**extra, **tracker.row()}
            for m in self.modules.values():
                m.eval()
            started = time.monotonic()
            with torch.inference_mode():
                val_rows = validate(epoch) if self.team.leader else []
            self.seconds += tracker.seconds + time.monotonic() - started
            self.curves.add(
                [{"epoch": epoch, "split": "train", **train_row}]
                + [{"epoch": epoch, "split": "val", **r} for r in val_rows]
            )
            self.epoch = epoch
            self.save()
            if after_epoch is not None and self.team.leader:
                after_epoch(self)
        return True
