"""The trainers' command line, one for every learned model (:data:`TRAINERS`):

    odolab train-robust-vo --config RECIPE [options] = python -m odolab.learned.robust_vo.train --config RECIPE ...
    odolab train-deepvo ...                          = python -m odolab.learned.deepvo.train ...
    odolab train-depth-corrector ...                 = python -m odolab.learned.depth_corrector.train ...
    odolab train-pose-corrector ...                  = python -m odolab.learned.pose_corrector.train ...

A TOML recipe, where states, curves and the model go, a time budget, the device and thread count;
each trainer module describes itself in a :class:`odolab.learned.training.trainer.Trainer` named
``TRAINER``. Mistakes are one line and exit code 2, before any work."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from odolab.cli.args import (
    ArgumentParser,
    UsageError,
    add_setting,
    check_folder_path,
    check_not_nested,
    check_output_dir,
    check_output_file,
    check_ray_option,
    check_report_dir,
    exit_process,
    file_arg,
    folder_owner,
    path_arg,
    run_cli,
    setting_help,
    setting_type,
)
from odolab.config import ChangeError, check, setting
from odolab.core.parallel import Execution

__all__ = [
    "TRAINERS",
    "TrainingJob",
    "check_workers",
    "command",
    "exit_process",
    "main_for",
    "parse_training_command",
    "train",
    "training_parser",
]

#: family -> the module whose ``TRAINER`` describes it (its ``python -m`` name)
TRAINERS: dict[str, str] = {
    "robust-vo": "odolab.learned.robust_vo.train",
    "deepvo": "odolab.learned.deepvo.train",
    "depth-corrector": "odolab.learned.depth_corrector.train",
    "pose-corrector": "odolab.learned.pose_corrector.train",
}


def trainer_of(family: str):
    """The :class:`~odolab.learned.training.trainer.Trainer` of ``family`` (its module imported now: torch loads)."""
    return importlib.import_module(TRAINERS[family]).TRAINER


@dataclass(frozen=True)
class TrainingJob:
    """What a training command was asked to do: the recipe (``config``), the torch device, where the
    per-epoch states (``work``), the curves (``reports``) and the finished model (``export``) go, the
    time budget in hours (None: no limit), where data are made and whether with progress bars
    (``execution``), and the command line that asked (for the record)."""

    config: Any
    device: Any
    work: Path
    reports: Path
    export: Path
    execution: Execution
    command: str
    hours: float | None = setting(
        None, range=(0.001, 1000.0), doc="stop before an epoch that would start after this many hours (rerun to resume)"
    )
    workers: int = setting(
        1,
        range=(1, 1024),
        doc="data-parallel training workers on Ray Train, each taking a share of every batch (1: in this "
        "process, without Ray)",
    )
    gpus_per_worker: float = setting(
        0.0, range=(0.0, 64.0), doc="GPUs per training worker with --workers (0: CPU workers, gloo)"
    )
    threads: int | None = setting(None, range=(1, 1024), doc="torch CPU threads")

    def __post_init__(self) -> None:
        check(self)


def training_parser(prog: str, description: str, family: str, set_example: str = "seed=1") -> ArgumentParser:
    """The shared options; ``family`` names the default folders (``runs/<family>/<recipe name>``,
    ``reports/<family>/<recipe name>``); ``set_example``: changes of this family's recipes for
    ``--set``'s help."""
    ap = ArgumentParser(prog=prog, description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", type=path_arg("--config"), required=True, help="TOML recipe")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="PATH=VALUE",
        help=f"change one recipe value, e.g. --set {set_example} (a changed recipe is another run: give it its own --work)",
    )
    ap.add_argument(
        "--work",
        type=path_arg("--work"),
        default=None,
        help=f"per-epoch training states (default runs/{family}/<recipe name>)",
    )
    ap.add_argument(
        "--reports",
        type=path_arg("--reports"),
        default=None,
        help=f"validation curves and status (default reports/{family}/<recipe name>)",
    )
    ap.add_argument(
        "--export",
        type=file_arg("--export"),
        default=None,
        help="the trained model, written when every epoch is done (default <work>/model.pt)",
    )
    ap.add_argument(
        "--hours",
        type=setting_type("--hours", TrainingJob, "hours"),
        default=None,
        help=setting_help(TrainingJob, "hours", "no limit"),
    )
    ap.add_argument("--device", default=None, help="torch device (default: a GPU when present, else cpu)")
    ap.add_argument(
        "--threads",
        type=setting_type("--threads", TrainingJob, "threads"),
        default=None,
        help=setting_help(TrainingJob, "threads", "torch's choice, all cores"),
    )
    ap.add_argument(
        "--ray-address",
        default=None,
        help="Ray cluster for making the data and the training workers (default: a local instance)",
    )
    add_setting(ap, "--workers", TrainingJob, "workers")
    add_setting(ap, "--gpus-per-worker", TrainingJob, "gpus_per_worker")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    ap.set_defaults(family=family)
    return ap


