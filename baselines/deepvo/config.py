"""DeepVO's network and training recipe, read from TOML (``studies/deepvo/*.toml``)."""

from __future__ import annotations

from dataclasses import dataclass, field

from odolab.learning import ComputeConfig, DataConfig, dataclass_from_toml
from odolab.learning.configs import check_ranges

#: The original encoder (FlowNetSimple's 9 convolutions): (output channels, kernel, stride).
FLOWNET_LAYERS = (
    (64, 7, 2),
    (128, 5, 2),
    (256, 5, 2),
    (256, 3, 1),
    (512, 3, 2),
    (512, 3, 1),
    (512, 3, 2),
    (512, 3, 1),
    (1024, 3, 2),
)


@dataclass(frozen=True)
class DeepVOModel:
    """Network shape. ``width_scale`` multiplies FlowNetSimple's channel widths (1.0: the original
    64 ... 1024; the shipped model uses 1/8); ``depth``: add each frame's depth / ``max_depth`` as a
    fourth channel (the original sees RGB only); ``hidden``: LSTM units per layer (the original
    1000); frames are resized to ``width`` x ``height`` px. ``actions`` (beyond the original, which
    sees images only): the action taken (forward, left, right as a one-hot) enters the LSTM beside
    each pair's image features, as the robot knows what it commanded (the robust VO picks its
    network by it)."""

    width: int = 170
    height: int = 96
    width_scale: float = 0.125
    depth: bool = False
    hidden: int = 256
    layers: int = 2
    dropout: float = 0.2
    max_depth: float = 10.0
    actions: bool = False

    def __post_init__(self) -> None:
        check_ranges(
            "",
            self,
            width=(8, 2048),
            height=(8, 2048),
            width_scale=(1e-3, 4.0),
            hidden=(1, 8192),
            layers=(1, 16),
            dropout=(0.0, 0.99),
            max_depth=(0.1, 100.0),
        )

    @property
    def channels(self) -> tuple[int, ...]:
        return tuple(max(4, round(c * self.width_scale)) for c, _, _ in FLOWNET_LAYERS)

    @property
    def frame_channels(self) -> int:
        return 4 if self.depth else 3


@dataclass(frozen=True)
class DeepVOTraining:
    """The recipe: windows of ``window`` frames (``window - 1`` pairs) cut from the data, ``batch``
    windows per step, Adam at ``lr``, loss MSE(dx, dz) + ``rotation_weight`` x MSE(dyaw).
    ``init``: start from the weights of this exported DeepVO model (same ``model``; a path from the
    working directory), e.g. a first stage trained with another rotation weight; "" = fresh weights.
    ``compute``: precision, memory format and batch-making workers (not part of the run's identity)."""

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
    init: str = ""
    compute: ComputeConfig = field(default_factory=ComputeConfig)

    def __post_init__(self) -> None:
        check_ranges(
            "recipe",
            self,
            window=(2, 64),
            batch=(1, 65_536),
            epochs=(1, 100_000),
            lr=(1e-12, 1.0),
            rotation_weight=(0.0, 1e6),
            windows_per_epoch=(0, 10**9),
            val_windows=(1, 10**7),
            seed=(0, 2**32 - 1),
        )
        for data in (self.train_data, self.val_data):
            data.require_size(self.model.width, self.model.height)

    def data_folder(self, data: DataConfig) -> str:
        """Where a data set lives (:meth:`DataConfig.folder` under ``data_root``; the robust VO's
        data of the same config is shared)."""
        return str(data.folder(self.data_root))


def load_training(path: str) -> DeepVOTraining:
    """Read a recipe from TOML; :class:`~odolab.learning.ConfigError` names the file and field."""
    return dataclass_from_toml(DeepVOTraining, path)
