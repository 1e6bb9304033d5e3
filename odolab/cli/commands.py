"""The ``odolab`` command: one entry point whose subcommands are the ``python -m`` commands.

    odolab compare [options]        = python -m odolab.compare [options]
    odolab study NAME [options]     = python -m studies.<module> [options] (odolab.cli.study)
    odolab --help                   lists them (odolab help compare = odolab compare --help)
    odolab --version                the installed version

Each subcommand imports its module only when it runs, so ``odolab --help`` is quick and a command
that needs torch is the only one that loads it. A subcommand's help and messages carry the name it
was typed with (``usage: odolab compare``; :func:`odolab.cli.help_text.command_face`).
"""

from __future__ import annotations

import contextlib
import importlib
import os
import sys
from collections.abc import Callable, Sequence

#: subcommand -> (its ``python -m`` module, the module of its ``main`` (``module:family`` for a trainer,
#: :func:`odolab.cli.train.main_for`), one line of help)
COMMANDS: dict[str, tuple[str, str, str]] = {
    "compare": (
        "odolab.compare",
        "odolab.cli.compare",
        "run odometers on simulator episodes or TUM folders; tables, figures, report",
    ),
    "evaluate": (
        "odolab.evaluate",
        "odolab.cli.evaluate",
        "ATE, RPE and KITTI t_rel/r_rel of trajectory files (TUM or KITTI format)",
    ),
    "navigate": (
        "odolab.navigate",
        "odolab.cli.navigate",
        "PointGoal navigation with each odometer; success, SPL, report",
    ),
    "navigation-diff": (
        "odolab.navigation.diff",
        "odolab.cli.navigation_diff",
        "compare two navigation runs episode by episode",
    ),
    "simcard": ("odolab.simcard", "odolab.cli.simcard", "the simulator's statistics beside the paper's"),
    "bench": (
        "odolab.bench",
        "odolab.cli.bench",
        "speed of the simulator, odometers, navigation, evaluation and training",
    ),
    "training-data": (
        "odolab.training_data",
        "odolab.cli.training_data",
        "render episodes into training shards (resumable, on Ray)",
    ),
    "train-robust-vo": (
        "odolab.learned.robust_vo.train",
        "odolab.cli.train:robust-vo",
        "train the robust VO from a TOML recipe (resumable)",
    ),
    "train-deepvo": (
        "odolab.learned.deepvo.train",
        "odolab.cli.train:deepvo",
        "train DeepVO from a TOML recipe (resumable)",
    ),
    "train-depth-corrector": (
        "odolab.learned.depth_corrector.train",
        "odolab.cli.train:depth-corrector",
        "train the depth corrector of denoised(...) from a TOML recipe (resumable)",
    ),
    "train-pose-corrector": (
        "odolab.learned.pose_corrector.train",
        "odolab.cli.train:pose-corrector",
        "train the pose corrector of corrected(...) from a TOML recipe (resumable)",
    ),
    "measure-tum": (
        "baselines.measure_tum",
        "odolab.cli.measure_tum",
        "per-pair errors and speed of odometers on a TUM RGB-D folder",
    ),
    "study": ("studies.<name>", "odolab.cli.study", "run a study of studies/ (odolab study --help lists them)"),
    "calibrate-fusion": (
        "odolab.fusion.calibrate",
        "odolab.cli.calibrate_fusion",
        "calibrate the noise models of fused(...) on the val split",
    ),
}


def usage() -> str:
    """The subcommand list."""
    width = max(map(len, COMMANDS))
    lines = ["usage: odolab COMMAND [options]   (odolab COMMAND --help for a command's options)", "", "commands:"]
    lines += [f"  {name:<{width}}  {text}  (python -m {module})" for name, (module, _, text) in COMMANDS.items()]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``odolab COMMAND ...``; exit code 2 with the list for an unknown or missing command."""
    from odolab.cli.args import run_cli
    from odolab.cli.help_text import command_face

    args = list(sys.argv[1:] if argv is None else argv)
    if args[:1] == ["help"] and len(args) > 1:  # odolab help compare = odolab compare --help
        args = [*args[1:], "--help"]
    if not args or args[0] in ("-h", "--help", "help"):
        return _print(usage(), sys.stdout if args else sys.stderr, 0 if args else 2)
    if args[0] in ("-V", "--version"):
        from importlib.metadata import PackageNotFoundError, version

        try:
            return _print(f"odolab {version('odolab')}", sys.stdout, 0)
        except PackageNotFoundError:
            return _print("odolab (version unknown: not installed as a package)", sys.stdout, 0)
    name, rest = args[0], args[1:]
    if name not in COMMANDS:
        import difflib

        near = difflib.get_close_matches(name.lower().replace("_", "-"), COMMANDS, n=1, cutoff=0.6)
        hint = f"; did you mean {near[0]!r}?" if near else ""
        print(f"odolab: error: unknown command {name!r}; expected one of {', '.join(COMMANDS)}{hint}", file=sys.stderr)
        return 2
    entry = entry_of(name)
    face = f"odolab {name}"
    if name == "study" and rest and not rest[0].startswith("-"):  # odolab study e-table: named in full
        face = f"odolab study {rest[0]}"
    with command_face(face), _current_folder_importable():  # as under python -m
        return run_cli(entry, face, rest)


def entry_of(name: str) -> Callable[[Sequence[str] | None], int | None]:
    """``main(argv)`` of subcommand ``name`` (its module imported now)."""
    module, _, family = COMMANDS[name][1].partition(":")
    loaded = importlib.import_module(module)
    return loaded.main_for(family) if family else loaded.main


@contextlib.contextmanager
def _current_folder_importable():
    """The current folder first on ``sys.path`` while a command runs, as ``python -m`` puts it, so a
    plug-in ``module:Class`` next to the user loads under both faces of a command."""
    here = os.getcwd()
    added = here not in sys.path and "" not in sys.path
    if added:
        sys.path.insert(0, here)
    try:
        yield
    finally:
        if added and here in sys.path:
            sys.path.remove(here)


def _print(text: str, stream, code: int) -> int:
    """``text`` on ``stream``; a reader that went away (``odolab --help | head -1``) is no error."""
    from odolab.cli.args import quiet_broken_pipe

    try:
        print(text, file=stream, flush=True)
    except BrokenPipeError:
        quiet_broken_pipe()
    return code


if __name__ == "__main__":
    from odolab.cli.args import exit_process

    exit_process(main())
