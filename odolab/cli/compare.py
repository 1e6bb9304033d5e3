"""``python -m odolab.compare``: run odometers side by side on identical episodes (or a TUM folder).

With no arguments: every available odometer on 5 test-split episodes of at most 60 steps, seed 0,
written to ``runs/compare`` (table.csv, report.html, figures, trajectories). Episodes are cached
(``--cache``) and generated as parallel Ray tasks (``--ray-address`` for a cluster).
"""

from __future__ import annotations

import argparse
import shlex
import sys
from collections.abc import Sequence
from pathlib import Path

from odolab.cli.args import (
    ArgumentParser,
    UsageError,
    add_odometer_option,
    add_scene_options,
    add_setting,
    check_cache_dir,
    check_ray_option,
    check_report_dir,
    execution_of,
    exit_process,
    given_options,
    hold_folder,
    path_arg,
    pinhole,
    run_cli,
    scene_words,
    scenes_of,
    setting_help,
    setting_type,
)
from odolab.config import range_text
from odolab.io.lock import FolderLock
from odolab.odometry.odometer import OdometerListError, available_odometers, parse_odometer_list, standalone_odometers
from odolab.odometry.options import OptionError, merge_options, naming_the_file, parse_assignments, read_options_file
from odolab.reporting.pipeline import (
    DEFAULT_CACHE,
    ComparisonConfig,
    ComparisonError,
    failure_reasons,
    load_odometers,
    run_comparison,
    tum_sequences,
)
from odolab.sim.episodes import NoiseConfig
from odolab.sim.mesh_scenes import MeshError
from odolab.sim.scenes import SPLITS

#: Options that choose simulator episodes; with --tum they would be silently meaningless.
SIMULATOR_OPTIONS = (
    "--episodes",
    "--seed",
    "--split",
    "--scenes",
    "--scene-up",
    "--scene-family",
    "--scene-unit",
    "--max-steps",
    "--rgb-noise",
    "--depth-noise",
    "--actuation-noise",
    "--cache",
    "--no-cache",
    "--ray-address",
    "--serial",
)


#: Stands for the list of every odometer in --odometers' help until the help is shown.
_EVERY = "<every odometer>"


class _Parser(ArgumentParser):
    """Lists every odometer in ``--help`` only when the help is shown: telling the composites apart
    imports each odometer's class (:func:`odolab.odometry.odometer.standalone_odometers`)."""

    def format_help(self) -> str:
        for action in self._actions:
            if action.help and _EVERY in action.help:
                action.help = action.help.replace(_EVERY, ", ".join(standalone_odometers()))
        return super().format_help()


def build_parser() -> argparse.ArgumentParser:
    ap = _Parser(prog="python -m odolab.compare", description=__doc__.splitlines()[0])
    ap.add_argument(
        "--odometers",
        default=None,
        help="comma-separated names, module:Class or path/to/file.py:Class, or fused(a,b,...) of "
        f"several (default: all of {_EVERY})",
    )
    add_setting(ap, "--episodes", ComparisonConfig, "episodes")
    add_setting(ap, "--seed", ComparisonConfig, "seed")
    ap.add_argument("--split", default="test", help=f"scene split: {' | '.join(SPLITS)} (default test)")
    add_scene_options(ap)
    add_setting(ap, "--max-steps", ComparisonConfig, "max_steps")
    add_setting(ap, "--step-timeout", ComparisonConfig, "step_timeout")
    for kind in ("rgb", "depth", "actuation"):
        ap.add_argument(
            f"--{kind}-noise",
            type=setting_type(f"--{kind}-noise", NoiseConfig, kind),
            default=getattr(NoiseConfig(), kind),
            metavar="M",
            help=setting_help(NoiseConfig, kind),
        )
    ap.add_argument(
        "--out",
        type=path_arg("--out"),
        default=Path("runs/compare"),
        help="output folder (default runs/compare); files a previous run wrote there are replaced",
    )
    ap.add_argument(
        "--tum",
        type=path_arg("--tum"),
        default=None,
        help="run on a TUM RGB-D folder instead of the simulator (simulator options are then refused)",
    )
    ap.add_argument(
        "--depth-scale",
        type=setting_type("--depth-scale", ComparisonConfig, "tum_depth_scale"),
        default=None,
        metavar="S",
        help=f"--tum: depth PNG values per metre, {range_text(ComparisonConfig, 'tum_depth_scale')} (default TUM's "
        "5000; millimetres: 1000)",
    )
    ap.add_argument(
        "--intrinsics",
        type=pinhole("--intrinsics"),
        default=None,
        metavar="FX,FY,CX,CY",
        help="--tum: the camera's pinhole in pixels (default: the TUM camera fr1/fr2/fr3 the folder's name says)",
    )
    ap.add_argument(
        "--cache", type=path_arg("--cache"), default=DEFAULT_CACHE, help=f"episode cache (default {DEFAULT_CACHE})"
    )
    ap.add_argument("--no-cache", action="store_true", help="do not read or write the episode cache")
    ap.add_argument(
        "--ray-address",
        default=None,
        help="Ray cluster address host:port or ray://host:port (default: a local instance)",
    )
    ap.add_argument("--serial", action="store_true", help="generate episodes in this process, without Ray")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    add_odometer_option(
        ap, "icp.max_depth=4.0 or examples.tiny_learned:TinyLearnedOdometer.checkpoint=runs/tiny.pt (repeatable)"
    )
    ap.add_argument(
        "--config",
        type=path_arg("--config"),
        default=None,
        metavar="FILE.toml",
        help='odometer options from a TOML file: [odometers."NAME"] key = value (--odometer-option overrides it)',
    )
    return ap


