"""The pose corrector's model file: its model config, the network's weights, the recipe (which names
the odometer X it corrects) and how it was trained, read back with ``torch.load(weights_only=True)``
(:mod:`odolab.learned.training.checkpoints`)."""

from __future__ import annotations

import os
from pathlib import Path

from odolab.learned.pose_corrector.config import PoseCorrectorModel, PoseCorrectorTraining
from odolab.learned.pose_corrector.model import PoseCorrectorNet
from odolab.learned.training import checkpoints
from odolab.reporting.report import file_stem

KIND = "odolab-pose-corrector"
#: Where the shipped models lie, one per corrected odometer (:func:`shipped_model`).
SHIPPED_FOLDER = Path(__file__).resolve().parents[2] / "data" / "pose_corrector"
#: The recipe of the shipped models.
SHIPPED_RECIPE = "studies/pose_corrector/shipped.toml"


def shipped_model(inner: str) -> Path:
    """The shipped model that corrects odometer ``inner``: ``<SHIPPED_FOLDER>/<file stem of the
    name>.pt`` (e.g. ``open3d-rgbd.pt``; :func:`odolab.reporting.report.file_stem`)."""
    return SHIPPED_FOLDER / f"{file_stem(inner)}.pt"


def save_model(path: str | os.PathLike, cfg: PoseCorrectorTraining, net: PoseCorrectorNet, training: dict) -> None:
    """Write the network with its model config, the whole recipe and the training status."""
    checkpoints.save_model(path, KIND, cfg, {"corrector": net}, training)


def load_model(path: str | os.PathLike) -> tuple[PoseCorrectorModel, PoseCorrectorNet, dict]:
    """(model config, network in eval mode, the file's ``recipe``, ``training`` and ``sha256``);
    :class:`~odolab.learned.training.CheckpointError` names the file and the problem (not such a file, or
    weights that do not fit its network)."""
    cfg, nets, info = checkpoints.load_model(
        path, KIND, PoseCorrectorModel, lambda c: {"corrector": PoseCorrectorNet(c)}
    )
    return cfg, nets["corrector"], info