def parse_training_command(
    ap: ArgumentParser,
    argv: Sequence[str] | None,
    load_config: Callable[[str, Sequence[str]], Any],
    state_files: Callable[[Any, Path], dict[str, Path]] | None = None,
    check_start: Callable[[Any, Path], object] | None = None,
) -> TrainingJob:
    """Parse, read the recipe with ``load_config(path, --set changes)`` (its ``ValueError`` becomes a
    usage error), pick the device, set the thread count and check every output path and the model
    the recipe starts from (``check_start``) before any folder is made: ``--export`` must not be the
    recipe, a training state (``state_files``, default
    :func:`~odolab.learned.training.trainer.stage_states`) or a file that is not
    a model odolab exported."""
    from odolab.learned.training.checkpoints import check_export
    from odolab.learned.training.device import pick_device, set_threads
    from odolab.learned.training.trainer import stage_states
    from odolab.learned.training.validation import other_training

    args = ap.parse_args(argv)
    _check_not_blank(args.config)
    try:
        config = load_config(str(args.config), args.set)
    except ChangeError as exc:
        raise UsageError(f"--set {exc}") from None
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    try:
        device = pick_device(args.device)
    except ValueError as exc:
        raise UsageError(f"--device: {exc}") from None
    name = args.config.stem
    work = args.work or Path("runs") / args.family / name
    reports = args.reports or Path("reports") / args.family / name
    export = args.export or work / "model.pt"
    check_ray_option(args.ray_address)  # and RAY_ADDRESS, which ray.init() heeds as it would --ray-address
    check_workers(args.workers, args.gpus_per_worker, args.device, device, args.ray_address)
    for kept in REPORT_FILES:  # the reports a run writes beside the model: found now, not after training
        if _same_path(export, reports / kept):
            raise UsageError(
                f"--export {export}: expected a file apart from the reports, found the path of "
                f"{kept} in --reports {reports}, which the run writes; give --export another path"
            )
    try:  # never the recipe, a training state or a file no export wrote
        check_export(export, args.config, (state_files or stage_states)(config, work), kind=f"odolab-{args.family}")
    except ValueError as exc:
        raise UsageError(str(exc) if args.export else f"{exc} (the default --export is <work>/model.pt)") from None
    if check_start is not None and getattr(config, "init", ""):
        try:
            check_start(config, export)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    other = other_training(reports, " ".join([ap.prog, *(list(argv) if argv is not None else sys.argv[1:])]))
    if other:  # never over another training's reports
        raise UsageError(f"--reports {reports}: {other}; choose another --reports")
    check_not_nested(work, "--work", own=reports)  # its states may sit in its own --reports
    owner = folder_owner(work) if work.is_dir() else None
    if owner is not None:
        raise UsageError(f"--work {work}: is {owner}; choose another --work")
    _check_work_files(work)
    if not export.parent.is_dir() and not any(_same_path(export.parent, p) for p in (work, reports)):
        check_output_file(export, "--export")  # its folder is missing: refused before any folder is made
    check_folder_path(work, "--work")  # both found fit before either is made
    check_folder_path(reports, "--reports")
    made = _first_missing(work)
    check_output_dir(work, "--work")  # made only once every check above has passed
    try:
        check_report_dir(reports, "--reports", manifest="training.json")  # never over a folder of the user's files
    except UsageError:
        _remove_empty(made)  # a refused run leaves no folder behind
        raise
    check_output_file(export, "--export")
    if args.threads:
        set_threads(args.threads)
    argv = list(argv) if argv is not None else sys.argv[1:]
    return TrainingJob(
        config,
        device,
        work,
        reports,
        export,
        Execution(ray_address=args.ray_address, progress=not args.quiet),
        " ".join([ap.prog, *argv]),
        hours=args.hours,
        workers=args.workers,
        gpus_per_worker=args.gpus_per_worker,
        threads=args.threads,
    )


