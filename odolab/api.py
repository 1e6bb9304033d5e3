"""odolab's public face: everything an odometer author, a learned model or a study needs, in one import.

``baselines/``, ``examples/`` and third-party code import only from here (an import-linter contract
in ``pyproject.toml`` holds them to it). Heavy modules (the simulator, Open3D) load on first use.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from odolab.config import ConfigError, Setting, assign, check, describe, range_text, setting
from odolab.core.geometry import (
    integrate,
    invert,
    planar_to_transform,
    transform_to_planar,
    wrap_angle,
)
from odolab.core.parallel import SERIAL, Execution
from odolab.core.types import (
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
from odolab.odometry.configured import check_choice, config_digest, configure
from odolab.odometry.odometer import (
    Odometer,
    UnknownOdometerError,
    available_odometers,
    load_odometer,
    register_odometer,
    split_odometer_names,
)
from odolab.odometry.options import whole_number
from odolab.running.threads import MAX_THREADS, check_threads

__all__ = [
    "DEFAULT_CACHE",
    "FORWARD_STEP",
    "MAX_THREADS",
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
    "check_choice",
    "check_threads",
    "config_digest",
    "configure",
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
    from odolab.core.trajectory import Trajectory
    from odolab.io.atomic import write_bytes_atomic, write_json_atomic
    from odolab.io.tum_rgbd import UnknownCameraError, load_tum_sequence
    from odolab.odometry.composites import load_inputs, one_input
    from odolab.reporting.pipeline import (
        DEFAULT_CACHE,
        ComparisonConfig,
        ComparisonError,
        ComparisonResult,
        run_comparison,
    )
    from odolab.running.runner import SequenceResult, StepByStep, failure_reason
    from odolab.running.scoring import Evaluation, evaluate_trajectory, pair_trajectories
    from odolab.sim.datasets import Pair, PairDataset, episode_specs, true_motions
    from odolab.sim.episodes import (
        EpisodeCache,
        EpisodeSpec,
        NoiseConfig,
        generate_episodes,
        load_episodes,
        stream_episodes,
    )
    from odolab.sim.scenes import SPLITS

_LAZY = {
    "EpisodeCache": "odolab.sim.episodes",
    "EpisodeSpec": "odolab.sim.episodes",
    "NoiseConfig": "odolab.sim.episodes",
    "generate_episodes": "odolab.sim.episodes",
    "load_episodes": "odolab.sim.episodes",
    "stream_episodes": "odolab.sim.episodes",
    "SPLITS": "odolab.sim.scenes",
    "Pair": "odolab.sim.datasets",
    "PairDataset": "odolab.sim.datasets",
    "episode_specs": "odolab.sim.datasets",
    "true_motions": "odolab.sim.datasets",
    "ComparisonConfig": "odolab.reporting.pipeline",
    "ComparisonResult": "odolab.reporting.pipeline",
    "ComparisonError": "odolab.reporting.pipeline",
    "run_comparison": "odolab.reporting.pipeline",
    "DEFAULT_CACHE": "odolab.reporting.pipeline",
    "SequenceResult": "odolab.running.runner",
    "StepByStep": "odolab.running.runner",
    "failure_reason": "odolab.running.runner",
    "load_inputs": "odolab.odometry.composites",
    "one_input": "odolab.odometry.composites",
    "load_tum_sequence": "odolab.io.tum_rgbd",
    "UnknownCameraError": "odolab.io.tum_rgbd",
    "write_bytes_atomic": "odolab.io.atomic",
    "write_json_atomic": "odolab.io.atomic",
    "Evaluation": "odolab.running.scoring",
    "evaluate_trajectory": "odolab.running.scoring",
    "pair_trajectories": "odolab.running.scoring",
    "Trajectory": "odolab.core.trajectory",
}


def run_odometers(odometers, sequences, **kw):
    """Every odometer on every sequence (see :func:`odolab.running.runner.run`)."""
    from odolab.running.runner import run

    return run(odometers, sequences, **kw)


def __getattr__(name: str):
    """Load episode, dataset and comparison names on first use (keeps ``import odolab.api`` light)."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'odolab.api' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(module), name)
