"""Recipes from TOML files into frozen dataclasses: the learned odometers' face of :mod:`odolab.config`
(the one way to configure), with errors that name the file, the field, what was expected and what was
found."""

from __future__ import annotations

from dataclasses import dataclass

from odolab.config import (
    MAX_BASE_CHAIN,
    MAX_TABLE_DEPTH,
    ConfigError,
    Setting,
    assign,
    build,
    check,
    describe,
    from_toml,
    range_text,
    read_toml,
    setting,
)
from odolab.learned.training.compute import ComputeConfig
from odolab.sim.training_data import DataConfig


@dataclass(frozen=True)
class RecipeConfig:
    """What every learned odometer's training recipe shares (the robust VO's ``TrainConfig``,
    DeepVO's ``DeepVOTraining``): its data sets, where they live, the seed, a start from an exported
    model, and the compute choices. A recipe adds its ``model`` (with ``width`` and ``height``, which
    the data must match) and its own fields; every field with a range is checked on construction,
    errors led by ``recipe: ``."""

    train_data: DataConfig = setting(default_factory=DataConfig, doc="the training episodes")
    val_data: DataConfig = setting(
        default_factory=lambda: DataConfig(split="val", episodes=64), doc="the validation episodes"
    )
    data_root: str = setting("data", doc="folder of the data sets (made when missing)")
    seed: int = setting(0, range=(0, 2**32 - 1), doc="seed of the weights, the data order and the validation draw")
    init: str = setting("", doc="start from this exported model (a path from the working directory); '': fresh")
    compute: ComputeConfig = setting(
        default_factory=ComputeConfig, doc="precision, memory format and batch-making workers (not in the identity)"
    )

    def __post_init__(self) -> None:
        check(self, "recipe: ")
        if not self.data_root.strip():
            raise ValueError(f"recipe: data_root must name a folder, got {self.data_root!r}")

    def require_data_size(self, width: int, height: int, resized: bool = False) -> None:
        """``ValueError`` unless both data sets hold frames of the model's ``width`` x ``height``
        (with ``resized``: at least that large, resized on load; :meth:`DataConfig.require_size`)."""
        for data in (self.train_data, self.val_data):
            data.require_size(width, height, resized)

    def data_folder(self, data: DataConfig) -> str:
        """Where a data set lives (:meth:`DataConfig.folder` under ``data_root``; recipes of the
        same data config share it)."""
        return str(data.folder(self.data_root))


__all__ = [
    "MAX_BASE_CHAIN",
    "MAX_TABLE_DEPTH",
    "ConfigError",
    "RecipeConfig",
    "Setting",
    "assign",
    "build",
    "check",
    "describe",
    "from_toml",
    "range_text",
    "read_toml",
    "setting",
]
