"""Calibrate the covariances of fusion inputs on held-out episodes, or check a calibration.

    python -m odolab.fusion.calibrate --odometers action-prior,icp,open3d-rgbd,robust-vo \
        --split val --episodes 20 --max-steps 100 --out odolab/data/fusion/calibration.json   # the shipped one
    python -m odolab.fusion.calibrate --check odolab/data/fusion/calibration.json --split test --episodes 20

Runs each odometer on the same episodes (generated as Ray tasks, cached like ``compare``'s),
takes its valid raw steps against the true motions and fits :mod:`odolab.fusion.calibration`;
``--check`` instead prints, per input and action, the share of bias-corrected steps inside the
calibrated 95 % ellipsoid (0.95 when the calibration carries over). Steps whose previous view's
median depth is below ``--near-depth`` (1 m) are fitted apart, as ``<action>@near`` entries
(:mod:`odolab.fusion.calibration`). ``action-prior`` must be calibrated: fusion
falls back on it. An action with fewer than 10 valid steps is left out (fusion then uses the input's
largest sigmas for it), and the summary says so. An oracle input (one reading ground truth) is
calibrated like any other, and named as one: a fused odometer using it is an oracle too.
``--out`` is replaced if it exists.
"""

from __future__ import annotations

import shlex
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from odolab.api import EpisodeSpec, load_episodes
from odolab.cli import (
    MAX_SEED,
    ArgumentParser,
    UsageError,
    check_output_dir,
    check_output_file,
    file_arg,
    given_options,
    number,
    path_arg,
    run_cli,
)
from odolab.comparison import DEFAULT_CACHE, ComparisonError, load_odometers, odometer_names
from odolab.episodes import MAX_EPISODE_STEPS, EpisodeCache
from odolab.fusion.calibration import (
    MAX_NEAR_DEPTH,
    NEAR,
    Calibration,
    debiased,
    ellipsoid_share,
    fit_input,
    view_is_near,
)
from odolab.fusion.graph import residual, right_covariance
from odolab.odometer import parse_odometer_list, standalone_odometers
from odolab.parallel import check_ray_option
from odolab.progress import StepProgressBar
from odolab.runner import failure_reason, run
from odolab.sim.scenes import SPLITS
from odolab.types import MOTION_ACTIONS


def near_views(episodes, near_depth: float) -> dict[str, np.ndarray]:
    """Per episode name: (N,) bool, whether each step's previous view is near (:func:`view_is_near`)."""
    return {
        ep.name: np.array([view_is_near(ep[k].depth, near_depth) for k in range(len(ep) - 1)], bool) for ep in episodes
    }


def steps_of(
    results, near: dict[str, np.ndarray]
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray | None], np.ndarray, np.ndarray]:
    """From one odometer's :class:`~odolab.runner.SequenceResult` list: residuals (N, 6), action
    values (N,), own covariances (right perturbation), the raw transforms of its valid steps and
    whether each one's view was near (``near``: per sequence name, from :func:`near_views`)."""
    xi, actions, own, Ts, close = [], [], [], [], []
    for r in results:
        for k, est in enumerate(r.raw):
            if est is None or failure_reason(est) is not None or r.truth is None:
                continue
            xi.append(residual(est.transform, r.truth[k]))
            actions.append(int(r.actions[k]))
            own.append(right_covariance(est.transform, est.covariance) if est.covariance is not None else None)
            Ts.append(est.transform)
            close.append(bool(near[r.sequence][k]))
    return (
        np.array(xi).reshape(-1, 6),
        np.array(actions, np.int64),
        own,
        np.array(Ts).reshape(-1, 4, 4),
        np.array(close, bool),
    )


