"""The robust VO's model file: the model config, every network's weights (float32) and how they
were trained, read back with ``torch.load(weights_only=True)``."""
from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import torch
from torch import nn

from odolab.learning import CheckpointError, dataclass_from_toml, load_checkpoint, save_checkpoint  # noqa: F401
from odolab.learning.configs import dataclass_from_dict
from odolab.robust_vo.config import ModelConfig, TrainConfig
from odolab.robust_vo.model import build_networks

KIND = "odolab-robust-vo"
FORMAT = 1
#: The shipped model (SepAct + DD + S-proj + DataAug + GeoInv, the paper's row 18, at reduced size).
SHIPPED = Path(__file__).resolve().parent.parent / "data" / "robust_vo" / "robust-vo.pt"


def save_model(path: str | os.PathLike, cfg: TrainConfig, nets: nn.ModuleDict, training: dict) -> None:
    """Write the networks with their model config, the whole recipe and the training status."""
    recipe = json.loads(json.dumps(dataclasses.asdict(cfg)))
    save_checkpoint(path, KIND, FORMAT, {
        "model": recipe["model"], "recipe": recipe, "training": json.loads(json.dumps(training)),
        "networks": {name: {k: v.detach().cpu() for k, v in net.state_dict().items()} for name, net in nets.items()}})


def load_model(path: str | os.PathLike) -> tuple[ModelConfig, nn.ModuleDict, dict]:
    """(model config, networks in eval mode, the checkpoint's ``training`` and ``recipe`` info);
    :class:`CheckpointError` names the file and the problem."""
    doc = load_checkpoint(path, KIND, FORMAT)
    try:
        cfg = dataclass_from_dict(ModelConfig, doc["model"], f"{path}: model")
        nets = build_networks(cfg)
        missing = sorted(set(nets) - set(doc["networks"]))
        if missing:
            raise CheckpointError(f"{path}: no weights for network(s) {', '.join(missing)}")
        for name, net in nets.items():
            net.load_state_dict(doc["networks"][name])
    except (KeyError, RuntimeError, ValueError) as exc:
        if isinstance(exc, CheckpointError):
            raise
        first = str(exc).strip().splitlines()[0]
        raise CheckpointError(f"{path}: robust-vo weights do not fit its config ({first})") from None
    return cfg, nets.eval(), {"training": doc.get("training", {}), "recipe": doc.get("recipe", {})}