#: The files a training writes under ``--reports`` (odolab.learned.training.validation).
REPORT_FILES = ("training.json", "curves.csv", "curves.png")


def _first_missing(path: Path) -> Path | None:
    """The outermost folder of ``path`` that does not exist yet (what making it would create), or None."""
    missing = None
    for p in [path, *path.parents]:
        if p.exists() or p.is_symlink():
            break
        missing = p
    return missing


def _remove_empty(top: Path | None) -> None:
    """Remove folder ``top`` if it holds nothing but empty folders (what this run made of it)."""
    if top is None or not top.is_dir() or top.is_symlink():
        return
    if any(files for _, _, files in os.walk(top)):
        return
    for root, dirs, _ in sorted(os.walk(top), key=lambda w: -len(w[0])):
        os.rmdir(root)


def _check_not_blank(config: Path) -> None:
    """:class:`UsageError` for a recipe file with nothing in it (an empty file, ``/dev/null``):
    every field at its default is never what a training was asked for."""
    try:
        blank = config.stat().st_size == 0 or (config.is_file() and not config.read_bytes()[:65536].strip())
    except OSError:
        return  # the recipe's reader words it
    if blank:
        raise UsageError(
            f"--config {config}: an empty recipe; expected a TOML training recipe (the shipped ones are in studies/)"
        )


def _check_work_files(work: Path) -> None:
    """:class:`UsageError` when folder ``work`` holds anything but training states and models
    (``.pt`` files), a training's reports (:data:`REPORT_FILES`) and hidden files (an atomic write's
    temporary file): the states are written there, never into a folder of the user's files."""
    if not work.is_dir():
        return
    for entry in sorted(work.iterdir()):
        ours = entry.name.startswith(".") or entry.name in REPORT_FILES or entry.suffix == ".pt"
        if not (ours and entry.is_file()):
            raise UsageError(
                f"--work {work}: expected a new folder or one of training states (.pt files), found "
                f"{entry.name!r}; choose a new or empty --work"
            )


