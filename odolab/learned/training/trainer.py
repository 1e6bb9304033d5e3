"""What a trainer tells the training command line (:mod:`odolab.cli.train`) about itself: its
family (the default folders ``runs/<family>/<recipe>`` and ``reports/<family>/<recipe>``), how to read
its TOML recipe, how to run it, where it keeps its states and what its recipe may start from.

Each trainer module (``odolab.learned.robust_vo.train``, ``odolab.learned.depth_corrector.train``,
``odolab.learned.pose_corrector.train``, ``odolab.learned.deepvo.train``) defines one :class:`Trainer` named
``TRAINER``; the command line is built from it, so the trainers hold no argument parsing.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["StartCheck", "StateFiles", "Trainer", "stage_states"]

#: What keeps a training state -> its file, given the recipe and ``--work``.
StateFiles = Callable[[Any, Path], dict[str, Path]]
#: A check of the model a recipe starts from (its ``init``), given the recipe and ``--export``:
#: ``ValueError`` when it cannot start this recipe.
StartCheck = Callable[[Any, Path], object]


def stage_states(config: Any, work: Path) -> dict[str, Path]:
    """The training states of a recipe with ``stages`` (the robust VO): one per stage,
    ``<work>/<stage name>.pt``; none for a recipe without stages."""
    return {f"stage {s.name!r}": work / f"{s.name}.pt" for s in getattr(config, "stages", ())}


@dataclass(frozen=True)
class Trainer:
    """One trainer: ``family`` names its folders and the kind of model it exports
    (``odolab-<family>``); ``description`` is one line for the help; ``load_config(path, --set changes)`` reads the recipe (``ValueError`` for a bad one);
    ``run(config, work=, reports=, export=, device=, hours=, execution=, command=, workers=,
    gpus_per_worker=)`` trains, True once every epoch is done; ``state_files`` and
    ``check_start`` guard ``--export`` and the recipe's ``init``; ``set_example`` shows ``--set``."""

    family: str
    description: str
    load_config: Callable[[str, Sequence[str]], Any]
    run: Callable[..., bool]
    state_files: StateFiles = stage_states
    check_start: StartCheck | None = None
    set_example: str = "seed=1"
