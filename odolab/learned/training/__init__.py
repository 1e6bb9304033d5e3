"""What learned odometers share (torch): device choice, safe checkpoints, TOML configs, a resumable
epoch loop with validation curves, and the training data as torch batches.

The public face for learned code beside :mod:`odolab.api` (which stays torch-free): the robust VO
(:mod:`odolab.learned.robust_vo`) and ``odolab/learned/deepvo`` are written against these two modules only.
"""

from __future__ import annotations

from odolab.core.parallel import SERIAL, Execution
from odolab.learned.training.checkpoints import (
    CheckpointError,
    differences_from_init,
    load_checkpoint,
    load_init,
    save_checkpoint,
)
from odolab.learned.training.compute import Compute, ComputeConfig, choose_compute
from odolab.learned.training.configs import ConfigError, check, describe, from_toml, read_toml, setting
from odolab.learned.training.curves import Curves
from odolab.learned.training.device import pick_device
from odolab.learned.training.epochs import EpochLoop, StopRequested, require_finite
from odolab.learned.training.loading import prefetched
from odolab.sim.training_data import DataConfig, TrainingData, make_training_data, resize_frame

__all__ = [
    "SERIAL",
    "CheckpointError",
    "Compute",
    "ComputeConfig",
    "ConfigError",
    "Curves",
    "DataConfig",
    "EpochLoop",
    "Execution",
    "StopRequested",
    "TrainingData",
    "check",
    "choose_compute",
    "describe",
    "differences_from_init",
    "from_toml",
    "load_checkpoint",
    "load_init",
    "make_training_data",
    "pick_device",
    "prefetched",
    "read_toml",
    "require_finite",
    "resize_frame",
    "save_checkpoint",
    "setting",
]