def main(argv: Sequence[str] | None = None) -> int:
    ap = ArgumentParser(prog="python -m odolab.fusion.calibrate", description=__doc__.splitlines()[0])
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
    ap.add_argument(
        "--near-depth",
        type=number("--near-depth", float, 0.0, MAX_NEAR_DEPTH),
        default=1.0,
        help="views whose median depth is below this many metres get their own entries (default %(default)s; 0: none)",
    )
    ap.add_argument("--split", default="val", help=f"{' | '.join(SPLITS)} (default val)")
    ap.add_argument("--episodes", type=number("--episodes", int, 1, 10_000), default=20)
    ap.add_argument(
        "--max-steps",
        type=number("--max-steps", int, 1, MAX_EPISODE_STEPS),
        default=100,
        help=f"steps per episode, 1-{MAX_EPISODE_STEPS} (default 100)",
    )
    ap.add_argument("--seed", type=number("--seed", int, 0, MAX_SEED), default=0)
    ap.add_argument(
        "--cache", type=path_arg("--cache"), default=DEFAULT_CACHE, help=f"episode cache (default {DEFAULT_CACHE})"
    )
    ap.add_argument("--ray-address", default=None)
    ap.add_argument("--serial", action="store_true", help="generate episodes in this process (no Ray)")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    args = ap.parse_args(argv)
    if args.split not in SPLITS:
        raise UsageError(f"--split {args.split!r} is not a split; choose one of {', '.join(SPLITS)}")
    try:
        names = parse_odometer_list(args.odometers)
        odometer_names(names)  # unknown names are named first
    except (ValueError, ComparisonError) as exc:
        raise UsageError(str(exc)) from None
    if any(n.startswith("fused(") or n == "fused" for n in names):
        raise UsageError("--odometers: a fused odometer is not an input of fusion; calibrate its inputs")
    calibration = None
    if args.check is not None:
        given = given_options(argv, ["--out", "--odometers", "--near-depth"])
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
    else:
        if "action-prior" not in names:
            raise UsageError("--odometers must include action-prior: fusion falls back on it")
        if args.episodes * args.max_steps < 30:
            raise UsageError(
                f"--episodes x --max-steps = {args.episodes * args.max_steps} steps: too few to calibrate "
                "(at least 10 valid steps of an action are needed; use hundreds)"
            )
        if args.out.suffix.lower() != ".json":  # before its folder is made
            raise UsageError(f"--out {args.out}: unknown file type {args.out.suffix or '(no extension)'!r}; use .json")
        try:
            args.out.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UsageError(f"--out {args.out}: cannot make its folder ({exc.strerror or exc})") from None
        check_output_file(args.out, "--out", suffixes=[".json"])
    check_output_dir(args.cache, "--cache")
    check_ray_option(args.ray_address, args.serial)
    try:
        odometers = load_odometers(names)
    except ComparisonError as exc:
        raise UsageError(str(exc)) from None
    specs = [
        EpisodeSpec(split=args.split, index=i, seed=args.seed, max_steps=args.max_steps) for i in range(args.episodes)
    ]
    episodes = load_episodes(
        specs, EpisodeCache(args.cache), ray_address=args.ray_address, parallel=not args.serial, progress=not args.quiet
    )
    results = run(odometers, episodes, observer=StepProgressBar(disable=args.quiet))
    near_depth = calibration.near_depth if calibration is not None else args.near_depth
    near = near_views(episodes, near_depth)
    fitted = {}
    for name in names:
        xi, actions, own, _, close = steps_of([r for r in results if r.odometer == name], near)
        if calibration is not None:
            cal = calibration.for_input(name)
            for a in MOTION_ACTIONS:
                for is_near in (False, True):
                    rows = np.flatnonzero((actions == a.value) & (close == is_near))
                    if not len(rows):
                        continue
                    covs = np.stack([cal.covariance(a, own[k], is_near) for k in rows])
                    xi[rows] = debiased(xi[rows], cal.bias_of(a, is_near))
                    note = "" if len(rows) >= 20 else "  (too few steps to judge)"
                    label = a.label + (NEAR if is_near else "")
                    entry = cal.label(a, is_near)
                    used = f"entry {entry}" if entry else "no entry: the input's largest sigmas"
                    print(
                        f"{name:>24} {label:>17}: {ellipsoid_share(xi[rows], covs):.3f} of {len(rows)} valid steps "
                        f"inside the 95 % ellipsoid ({used}){note}"
                    )
            continue
        try:
            fitted[name] = fit_input(xi, actions, own, close)
        except ValueError as exc:
            raise UsageError(f"{name}: {exc}; use more --episodes or --max-steps") from None
        cal = fitted[name]
        gives_own = any(c is not None for c in own)

        def own_note(a: str, cal: Calibration = cal, gives_own: bool = gives_own) -> str:
            if cal.own_scale.get(a):
                return f" (own covariance x {cal.own_scale[a]:.3g})"
            return " (own covariance fits worse than the fixed one: not used)" if gives_own else ""

        said = ", ".join(f"{a} {n} steps{own_note(a)}" for a, n in cal.steps.items())
        left = [a.label for a in MOTION_ACTIONS if a.label not in cal.steps]  # no plain entry: no near one either
        oracle = (
            " (an oracle: it reads ground truth, and a fused odometer using it is marked oracle)"
            if getattr(odometers[name], "oracle", False)
            else ""
        )
        print(
            f"{name}{oracle}: {said}" + (f"; NOT calibrated (too few valid steps): {', '.join(left)}" if left else "")
        )
    if calibration is None:
        command = "python -m odolab.fusion.calibrate " + " ".join(
            shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:])
        )
        Calibration(fitted, source=command, near_depth=args.near_depth).save(args.out)
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(run_cli(main, "python -m odolab.fusion.calibrate"))