def _same_path(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` name one file (links and ``..`` resolved; either may not exist yet)."""
    try:
        return os.path.realpath(a) == os.path.realpath(b)
    except (OSError, ValueError):
        return False


def check_workers(
    workers: int,
    gpus_per_worker: float,
    device_name: str | None,
    device: Any,
    ray_address: str | None,
    resources: Callable[[], tuple[float, float]] | None = None,
) -> None:
    """:class:`UsageError`, before any work, for ``--workers`` / ``--gpus-per-worker`` / ``--device``
    that cannot run as asked: GPUs per worker without workers, a ``--device`` the workers would not
    use (they train on a GPU exactly when ``--gpus-per-worker`` gives them one), or more than a
    local Ray instance holds (Ray Train would wait for them forever). A cluster (``--ray-address``
    or ``RAY_ADDRESS``) may grow, so its size is not checked here."""
    if workers == 1:
        if gpus_per_worker:
            raise UsageError(
                "--gpus-per-worker places Ray Train workers; with --workers 1 training runs here "
                "(use --device cuda for this machine's GPU)"
            )
        return
    if device_name:
        if device.type not in ("cpu", "cuda"):
            raise UsageError(
                f"--device {device_name} with --workers {workers}: Ray Train workers train on "
                "CPUs, or on CUDA GPUs with --gpus-per-worker"
            )
        if device.type == "cuda" and not gpus_per_worker:
            raise UsageError(
                f"--device {device_name} with --workers {workers}: a worker gets a GPU only with "
                "--gpus-per-worker (e.g. --gpus-per-worker 1); without it they train on CPUs"
            )
        if device.type == "cpu" and gpus_per_worker:
            raise UsageError(
                f"--device {device_name} contradicts --gpus-per-worker {gpus_per_worker:g}: give one "
                "of them (workers with GPUs train on them)"
            )
    if ray_address is not None or os.environ.get("RAY_ADDRESS"):
        return
    if resources is None:
        from odolab.learned.training.device import local_ray_resources as resources
    cpus, gpus = resources()
    if workers > cpus:
        raise UsageError(
            f"--workers {workers}: a local Ray instance here has {cpus:g} CPUs and each worker "
            f"takes one; use --workers {max(1, int(cpus))} or fewer, or --ray-address for a cluster"
        )
    if gpus_per_worker * workers > gpus + 1e-9:
        raise UsageError(
            f"--workers {workers} --gpus-per-worker {gpus_per_worker:g}: needs "
            f"{gpus_per_worker * workers:g} GPUs, this machine has {gpus:g}; use fewer, or "
            "--ray-address for a cluster"
        )


def train(family: str, argv: Sequence[str] | None, prog: str) -> int:
    """The trainer of ``family`` as a command named ``prog``: parse (:func:`parse_training_command`),
    hold the folders, run the trainer (its ``ValueError`` becomes one line and exit 2) and say
    whether it finished or stopped."""
    trainer = trainer_of(family)
    ap = training_parser(prog, trainer.description, family, trainer.set_example)
    job = parse_training_command(ap, argv, trainer.load_config, trainer.state_files, trainer.check_start)
    with hold_training_folders(job):
        done = _train(job, trainer.run)
    said = f"finished; model written to {job.export}" if done else "stopped; run the same command to resume"
    print(f"{said} (curves: {job.reports / 'curves.png'})")
    return 0


def main_for(family: str) -> Callable[[Sequence[str] | None], int]:
    """``main(argv)`` of the ``odolab train-<family>`` subcommand."""
    return lambda argv: train(family, argv, f"odolab train-{family}")


def command(family: str, argv: Sequence[str] | None = None) -> int:
    """``python -m <the trainer's module>``: :func:`train` under :func:`~odolab.cli.args.run_cli`
    (one line and exit 2 for a user's mistake; 130 for Ctrl-C)."""
    prog = f"python -m {TRAINERS[family]}"
    return run_cli(lambda args: train(family, args, prog), prog, argv)


@contextlib.contextmanager
def hold_training_folders(job: TrainingJob) -> Iterator[None]:
    """Hold ``--work`` and ``--reports`` for this training while the block runs, or :class:`UsageError`
    at once when another odolab run holds either (two trainings into one folder would overwrite each
    other's states, curves and model); the system releases them if the process dies."""
    from odolab.io.lock import FolderInUseError, lock_folder

    with contextlib.ExitStack() as held:
        for folder, option in ((job.work, "--work"), (job.reports, "--reports")):
            if option == "--reports" and _same_path(job.reports, job.work):
                continue
            try:
                held.enter_context(lock_folder(folder))
            except FolderInUseError as exc:
                raise UsageError(exc.named(option)) from None
        yield


def _train(job: TrainingJob, run: Callable[..., bool]) -> bool:
    """``run`` the job (its ``ValueError`` becomes one line); True when every epoch is done."""
    try:
        return run(
            job.config,
            work=job.work,
            reports=job.reports,
            export=job.export,
            device=job.device,
            hours=job.hours,
            execution=job.execution,
            command=job.command,
            workers=job.workers,
            gpus_per_worker=job.gpus_per_worker,
        )
    except ValueError as exc:
        raise UsageError(str(exc)) from None
