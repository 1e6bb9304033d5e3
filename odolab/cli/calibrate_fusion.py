"""``python -m odolab.fusion.calibrate``: calibrate the covariances of fusion inputs on held-out
episodes, or check a calibration (:mod:`odolab.fusion.calibrate`, :mod:`odolab.fusion.calibration`).

    python -m odolab.fusion.calibrate --odometers action-prior,icp,open3d-rgbd,robust-vo \
        --split val --episodes 20 --max-steps 100 --out odolab/data/fusion/calibration.json   # the shipped one
    python -m odolab.fusion.calibrate --check odolab/data/fusion/calibration.json --split test --episodes 20
"""

from __future__ import annotations

import shlex
import sys
from collections.abc import Sequence
from pathlib import Path

from odolab.api import load_episodes
from odolab.cli.args import (
    ArgumentParser,
    UsageError,
    add_setting,
    check_cache_dir,
    check_output_file,
    check_ray_option,
    execution_of,
    exit_process,
    file_arg,
    given_options,
    path_arg,
    run_cli,
)
from odolab.core.progress import StepProgressBar
from odolab.core.types import MOTION_ACTIONS
from odolab.fusion import calibrate
from odolab.fusion.calibrate import CalibrationRun, check_input, near_views, steps_of
from odolab.fusion.calibration import (
    COMMAND,
    MIN_STEPS,
    NEAR,
    Calibration,
    fit_input,
    what_file,
)
from odolab.fusion.odometer import is_fused
from odolab.odometry.odometer import OdometerListError, parse_odometer_list, standalone_odometers
from odolab.reporting.pipeline import DEFAULT_CACHE, ComparisonError, load_odometers, odometer_names
from odolab.running.runner import run as run_odometers
from odolab.sim.episodes import EpisodeCache
from odolab.sim.scenes import SPLITS

#: Fewest steps (--episodes x --max-steps) worth calibrating on.
MIN_RUN_STEPS = 30


def build_parser() -> ArgumentParser:
    """The command line of ``python -m odolab.fusion.calibrate``."""
    ap = ArgumentParser(prog="python -m odolab.fusion.calibrate", description=calibrate.__doc__.splitlines()[0])
    ap.add_argument(
        "--odometers",
        default="action-prior,icp,open3d-rgbd,robust-vo",
        help="comma-separated inputs to calibrate (default: %(default)s)",
    )
    ap.add_argument(
        "--check", type=path_arg("--check"), default=None, help="check this calibration instead of fitting one"
    )
    ap.add_argument(
        "--out",
        type=file_arg("--out"),
        default=Path("runs/fusion/calibration.json"),
        help="calibration file to write (default %(default)s; its folder is created)",
    )
    add_setting(ap, "--near-depth", CalibrationRun, "near_depth")
    ap.add_argument("--split", default="val", help=f"{' | '.join(SPLITS)} (default val)")
    for option in ("--episodes", "--max-steps", "--seed"):
        add_setting(ap, option, CalibrationRun, option[2:].replace("-", "_"))
    ap.add_argument(
        "--cache", type=path_arg("--cache"), default=DEFAULT_CACHE, help=f"episode cache (default {DEFAULT_CACHE})"
    )
    ap.add_argument("--ray-address", default=None)
    ap.add_argument("--serial", action="store_true", help="generate episodes in this process (no Ray)")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    args.argv = list(argv) if argv is not None else sys.argv[1:]
    return run(args)


def run(args) -> int:
    """Fit a calibration of ``args.odometers`` on held-out episodes and write it, or check
    ``args.check`` on them (printed); 0 when done. ``args.argv``: the command's arguments."""
    names, calibration = _inputs(args)
    check_ray_option(args.ray_address, args.serial)  # and RAY_ADDRESS: before any folder is made
    if calibration is None:
        try:
            args.out.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UsageError(f"--out {args.out}: cannot make its folder ({exc.strerror or exc})") from None
        check_output_file(args.out, "--out", suffixes=[".json"])
    check_cache_dir(args.cache, "--cache")  # a read-only cache is read
    try:
        odometers = load_odometers(names)
    except ComparisonError as exc:
        raise UsageError(str(exc)) from None
    specs = CalibrationRun(args.near_depth, args.episodes, args.max_steps, args.seed).specs(args.split)
    episodes = load_episodes(specs, EpisodeCache(args.cache), execution=execution_of(args))
    results = run_odometers(odometers, episodes, observer=StepProgressBar(disable=args.quiet))
    near = near_views(episodes, calibration.near_depth if calibration is not None else args.near_depth)
    fitted = {}
    for name in names:
        xi, actions, own, _, close = steps_of([r for r in results if r.odometer == name], near)
        if calibration is not None:
            _print_check(name, check_input(calibration.for_input(name), xi, actions, own, close))
            continue
        try:
            fitted[name] = fit_input(xi, actions, own, close)
        except ValueError as exc:
            raise UsageError(f"{name}: {exc}; use more --episodes or --max-steps") from None
        _print_fit(name, fitted[name], any(c is not None for c in own), getattr(odometers[name], "oracle", False))
    if calibration is None:
        command = f"{COMMAND} " + " ".join(shlex.quote(a) for a in args.argv)
        Calibration(fitted, source=command, near_depth=args.near_depth).save(args.out)
        print(f"wrote {args.out}")
    return 0


