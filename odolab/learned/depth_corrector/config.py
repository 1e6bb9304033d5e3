"""The depth corrector's network shape and training recipe, read from TOML
(``studies/depth_corrector/*.toml``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from odolab.learned.training import check, from_toml, setting
from odolab.learned.training.configs import RecipeConfig
from odolab.sim.training_data import DataConfig


@dataclass(frozen=True)
class CorrectorModel:
    """Network shape: a U-Net of ``levels`` scales, ``base`` channels at full resolution, doubling at
    each scale below. Inputs per pixel: depth / ``depth_scale``, its validity, RGB and the pixel's
    place in the image (the Redwood distortion is a function of pixel position and depth); outputs a
    relative depth correction (at most ``max_correction``, e.g. 0.2 = 20 %) and the spread of the
    corrected depth's error (a Laplace scale, m). Frames of another size are resized to ``width`` x
    ``height`` and the correction resized back."""

    width: int = setting(341, range=(8, 2048), doc="input width, px")
    height: int = setting(192, range=(8, 2048), doc="input height, px")
    base: int = setting(8, range=(1, 256), doc="channels at full resolution")
    levels: int = setting(4, range=(2, 6), doc="scales of the U-Net (each halves the resolution)")
    depth_scale: float = setting(5.0, range=(0.1, 100.0), doc="depth is divided by this on input, m")
    max_correction: float = setting(0.2, range=(1e-3, 1.0), doc="largest relative correction (tanh-bounded)")

    def __post_init__(self) -> None:
        check(self)


def _data(split: str, episodes: int) -> DataConfig:
    return DataConfig(split=split, episodes=episodes, max_steps=30, width=341, height=192, clean_depth=True)


@dataclass(frozen=True)
class CorrectorTraining(RecipeConfig):
    """The recipe (data, seed, ``init`` and ``compute`` as every learned recipe): random crops
    (``crop_width`` x ``crop_height`` px) of ``batch`` frames per step, ``frames_per_epoch`` frames an epoch,
    Adam at ``lr``; loss: the mean absolute error of the corrected depth (m) over pixels with both a
    noisy and a true reading, plus ``spread_weight`` x the Laplace negative log-likelihood of that
    error under the predicted spread (the error itself detached there, so the spread does not bend
    the correction). Validation on ``val_frames`` whole frames of the val data."""

    model: CorrectorModel = setting(default_factory=CorrectorModel, doc="the network")
    train_data: DataConfig = setting(default_factory=lambda: _data("train", 200), doc="the training episodes")
    val_data: DataConfig = setting(default_factory=lambda: _data("val", 24), doc="the validation episodes")
    batch: int = setting(8, range=(1, 4096), doc="frames per step")
    crop_height: int = setting(96, range=(8, 2048), doc="training crop height, px")
    crop_width: int = setting(160, range=(8, 2048), doc="training crop width, px")
    epochs: int = setting(20, range=(1, 100_000), doc="epochs")
    frames_per_epoch: int = setting(1600, range=(1, 10**9), doc="frames per epoch (drawn at random)")
    lr: float = setting(2e-3, range=(1e-12, 1.0), doc="Adam's learning rate")
    spread_weight: float = setting(0.1, range=(0.0, 100.0), doc="weight of the spread's Laplace likelihood")
    val_frames: int = setting(120, range=(1, 10**6), doc="validation frames at most")

    def __post_init__(self) -> None:
        super().__post_init__()
        self.require_data_size(self.model.width, self.model.height)
        for data in (self.train_data, self.val_data):
            if not data.clean_depth:
                raise ValueError(f"recipe: {data.split} data: clean_depth must be true (the corrector's target)")
        if self.crop_height > self.model.height or self.crop_width > self.model.width:
            raise ValueError(
                f"recipe: the crop ({self.crop_width} x {self.crop_height} px) must fit the model's "
                f"{self.model.width} x {self.model.height}"
            )


def load_training(path: str, changes: Sequence[str] = ()) -> CorrectorTraining:
    """A recipe from a TOML file with ``--set`` changes (:func:`odolab.learned.training.from_toml`)."""
    return from_toml(CorrectorTraining, path, changes)
