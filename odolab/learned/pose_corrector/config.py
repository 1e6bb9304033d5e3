"""The pose corrector's network shape and training recipe, read from TOML
(``studies/pose_corrector/*.toml``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from odolab.learned.training import check, from_toml, setting
from odolab.learned.training.configs import RecipeConfig
from odolab.sim.training_data import DataConfig

#: The camera's frame size (px), at which X runs at run time: X runs on the stored frames of the
#: training data, so a recipe's data should be of this size (a test's may be smaller).
CAMERA_SIZE = (341, 192)


@dataclass(frozen=True)
class PoseCorrectorModel:
    """Network shape: four stride-2 stages of ``base``, 2 ``base``, 4 ``base``, 4 ``base`` channels
    over the pair (the previous frame and the current one warped into its view, ``width`` x
    ``height`` px), a hidden layer of ``hidden`` units that also reads the action and X's motion,
    and a head answering a correction of (dx, dz, dyaw), bounded by ``max_translation`` (m) and
    ``max_rotation`` (rad), and its log-variance. The head starts at zero: an untrained network
    answers no correction, with standard deviations ``base_std_translation`` (m) and
    ``base_std_rotation`` (rad)."""

    width: int = setting(170, range=(16, 2048), doc="input width, px")
    height: int = setting(96, range=(16, 2048), doc="input height, px")
    base: int = setting(16, range=(1, 256), doc="channels of the first stage")
    hidden: int = setting(128, range=(1, 4096), doc="units of the hidden layer")
    depth_scale: float = setting(5.0, range=(0.1, 100.0), doc="depth is divided by this on input, m")
    residual_scale: float = setting(0.1, range=(1e-3, 10.0), doc="the warped depth's change is divided by this, m")
    max_translation: float = setting(0.1, range=(1e-3, 1.0), doc="largest correction of dx and dz (tanh-bounded), m")
    max_rotation: float = setting(0.2, range=(1e-3, 1.0), doc="largest correction of dyaw (tanh-bounded), rad")
    base_std_translation: float = setting(0.03, range=(1e-4, 1.0), doc="an untrained model's dx, dz std, m")
    base_std_rotation: float = setting(0.03, range=(1e-4, 1.0), doc="an untrained model's dyaw std, rad")

    def __post_init__(self) -> None:
        check(self)


def _data(split: str, episodes: int, max_steps: int, per_shard: int) -> DataConfig:
    return DataConfig(
        split=split,
        episodes=episodes,
        max_steps=max_steps,
        width=CAMERA_SIZE[0],
        height=CAMERA_SIZE[1],
        episodes_per_shard=per_shard,
    )


@dataclass(frozen=True)
class PoseCorrectorTraining(RecipeConfig):
    """The recipe (data, seed, ``init`` and ``compute`` as every learned recipe): the odometer
    ``inner`` (X, with its options from ``options_file``) whose estimates are corrected; ``batch``
    random pairs per step, ``pairs_per_epoch`` pairs an epoch, Adam at ``lr``. Loss: the mean
    absolute error of the correction against the truth's residual (m, m, rad: dyaw counts like dx
    and dz, as the robust VO's loss) plus ``nll_weight`` x the Gaussian negative log-likelihood of
    that error under the predicted variance (the error detached there, so the variance does not
    bend the correction). Validation on at most ``val_pairs`` pairs of the val data. X runs on the
    stored frames: give the data the camera's size (:data:`CAMERA_SIZE`), as X sees at run time; the
    network's input is resized from them."""

    model: PoseCorrectorModel = setting(default_factory=PoseCorrectorModel, doc="the network")
    train_data: DataConfig = setting(default_factory=lambda: _data("train", 400, 50, 8), doc="the training episodes")
    val_data: DataConfig = setting(default_factory=lambda: _data("val", 24, 30, 4), doc="the validation episodes")
    inner: str = setting("open3d-rgbd", doc="the odometer X whose estimates are corrected")
    options_file: str = setting("", doc="X's options (TOML [odometers.\"NAME\"]); '': its defaults")
    batch: int = setting(16, range=(1, 4096), doc="pairs per step")
    epochs: int = setting(16, range=(1, 100_000), doc="epochs")
    pairs_per_epoch: int = setting(20_000, range=(1, 10**9), doc="pairs per epoch (drawn at random)")
    lr: float = setting(1e-3, range=(1e-12, 1.0), doc="Adam's learning rate")
    nll_weight: float = setting(0.05, range=(0.0, 100.0), doc="weight of the variance's Gaussian likelihood")
    val_pairs: int = setting(2000, range=(1, 10**7), doc="validation pairs at most")

    def __post_init__(self) -> None:
        super().__post_init__()
        self.require_data_size(self.model.width, self.model.height, resized=True)
        if not self.inner.strip():
            raise ValueError('recipe: inner must name the odometer to correct, e.g. inner = "open3d-rgbd"')


def load_training(path: str, changes: Sequence[str] = ()) -> PoseCorrectorTraining:
    """A recipe from a TOML file with ``--set`` changes (:func:`odolab.learned.training.from_toml`)."""
    return from_toml(PoseCorrectorTraining, path, changes)