def _inputs(args) -> tuple[list[str], Calibration | None]:
    """The inputs to fit or check and, with ``--check``, the calibration read; every option
    checked against the others (``UsageError`` in one line) before any folder is made."""
    if args.split not in SPLITS:
        raise UsageError(f"--split {args.split!r} is not a split; choose one of {', '.join(SPLITS)}")
    try:
        names = parse_odometer_list(args.odometers)
        odometer_names(names)  # unknown names are named first
    except OdometerListError as exc:
        raise UsageError(exc.named("--odometers")) from None
    except (ValueError, ComparisonError) as exc:
        raise UsageError(str(exc)) from None
    if any(map(is_fused, names)):
        raise UsageError("--odometers: a fused odometer is not an input of fusion; calibrate its inputs")
    if args.check is None:
        _check_fit_options(args, names)
        return names, None
    given = given_options(args.argv, ["--out", "--odometers", "--near-depth"])
    if "--out" in given:
        raise UsageError("--out is for a new calibration; --check only prints (redirect it to keep it)")
    if "--near-depth" in given:
        raise UsageError("--near-depth is for a new calibration; --check uses the near_depth of the file it checks")
    try:
        calibration = Calibration.load(args.check)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if "--odometers" not in given:  # all the file calibrates; named ones must all be in it
        names = sorted(calibration.inputs)
        known = set(standalone_odometers())
        stranger = next((n for n in names if n not in known), None)
        if stranger is not None:  # a data file never makes odolab import a module or build a composite
            raise UsageError(
                f"{args.check}: input {stranger!r} is not a registered odometer (known: "
                f"{', '.join(sorted(known))}); to check it, name the inputs with --odometers"
            )
    missing = [n for n in names if n not in calibration.inputs]
    if missing:
        raise UsageError(
            f"{args.check}: no calibration for {missing[0]!r} (it has {', '.join(sorted(calibration.inputs))})"
        )
    return names, calibration


def _check_fit_options(args, names: list[str]) -> None:
    """A fit's own rules: action-prior among the inputs, enough steps, ``--out`` a .json file that
    is new or a calibration this command wrote."""
    if "action-prior" not in names:
        raise UsageError("--odometers must include action-prior: fusion falls back on it")
    steps = args.episodes * args.max_steps
    if steps < MIN_RUN_STEPS:
        raise UsageError(
            f"--episodes {args.episodes} x --max-steps {args.max_steps} = {steps} steps: too few to "
            f"calibrate, at least {MIN_RUN_STEPS} ({MIN_STEPS} valid steps of an action are needed; use hundreds)"
        )
    if args.out.is_dir():  # not "unknown file type": the folder itself is the mistake
        raise UsageError(f"--out {args.out}: is a folder, not a file; give a .json file's name")
    if args.out.suffix.lower() != ".json":  # before its folder is made
        raise UsageError(f"--out {args.out}: unknown file type {args.out.suffix or '(no extension)'!r}; use .json")
    found = what_file(args.out) if args.out.is_file() else None
    if found is not None:  # a navigation config, a study's result, a user's file: never replaced
        raise UsageError(
            f"--out {args.out}: expected a new file or a calibration this command wrote, found {found}; "
            "odolab replaces only the calibrations it wrote: give --out another path"
        )


def _print_check(name: str, checks) -> None:
    """One line per entry checked: the share of valid steps inside its 95 % ellipsoid."""
    for c in checks:
        note = "" if c.steps >= 20 else "  (too few steps to judge)"
        label = c.action.label + (NEAR if c.near else "")
        used = f"entry {c.entry}" if c.entry else "no entry: the input's largest sigmas"
        print(
            f"{name:>24} {label:>17}: {c.share:.3f} of {c.steps} valid steps inside the 95 % ellipsoid ({used}){note}"
        )


def _print_fit(name: str, cal: Calibration, gives_own: bool, oracle: bool) -> None:
    """One line per input fitted: its steps per action, its own covariance's scale, what is left uncalibrated."""

    def own_note(a: str) -> str:
        if cal.own_scale.get(a):
            return f" (own covariance x {cal.own_scale[a]:.3g})"
        return " (own covariance fits worse than the fixed one: not used)" if gives_own else ""

    said = ", ".join(f"{a} {n} steps{own_note(a)}" for a, n in cal.steps.items())
    left = [a.label for a in MOTION_ACTIONS if a.label not in cal.steps]  # no plain entry: no near one either
    marked = " (an oracle: it reads ground truth, and a fused odometer using it is marked oracle)" if oracle else ""
    print(f"{name}{marked}: {said}" + (f"; NOT calibrated (too few valid steps): {', '.join(left)}" if left else ""))


if __name__ == "__main__":
    exit_process(run_cli(main, "python -m odolab.fusion.calibrate"))
