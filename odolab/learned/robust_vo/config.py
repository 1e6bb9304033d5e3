"""The robust VO's switches (every one of the paper's Table 1 and a few after it) and its training
recipe, as frozen dataclasses read from TOML (see ``studies/robust_vo/*.toml``)."""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

from odolab.api import MOTION_ACTIONS, Action
from odolab.learned.training import from_toml
from odolab.learned.training.configs import RecipeConfig, check, setting

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
    motion before psi (:mod:`odolab.learned.robust_vo.warp`), so the network sees only the deviation from the
    command; ``none`` is the paper's input. ``mirror_turns`` (SepAct, beyond the paper): no network
    of its own for turn_right; a right turn is the left-turn network's answer for the mirrored pair,
    mirrored back (dx and dyaw negated), so one turn network learns from both turns (the world's
    left-right symmetry that Partsey et al.'s mirror augmentation uses). ``depth_residual`` (beyond
    the paper; needs the ``nominal`` warp): > 0 adds one channel per pair, the warped current depth
    minus the previous depth over this many metres (:func:`odolab.learned.robust_vo.inputs.residual_channel`);
    0 is off.
    """

    kind: Literal["sepact", "unified", "actembed"] = setting(
        "sepact", doc="sepact: one network per action; unified: one, no action; actembed: one with an action embedding"
    )
    visual: Literal["rgb", "depth", "rgbd"] = setting("rgbd", doc="which images enter")
    dd_bins: int = setting(10, range=(0, 64), doc="one-hot discretised depth channels per frame (0: off)")
    sproj: bool = setting(True, doc="the soft top-down projection channel")
    width: int = setting(170, range=(8, 2048), doc="input width, px (frames are resized to it)")
    height: int = setting(96, range=(8, 2048), doc="input height, px")
    base_planes: int = setting(32, doc="ResNet-18 width (a multiple of groups)")
    groups: int = setting(16, range=(1, 4096), doc="GroupNorm groups")
    compress_channels: int = setting(31, range=(1, 4096), doc="outputs of the 3x3 compression conv")
    dropout: float = setting(0.2, range=(0.0, 1.0), open_high=True, doc="dropout before each FC layer")
    hidden: int = setting(512, range=(1, 4096), doc="units of each FC layer")
    embed_dim: int = setting(32, range=(1, 4096), doc="action embedding size (actembed)")
    max_depth: float = setting(10.0, range=(0.0, 100.0), open_low=True, doc="depth range of dd_bins and sproj, m")
    sproj_rows: float = setting(
        100 / 192,
        range=(0.0, 1.0),
        open_low=True,
        doc="central share of image rows projected (the reference: 100 of 192)",
    )
    warp: Literal["none", "nominal"] = setting("none", doc="nominal: the current frame warped by the commanded motion")
    mirror_turns: bool = setting(False, doc="right turns through the mirrored left-turn network (sepact)")
    depth_residual: float = setting(0.0, doc="> 0: a warped-depth residual channel over this many m; 0: off")

    def __post_init__(self) -> None:
        check(self)
        if self.base_planes < 1 or self.base_planes % self.groups:
            raise ValueError(f"base_planes ({self.base_planes}) must be a positive multiple of groups ({self.groups})")
        if self.mirror_turns and self.kind != "sepact":
            raise ValueError(f"mirror_turns needs kind = 'sepact' (one network per action), got {self.kind!r}")
        if not (self.depth_residual == 0 or 0 < self.depth_residual <= 10):
            raise ValueError(f"depth_residual must be 0 (off) or in (0, 10] m, got {self.depth_residual}")
        if self.depth_residual and self.warp != "nominal":
            raise ValueError("depth_residual needs warp = 'nominal' (the residual is the deviation from the command)")

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

    name: str = setting(doc="the stage's name (it names a file): letters, digits, '-' or '_'")
    actions: tuple[str, ...] = setting(doc="the actions whose pairs it trains on")
    epochs: int = setting(range=(1, 100_000), doc="epochs of this stage")
    lr: float = setting(2.5e-4, range=(1e-12, 1.0), doc="Adam's learning rate")
    batch: int = setting(128, range=(1, 65_536), doc="pairs per step")
    data_aug: bool = setting(False, doc="also train on swapped pairs (turns only)")
    mirror: bool = setting(False, doc="also train on mirrored pairs")
    geoinv: bool = setting(False, doc="the geometric-invariance loss between turn pairs and their swaps")
    pairs_per_epoch: int = setting(0, range=(0, 10**9), doc="pairs per epoch; 0: every pair once")
    blocked_repeat: int = setting(1, range=(1, 1000), doc="times each blocked forward pair is repeated")

    def __post_init__(self) -> None:
        if not STAGE_NAME.fullmatch(self.name):
            raise ValueError(f"stage name must be letters, digits, '-' or '_' (it names a file), got {self.name!r}")
        bad = [a for a in self.actions if a not in ACTION_BY_LABEL]
        if bad or not self.actions:
            raise ValueError(
                f"stage {self.name!r}: actions must be some of {', '.join(ACTION_BY_LABEL)}, got {list(self.actions)}"
            )
        check(self, f"stage {self.name!r}: ")
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
class TrainConfig(RecipeConfig):
    """A whole recipe: data (made when missing), model, stages in order, validation size, seed
    (:class:`~odolab.learned.training.configs.RecipeConfig`, which DeepVO's recipe shares). ``init``: start
    every network from this exported robust-VO model (a path from the working directory; the same
    model but for added inputs, :func:`odolab.learned.robust_vo.checkpoint.load_start`); "" = fresh weights.
    ``compute``: precision, memory format and batch-making workers (not part of the run's identity)."""

    model: ModelConfig = setting(default_factory=ModelConfig, doc="the network and its inputs")
    stages: tuple[StageConfig, ...] = setting((), doc="the training stages, in order ([[stages]] tables)")
    val_pairs: int = setting(3000, range=(0, 10**7), doc="validation pairs drawn from the validation data")

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.stages:
            raise ValueError("a training config needs at least one [[stages]] table")
        names = [s.name for s in self.stages]
        if len(set(names)) != len(names):
            raise ValueError(f"stage names must be unique, got {names}")
        self.require_data_size(self.model.width, self.model.height)


def load_train_config(path: str, changes: Sequence[str] = ()) -> TrainConfig:
    """Read a recipe from TOML with ``path=value`` ``changes`` (``stages.forward.lr=1e-4``,
    :func:`odolab.config.change_document`); :class:`~odolab.learned.training.ConfigError` names the file and field."""
    return from_toml(TrainConfig, path, changes)