def _check_before_work(args: argparse.Namespace, argv: Sequence[str]) -> None:
    """Every check of the user's input that makes nothing, done before any odometer is made (then :func:`_check_folders`)."""
    if args.split not in SPLITS:
        raise UsageError(f"--split {args.split!r} is not a split; choose one of {', '.join(SPLITS)}")
    if args.tum is None:
        for option in given_options(argv, ("--depth-scale", "--intrinsics")):
            raise UsageError(f"{option} describes a TUM folder's images; it needs --tum")
    if args.tum is not None:
        from odolab.io.tum_rgbd import tum_camera_for

        if not args.tum.is_dir():  # before the folder's name is read for its camera
            what = (
                "is a link to nothing"
                if args.tum.is_symlink() and not args.tum.exists()
                else "is a file, not a folder"
                if args.tum.exists()
                else "no such folder"
            )
            raise UsageError(f"--tum {args.tum}: {what}; expected a TUM RGB-D sequence folder (rgb.txt, depth.txt)")
        if args.intrinsics is None and tum_camera_for(args.tum) is None:
            raise UsageError(
                f"--tum {args.tum}: cannot tell the camera from the folder's name (no fr1, fr2 or fr3 "
                "in it); give it with --intrinsics fx,fy,cx,cy (pixels)"
            )
        ignored = given_options(argv, SIMULATOR_OPTIONS)
        if ignored:
            raise UsageError(
                f"{', '.join(ignored)}: simulator option{'s' if len(ignored) > 1 else ''}, "
                "meaningless with --tum (a TUM folder is one real recording); drop "
                f"{'them' if len(ignored) > 1 else 'it'}"
            )
    else:
        if args.no_cache and given_options(argv, ["--cache"]):
            raise UsageError("--cache and --no-cache contradict each other; give one of them")
        check_ray_option(args.ray_address, args.serial)  # and RAY_ADDRESS: before any folder is made


def _check_folders(args: argparse.Namespace) -> FolderLock:
    """The cache and report folders: made if missing and checked (after every other check); returns
    the hold of this run on ``--out`` (a second run into it is refused at once)."""
    if args.tum is None and not args.no_cache:
        check_cache_dir(args.cache, "--cache")  # read-only: read; what it lacks is made, not written
    check_report_dir(args.out, "--out")
    from odolab.io.owned import UnsafeOutputError
    from odolab.reporting.report import MANIFEST, ManifestError, OutputFolder

    held = hold_folder(args.out, "--out")
    try:  # what the previous run wrote, and this run's fixed files, can be replaced without leaving --out
        OutputFolder.check(
            args.out,
            files=("table.csv", "table_per_action.csv", "table_paired.csv", "errors.png", "report.html", MANIFEST),
            folders=("trajectories",),
        )
    except ManifestError as exc:
        held.release()
        raise UsageError(f"--out {exc}") from None
    except UnsafeOutputError as exc:
        held.release()
        raise UsageError(f"--out: {exc}; remove it or choose another --out") from None
    return held


