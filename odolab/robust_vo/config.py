"""The robust VO's switches (every one of the paper's Table 1 and a few after it) and its training
recipe, as frozen dataclasses read from TOML (see ``studies/robust_vo/*.toml``)."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Literal

from odolab.api import MOTION_ACTIONS, Action
from odolab.learning import DataConfig, dataclass_from_toml
from odolab.learning.compute import ComputeConfig
from odolab.learning.configs import check_ranges

ACTION_BY_LABEL = {a.label: a for a in MOTION_ACTIONS}
STAGE_NAME = re.compile(r"[A-Za-z0-9_-]{1,64}")


@dataclass(frozen=True)
class ModelConfig:
    """Network and input switches.

    ``kind``: ``sepact`` (one network per action, picked by the action taken), ``unified`` (one
    network, no action information) or ``actembed`` (one network with a learned action embedding of
    ``embed_dim`` before the head). ``visual``: which images enter (``rgb``, ``depth``, ``rgbd``);
    ``dd_bins``: one-hot discretised depth channels per frame over [0, ``max_depth``] m (0 = off);
    ``sproj``: the soft top-down projection channel; ``width`` x ``height``: input pixels (frames are
    resized to it, the paper's 341 x 192 is selectable); ``base_planes`` and ``groups``: ResNet-18
    width and GroupNorm groups; ``compress_channels``: the 3x3 compression conv's outputs;
    ``dropout``: before each of the two FC layers (``hidden`` units). ``warp`` (beyond the paper):
    ``nominal`` resamples each pair's current frame into the previous view by the action's commanded
    motion before psi (:mod:`odolab.robust_vo.warp`), so the network sees only the deviation from the
    command; ``none`` is the paper's input. ``mirror_turns`` (SepAct, beyond the paper): no network
    of its own for turn_right; a right turn is the left-turn network's answer for the mirrored pair,
    mirrored back (dx and dyaw negated), so one turn network learns from both turns (the world's
    left-right symmetry that Partsey et al.'s mirror augmentation uses). ``depth_residual`` (beyond
    the paper; needs the ``nominal`` warp): > 0 adds one channel per pair, the warped current depth
    minus the previous depth over this many metres (:func:`odolab.robust_vo.inputs.residual_channel`);
    0 is off.
    """

    kind: Literal["sepact", "unified", "actembed"] = "sepact"
    visual: Literal["rgb", "depth", "rgbd"] = "rgbd"
    dd_bins: int = 10
    sproj: bool = True
    width: int = 170
    height: int = 96
    base_planes: int = 32
    groups: int = 16
    compress_channels: int = 31
    dropout: float = 0.2
    hidden: int = 512
    embed_dim: int = 32
    max_depth: float = 10.0
    sproj_rows: float = 100 / 192  # central share of image rows projected (the reference keeps 100 of 192)
    warp: Literal["none", "nominal"] = "none"
    mirror_turns: bool = False
    depth_residual: float = 0.0

    def __post_init__(self) -> None:
        for name in ("groups", "compress_channels", "hidden", "embed_dim"):
            if not 1 <= getattr(self, name) <= 4096:
                raise ValueError(f"{name} must be in [1, 4096], got {getattr(self, name)}")
        if self.dd_bins < 0 or self.dd_bins > 64:
            raise ValueError(f"dd_bins must be in [0, 64], got {self.dd_bins}")
        if not (8 <= self.width <= 2048 and 8 <= self.height <= 2048):
            raise ValueError(f"width and height must be in [8, 2048], got {self.width} x {self.height}")
        if self.base_planes < 1 or self.base_planes % self.groups:
            raise ValueError(f"base_planes ({self.base_planes}) must be a positive multiple of groups ({self.groups})")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {self.dropout}")
        if not 0.0 < self.sproj_rows <= 1.0:
            raise ValueError(f"sproj_rows must be in (0, 1], got {self.sproj_rows}")
        if self.mirror_turns and self.kind != "sepact":
            raise ValueError(f"mirror_turns needs kind = 'sepact' (one network per action), got {self.kind!r}")
        if self.warp not in ("none", "nominal"):
            raise ValueError(f"warp must be 'none' or 'nominal', got {self.warp!r}")
        if not (self.depth_residual == 0 or 0 < self.depth_residual <= 10):
            raise ValueError(f"depth_residual must be 0 (off) or in (0, 10] m, got {self.depth_residual}")
        if self.depth_residual and self.warp != "nominal":
            raise ValueError("depth_residual needs warp = 'nominal' (the residual is the deviation from the command)")
        if not 0 < self.max_depth <= 100:
            raise ValueError(f"max_depth must be in (0, 100] m, got {self.max_depth}")

    @property
    def channels_per_frame(self) -> int:
        rgb = 3 if self.visual in ("rgb", "rgbd") else 0
        depth = 1 if self.visual in ("depth", "rgbd") else 0
        return rgb + depth + self.dd_bins + int(self.sproj)

    @property
    def input_channels(self) -> int:
        """Channels of a pair's psi: both frames' and the residual channel when it is on."""
        return 2 * self.channels_per_frame + int(self.depth_residual > 0)

    def model_names(self) -> tuple[str, ...]:
        """The networks of this kind: one per action label for SepAct (no turn_right with
        ``mirror_turns``), else ``("all",)``."""
        if self.kind != "sepact":
            return ("all",)
        return tuple(a.label for a in MOTION_ACTIONS if not self.mirrored(a))

    def model_for(self, action: Action) -> str:
        """The network that answers for ``action``."""
        if self.kind != "sepact":
            return "all"
        return Action.TURN_LEFT.label if self.mirrored(action) else action.label

    def mirrored(self, action: Action) -> bool:
        """Whether ``action``'s pairs go through their network mirrored (``mirror_turns``)."""
        return self.mirror_turns and action is Action.TURN_RIGHT


@dataclass(frozen=True)
class StageConfig:
    """One training stage: which actions' pairs, for how long, with which augmentations and losses.

    ``data_aug``: also train on pairs with their frames swapped (a reversed turn_left pair is a
    turn_right sample; turns only). ``mirror``: also on mirrored pairs (dx, dyaw negated, left and right
    swapped; Partsey et al. 2022). ``geoinv``: add the geometric-invariance loss between each turn pair
    and its swap (needs both turn actions). ``pairs_per_epoch``: 0 = every pair (with augmentations)
    once per epoch.
    """

    name: str
    actions: tuple[str, ...]
    epochs: int
    lr: float = 2.5e-4
    batch: int = 128
    data_aug: bool = False
    mirror: bool = False
    geoinv: bool = False
    pairs_per_epoch: int = 0
    blocked_repeat: int = 1

    def __post_init__(self) -> None:
        if not STAGE_NAME.fullmatch(self.name):
            raise ValueError(f"stage name must be letters, digits, '-' or '_' (it names a file), got {self.name!r}")
        bad = [a for a in self.actions if a not in ACTION_BY_LABEL]
        if bad or not self.actions:
            raise ValueError(
                f"stage {self.name!r}: actions must be some of {', '.join(ACTION_BY_LABEL)}, got {list(self.actions)}"
            )
        check_ranges(
            f"stage {self.name!r}",
            self,
            epochs=(1, 100_000),
            batch=(1, 65_536),
            lr=(1e-12, 1.0),
            pairs_per_epoch=(0, 10**9),
            blocked_repeat=(1, 1000),
        )
        if self.blocked_repeat > 1 and "move_forward" not in self.actions:
            raise ValueError(
                f"stage {self.name!r}: blocked_repeat repeats forward pairs; this stage has no move_forward"
            )
        if self.geoinv and not {"turn_left", "turn_right"} <= set(self.actions):
            raise ValueError(f"stage {self.name!r}: geoinv pairs turn_left with turn_right; list both actions")

    @property
    def action_set(self) -> tuple[Action, ...]:
        return tuple(ACTION_BY_LABEL[a] for a in self.actions)


@dataclass(frozen=True)
class TrainConfig:
    """A whole recipe: data (made when missing), model, stages in order, validation size, seed.
    ``init``: start every network from this exported robust-VO model (a path from the working
    directory; the same model but for added inputs, :func:`odolab.robust_vo.checkpoint.load_start`);
    "" = fresh weights. ``compute``: precision, memory format and batch-making workers (not part of
    the run's identity)."""

    model: ModelConfig = field(default_factory=ModelConfig)
    stages: tuple[StageConfig, ...] = ()
    train_data: DataConfig = field(default_factory=DataConfig)
    val_data: DataConfig = field(default_factory=lambda: DataConfig(split="val", episodes=64))
    data_root: str = "data"
    val_pairs: int = 3000
    seed: int = 0
    init: str = ""
    compute: ComputeConfig = field(default_factory=ComputeConfig)

    def __post_init__(self) -> None:
        check_ranges("recipe", self, val_pairs=(0, 10**7), seed=(0, 2**32 - 1))
        if not self.stages:
            raise ValueError("a training config needs at least one [[stages]] table")
        names = [s.name for s in self.stages]
        if len(set(names)) != len(names):
            raise ValueError(f"stage names must be unique, got {names}")
        for data in (self.train_data, self.val_data):
            data.require_size(self.model.width, self.model.height)

    def data_folder(self, data: DataConfig) -> str:
        """Where a data set lives (:meth:`DataConfig.folder` under ``data_root``)."""
        return str(data.folder(self.data_root))


def load_train_config(path: str) -> TrainConfig:
    """Read a recipe from TOML; :class:`~odolab.learning.ConfigError` names the file and field."""
    return dataclass_from_toml(TrainConfig, path)
