"""The depth corrector's model file: its model config, the network's weights and how they were
trained, read back with ``torch.load(weights_only=True)`` (:mod:`odolab.learned.training.checkpoints`)."""

from __future__ import annotations

import os
from pathlib import Path

from odolab.learned.depth_corrector.config import CorrectorModel, CorrectorTraining
from odolab.learned.depth_corrector.model import DepthCorrectorNet
from odolab.learned.training import checkpoints

KIND = "odolab-depth-corrector"
#: The shipped model (studies/depth_corrector/shipped.toml).
SHIPPED = Path(__file__).resolve().parents[2] / "data" / "depth_corrector" / "depth-corrector.pt"


def save_model(path: str | os.PathLike, cfg: CorrectorTraining, net: DepthCorrectorNet, training: dict) -> None:
    """Write the network with its model config, the whole recipe and the training status."""
    checkpoints.save_model(path, KIND, cfg, {"corrector": net}, training)


def load_model(path: str | os.PathLike) -> tuple[CorrectorModel, DepthCorrectorNet, dict]:
    """(model config, network in eval mode, the file's ``recipe``, ``training`` and ``sha256``);
    :class:`~odolab.learned.training.CheckpointError` names the file and the problem (not such a file, or
    weights that do not fit its network)."""
    cfg, nets, info = checkpoints.load_model(path, KIND, CorrectorModel, lambda c: {"corrector": DepthCorrectorNet(c)})
    return cfg, nets["corrector"], info