def _config(args: argparse.Namespace, argv: Sequence[str]) -> ComparisonConfig:

    try:
        from_file = read_options_file(args.config) if args.config else {}
    except OptionError as exc:
        raise UsageError(f"--config {exc}") from None  # the file's problem, under the option that named it
    try:
        options = merge_options(from_file, parse_assignments(args.odometer_option))
    except OptionError as exc:
        raise UsageError(str(exc)) from None
    names = None
    if args.odometers is not None:
        try:
            names = parse_odometer_list(args.odometers)
        except ValueError as exc:
            said = exc.named("--odometers") if isinstance(exc, OdometerListError) else str(exc)
            raise UsageError(f"{said}; available: {', '.join(available_odometers())}") from None
    scenes = scenes_of(args, argv) if args.tum is None else None  # with --tum, refused below as every simulator option
    return ComparisonConfig(
        odometers=names,
        scenes=scenes,
        family=args.scene_family if args.tum is None else "boxes",
        options=options,
        episodes=args.episodes,
        seed=args.seed,
        split=args.split,
        max_steps=args.max_steps,
        step_timeout=args.step_timeout,
        noise=NoiseConfig(rgb=args.rgb_noise, depth=args.depth_noise, actuation=args.actuation_noise),
        tum=args.tum,
        tum_depth_scale=args.depth_scale,
        tum_intrinsics=args.intrinsics,
        cache=None if args.no_cache else args.cache,
        execution=execution_of(args),
        command=None if args.tum is not None else _command(args),
    )


def _command(args: argparse.Namespace) -> str:
    """The simulator episodes' settings as this command line's options, for the report's notes."""
    return (
        f"python -m odolab.compare --episodes {args.episodes} --seed {args.seed} "
        f"--split {args.split} --max-steps {args.max_steps} --rgb-noise {args.rgb_noise:g} "
        f"--depth-noise {args.depth_noise:g} --actuation-noise {args.actuation_noise:g}"
        + scene_words(args)
        + "".join(f" --{flag} {shlex.quote(str(value))}" for flag, value in _chosen(args))
    )


def _chosen(args: argparse.Namespace) -> list[tuple[str, object]]:
    """The options that choose the odometers, as given (flag without dashes, value)."""
    given = [("odometers", args.odometers)] if args.odometers is not None else []
    given += [("config", args.config)] if args.config is not None else []
    return given + [("odometer-option", o) for o in args.odometer_option or []]


def main(argv: Sequence[str] | None = None) -> int:
    """Parse, check, run the comparison (:func:`odolab.reporting.pipeline.run_comparison`), print and write."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    config = _config(args, argv)
    _check_before_work(args, argv)
    if not args.quiet and sys.stderr.isatty():  # at once on a terminal: loading the odometers takes seconds
        print("loading odometers", end="\r", file=sys.stderr, flush=True)  # the next line writes over it
    try:  # every name and option checked before a folder is made
        odometers = load_odometers(config.odometers, config.options)
    except ComparisonError as exc:
        raise UsageError(naming_the_file(str(exc), args.config, bool(args.odometer_option))) from None
    sequences = None
    if args.tum is not None:  # the folder read and checked before --out is made
        try:
            sequences = tum_sequences(config)
        except ComparisonError as exc:
            raise UsageError(f"--tum {args.tum}: {exc}") from None
    with _check_folders(args):  # --out held until the report is written
        from odolab.core.progress import StepProgressBar
        from odolab.reporting.report import format_table, write_report
        from odolab.running.paired import paired_verdicts
        from odolab.running.summary import every_step_failed

        try:
            result = run_comparison(
                config, observer=StepProgressBar(disable=args.quiet), odometers=odometers, sequences=sequences
            )
        except ComparisonError as exc:
            raise UsageError(naming_the_file(str(exc), args.config, bool(args.odometer_option))) from None
        except MeshError as exc:  # a mesh file changed since it was read
            raise UsageError(f"--scenes {exc}") from None
        for warning in result.warnings:
            print(f"note: {warning}", file=sys.stderr)
        print(result.title)  # the table first: nothing that follows can lose it
        print(format_table(result.rows, real_data=args.tum is not None))
        for line in paired_verdicts(result.paired_rows):
            print(line)
        write_report(
            args.out,
            rows=result.rows,
            action_rows=result.action_rows,
            results=result.results,
            title=result.title,
            notes=result.notes,
            plans=result.plans,
            configs=result.configs,
            paired_rows=result.paired_rows,
        )
        for r in result.results:
            for e in r.errors[:1]:
                print(f"note: {r.odometer} raised on {r.sequence}: {e}")
        for line in every_step_failed(result.rows):
            print(f"note: {line}")
        for name, reasons in failure_reasons(result.results).items():
            print(f"note: {name} failed steps by reason: " + ", ".join(f"{k} {v}" for k, v in sorted(reasons.items())))
        print(f"wrote {args.out / 'table.csv'} and {args.out / 'report.html'}")
    return 0


if __name__ == "__main__":
    exit_process(run_cli(main, "python -m odolab.compare"))
