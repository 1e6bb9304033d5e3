"""The robust VO's model file: the model config, every network's weights (float32) and how they
were trained, read back with ``torch.load(weights_only=True)``."""
from __future__ import annotations

import os
from pathlib import Path

from torch import nn

from odolab.learning import checkpoints
from odolab.robust_vo.config import ModelConfig, TrainConfig
from odolab.robust_vo.model import build_networks

KIND = "odolab-robust-vo"
#: The shipped model (SepAct + DD + S-proj + DataAug + GeoInv, the paper's row 18, at reduced size).
SHIPPED = Path(__file__).resolve().parent.parent / "data" / "robust_vo" / "robust-vo.pt"


def save_model(path: str | os.PathLike, cfg: TrainConfig, nets: nn.ModuleDict, training: dict) -> None:
    """Write the networks with their model config, the whole recipe and the training status."""
    checkpoints.save_model(path, KIND, cfg, dict(nets.items()), training)


def load_model(path: str | os.PathLike) -> tuple[ModelConfig, nn.ModuleDict, dict]:
    """(model config, networks in eval mode, the checkpoint's ``training`` and ``recipe`` info);
    :class:`~odolab.learning.CheckpointError` names the file and the problem."""
    cfg, nets, info = checkpoints.load_model(path, KIND, ModelConfig, lambda c: dict(build_networks(c).items()))
    return cfg, nn.ModuleDict(nets).eval(), info
