"""DeepVO's network and training recipe, read from TOML (``studies/deepvo/*.toml``)."""
from __future__ import annotations

from dataclasses import dataclass, field

from odolab.learning import DataConfig, dataclass_from_toml

#: The original encoder (FlowNetSimple's 9 convolutions): (output channels, kernel, stride).
FLOWNET_LAYERS = ((64, 7, 2), (128, 5, 2), (256, 5, 2), (256, 3, 1), (512, 3, 2), (512, 3, 1), (512, 3, 2),
                  (512, 3, 1), (1024, 3, 2))


@dataclass(frozen=True)
class DeepVOModel:
    """Network shape. ``width_scale`` multiplies FlowNetSimple's channel widths (1.0: the original
    64 ... 1024; the shipped model uses 1/8); ``depth``: add each frame's depth / ``max_depth`` as a
    fourth channel (the original sees RGB only); ``hidden``: LSTM units per layer (the original
    1000); frames are resized to ``width`` x ``height`` px."""

    width: int = 170
    height: int = 96
    width_scale: float = 0.125
    depth: bool = False
    hidden: int = 256
    layers: int = 2
    dropout: float = 0.2
    max_depth: float = 10.0

    def __post_init__(self) -> None:
        if not (8 <= self.width <= 2048 and 8 <= self.height <= 2048):
            raise ValueError(f"width and height must be in [8, 2048], got {self.width} x {self.height}")
        if not 0.0 < self.width_scale <= 4.0:
            raise ValueError(f"width_scale must be in (0, 4], got {self.width_scale}")
        if self.hidden < 1 or self.layers < 1:
            raise ValueError(f"hidden and layers must be >= 1, got {self.hidden} and {self.layers}")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {self.dropout}")

    @property
    def channels(self) -> tuple[int, ...]:
        return tuple(max(4, round(c * self.width_scale)) for c, _, _ in FLOWNET_LAYERS)

    @property
    def frame_channels(self) -> int:
        return 4 if self.depth else 3


@dataclass(frozen=True)
class DeepVOTraining:
    """The recipe: windows of ``window`` frames (``window - 1`` pairs) cut from the data, ``batch``
    windows per step, Adam at ``lr``, loss MSE(dx, dz) + ``rotation_weight`` x MSE(dyaw)."""

    model: DeepVOModel = field(default_factory=DeepVOModel)
    train_data: DataConfig = field(default_factory=DataConfig)
    val_data: DataConfig = field(default_factory=lambda: DataConfig(split="val", episodes=64))
    data_root: str = "data"
    window: int = 6
    batch: int = 8
    epochs: int = 4
    lr: float = 5e-4
    rotation_weight: float = 100.0
    windows_per_epoch: int = 0
    val_windows: int = 500
    seed: int = 0

    def __post_init__(self) -> None:
        if not 2 <= self.window <= 64:
            raise ValueError(f"window must be in [2, 64] frames, got {self.window}")
        if self.batch < 1 or self.epochs < 1 or not self.lr > 0 or self.windows_per_epoch < 0 or self.val_windows < 1:
            raise ValueError("batch, epochs and val_windows must be >= 1, lr > 0, windows_per_epoch >= 0")
        for data in (self.train_data, self.val_data):
            data.require_size(self.model.width, self.model.height)

    def data_folder(self, data: DataConfig) -> str:
        """Where a data set lives (:meth:`DataConfig.folder` under ``data_root``; the robust VO's
        data of the same config is shared)."""
        return str(data.folder(self.data_root))


def load_training(path: str) -> DeepVOTraining:
    """Read a recipe from TOML; :class:`~odolab.learning.ConfigError` names the file and field."""
    return dataclass_from_toml(DeepVOTraining, path)
