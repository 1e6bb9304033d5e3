"""odolab's public face: everything an odometer author, a learned model or a study needs, in one import.

``baselines/``, ``examples/`` and third-party code import only from here (an import-linter contract
in ``pyproject.toml`` holds them to it). Heavy modules (the simulator, Open3D) load on first use.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from odolab.config import ConfigError, Setting, assign, check, describe, range_text, setting
from odolab.geometry import (
    integrate,
    invert,
    planar_to_transform,
    transform_to_planar,
    wrap_angle,
)
from odolab.odometer import (
    Odometer,
    UnknownOdometerError,
    available_odometers,
    load_odometer,
    register_odometer,
    split_odometer_names,
)
from odolab.options import whole_number
from odolab.parallel import SERIAL, Execution
from odolab.threads import check_threads
from odolab.types import (
    FORWARD_STEP,
    MOTION_ACTIONS,
    TURN_ANGLE,
    Action,
    Estimate,
    Frame,
    Intrinsics,
    Sequence,
    as_action,
    nominal_motion,
    nominal_planar,
)

__all__ = [
    "DEFAULT_CACHE",
    "FORWARD_STEP",
    "MOTION_ACTIONS",
    "SERIAL",
    "SPLITS",
    "TURN_ANGLE",
    "Action",
    # running and comparing
    "ComparisonConfig",
    "ComparisonError",
    "ComparisonResult",
    # configs: fields with ranges and descriptions (odolab.config)
    "ConfigError",
    # episodes and training data (loaded on first use)
    "EpisodeCache",
    "EpisodeSpec",
    "Estimate",
    # evaluating trajectories (the library behind python -m odolab.evaluate)
    "Evaluation",
    # where fan-out work runs (a local Ray instance, a cluster, or serially here)
    "Execution",
    "Frame",
    "Intrinsics",
    "NoiseConfig",
    "Odometer",
    "Pair",
    "PairDataset",
    "Sequence",
    "SequenceResult",
    "Setting",
    "StepByStep",
    "Trajectory",
    "UnknownCameraError",
    "UnknownOdometerError",
    "as_action",
    "assign",
    "available_odometers",
    "check",
    "check_threads",
    "describe",
    "episode_specs",
    "evaluate_trajectory",
    "failure_reason",
    "generate_episodes",
    "integrate",
    "invert",
    "load_episodes",
    "load_inputs",
    "load_odometer",
    "load_tum_sequence",
    "nominal_motion",
    "nominal_planar",
    "one_input",
    "pair_trajectories",
    "planar_to_transform",
    "range_text",
    "register_odometer",
    "run_comparison",
    "run_odometers",
    "setting",
    "split_odometer_names",
    "stream_episodes",
    "transform_to_planar",
    "true_motions",
    "whole_number",
    "wrap_angle",
    "write_bytes_atomic",
    "write_json_atomic",
]

if TYPE_CHECKING:  # the lazily loaded names below, visible to type checkers and import-linter
    from odolab.comparison import DEFAULT_CACHE, ComparisonConfig, ComparisonError, ComparisonResult, run_comparison
    from odolab.composites import load_inputs, one_input
    from odolab.datasets import Pair, PairDataset, episode_specs, true_motions
    from odolab.episodes import (
        EpisodeCache,
        EpisodeSpec,
        NoiseConfig,
        generate_episodes,
        load_episodes,
        stream_episodes,
    )
    from odolab.evaluation import Evaluation, evaluate_trajectory, pair_trajectories
    from odolab.io.atomic import write_bytes_atomic, write_json_atomic
    from odolab.io.tum_rgbd import UnknownCameraError, load_tum_sequence
    from odolab.runner import SequenceResult, StepByStep, failure_reason
    from odolab.sim.scenes import SPLITS
    from odolab.trajectory import Trajectory

_LAZY = {
    "EpisodeCache": "odolab.episodes",
    "EpisodeSpec": "odolab.episodes",
    "NoiseConfig": "odolab.episodes",
    "generate_episodes": "odolab.episodes",
    "load_episodes": "odolab.episodes",
    "stream_episodes": "odolab.episodes",
    "SPLITS": "odolab.sim.scenes",
    "Pair": "odolab.datasets",
    "PairDataset": "odolab.datasets",
    "episode_specs": "odolab.datasets",
    "true_motions": "odolab.datasets",
    "ComparisonConfig": "odolab.comparison",
    "ComparisonResult": "odolab.comparison",
    "ComparisonError": "odolab.comparison",
    "run_comparison": "odolab.comparison",
    "DEFAULT_CACHE": "odolab.comparison",
    "SequenceResult": "odolab.runner",
    "StepByStep": "odolab.runner",
    "failure_reason": "odolab.runner",
    "load_inputs": "odolab.composites",
    "one_input": "odolab.composites",
    "load_tum_sequence": "odolab.io.tum_rgbd",
    "UnknownCameraError": "odolab.io.tum_rgbd",
    "write_bytes_atomic": "odolab.io.atomic",
    "write_json_atomic": "odolab.io.atomic",
    "Evaluation": "odolab.evaluation",
    "evaluate_trajectory": "odolab.evaluation",
    "pair_trajectories": "odolab.evaluation",
    "Trajectory": "odolab.trajectory",
}


def run_odometers(odometers, sequences, **kw):
    """Every odometer on every sequence (see :func:`odolab.runner.run`)."""
    from odolab.runner import run

    return run(odometers, sequences, **kw)


def __getattr__(name: str):
    """Load episode, dataset and comparison names on first use (keeps ``import odolab.api`` light)."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'odolab.api' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(module), name)
