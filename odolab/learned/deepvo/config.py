"""DeepVO's network and training recipe, read from TOML (``studies/deepvo/*.toml``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from odolab.learned.training import check, from_toml, setting
from odolab.learned.training.configs import RecipeConfig

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

    width: int = setting(170, range=(8, 2048), doc="input width, px (frames are resized to it)")
    height: int = setting(96, range=(8, 2048), doc="input height, px")
    width_scale: float = setting(0.125, range=(1e-3, 4.0), doc="multiple of FlowNetSimple's channel widths")
    depth: bool = setting(False, doc="depth / max_depth as a fourth channel")
    hidden: int = setting(256, range=(1, 8192), doc="LSTM units per layer")
    layers: int = setting(2, range=(1, 16), doc="LSTM layers")
    dropout: float = setting(0.2, range=(0.0, 0.99), doc="dropout")
    max_depth: float = setting(10.0, range=(0.1, 100.0), doc="depth scale of the depth channel, m")
    actions: bool = setting(False, doc="the action taken (one-hot) enters the LSTM beside the image features")

    def __post_init__(self) -> None:
        check(self)

    @property
    def channels(self) -> tuple[int, ...]:
        return tuple(max(4, round(c * self.width_scale)) for c, _, _ in FLOWNET_LAYERS)

    @property
    def frame_channels(self) -> int:
        return 4 if self.depth else 3


@dataclass(frozen=True)
class DeepVOTraining(RecipeConfig):
    """The recipe (data, seed, ``init`` and ``compute`` as every learned recipe,
    :class:`~odolab.learned.training.configs.RecipeConfig`): windows of ``window`` frames (``window - 1``
    pairs) cut from the data, ``batch`` windows per step, Adam at ``lr``, loss MSE(dx, dz) +
    ``rotation_weight`` x MSE(dyaw). ``init``: start from the weights of this exported DeepVO model
    (same ``model``; a path from the working directory), e.g. a first stage trained with another
    rotation weight; "" = fresh weights. ``compute``: precision, memory format and batch-making
    workers (not part of the run's identity)."""

    model: DeepVOModel = setting(default_factory=DeepVOModel, doc="the network")
    window: int = setting(6, range=(2, 64), doc="frames per window (window - 1 pairs)")
    batch: int = setting(8, range=(1, 65_536), doc="windows per step")
    epochs: int = setting(4, range=(1, 100_000), doc="epochs")
    lr: float = setting(5e-4, range=(1e-12, 1.0), doc="Adam's learning rate")
    rotation_weight: float = setting(100.0, range=(0.0, 1e6), doc="weight of MSE(dyaw) against MSE(dx, dz)")
    windows_per_epoch: int = setting(0, range=(0, 10**9), doc="windows per epoch; 0: every window once")
    val_windows: int = setting(500, range=(1, 10**7), doc="validation windows at most")

    def __post_init__(self) -> None:
        super().__post_init__()
        self.require_data_size(self.model.width, self.model.height, resized=True)


def load_training(path: str, changes: Sequence[str] = ()) -> DeepVOTraining:
    """Read a recipe from TOML with ``path=value`` ``changes`` (``lr=1e-4``, ``model.width_scale=0.25``);
    :class:`~odolab.learned.training.ConfigError` names the file and field."""
    return from_toml(DeepVOTraining, path, changes)
