"""``python -m odolab.compare``: run odometers side by side on identical episodes (or a TUM folder).

With no arguments: every available odometer on 5 test-split episodes of at most 60 steps, seed 0,
written to ``runs/compare`` (table.csv, report.html, figures, trajectories). Episodes are cached
(``--cache``) and generated as parallel Ray tasks (``--ray-address`` for a cluster).
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Sequence

from odolab.cli import MAX_SEED, ArgumentParser, UsageError, check_output_dir, number, run_cli, seed
from odolab.odometer import available_odometers, load_odometer
from odolab.sim.scenes import SPLITS

DEFAULT_CACHE = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "odolab" / "episodes"


#: Documented ranges of the numeric options (enforced with one line by odolab.cli.number).
MAX_EPISODES = 1000
MAX_STEPS = 500
MAX_NOISE = 10.0
#: Options that choose simulator episodes; with --tum they would be silently meaningless.
SIMULATOR_OPTIONS = ("--episodes", "--seed", "--split", "--max-steps", "--rgb-noise", "--depth-noise",
                     "--actuation-noise", "--cache", "--no-cache", "--ray-address", "--serial")


def build_parser() -> argparse.ArgumentParser:
    ap = ArgumentParser(prog="python -m odolab.compare", description=__doc__.splitlines()[0])
    ap.add_argument("--odometers", default=None,
                    help="comma-separated names or module:Class (default: all available: %(choices)s)".replace(
                        "%(choices)s", ", ".join(available_odometers())))
    ap.add_argument("--episodes", type=number("--episodes", int, 1, MAX_EPISODES), default=5,
                    help=f"number of episodes, 1-{MAX_EPISODES} (default 5)")
    ap.add_argument("--seed", type=seed(), default=0, help=f"episode seed, 0-{MAX_SEED} (default 0)")
    ap.add_argument("--split", default="test", help=f"scene split: {' | '.join(SPLITS)} (default test)")
    ap.add_argument("--max-steps", type=number("--max-steps", int, 1, MAX_STEPS), default=60,
                    help=f"steps per episode, 1-{MAX_STEPS} (default 60)")
    for kind, default, what in (("rgb", 1.0, "RGB Gaussian (sigma 0.1 x M)"), ("depth", 1.0, "Redwood depth"),
                                ("actuation", 0.5, "PyRobot actuation")):
        ap.add_argument(f"--{kind}-noise", type=number(f"--{kind}-noise", float, 0, MAX_NOISE), default=default,
                        metavar="M", help=f"{what} noise multiplier, 0-{MAX_NOISE:g}, 0 = none (default {default:g})")
    ap.add_argument("--out", type=Path, default=Path("runs/compare"),
                    help="output folder (default runs/compare); files a previous run wrote there are replaced")
    ap.add_argument("--tum", type=Path, default=None,
                    help="run on a TUM RGB-D folder instead of the simulator (simulator options are then refused)")
    ap.add_argument("--cache", type=Path, default=DEFAULT_CACHE, help=f"episode cache (default {DEFAULT_CACHE})")
    ap.add_argument("--no-cache", action="store_true", help="do not read or write the episode cache")
    ap.add_argument("--ray-address", default=None,
                    help="Ray cluster address host:port or ray://host:port (default: a local instance)")
    ap.add_argument("--serial", action="store_true", help="generate episodes in this process, without Ray")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    return ap


def _given(argv: Sequence[str], options: Sequence[str]) -> list[str]:
    """The ``options`` that appear in ``argv`` (``--opt value`` or ``--opt=value``)."""
    used = {a.split("=", 1)[0] for a in argv if a.startswith("--")}
    return [o for o in options if o in used]


def _check_before_work(args: argparse.Namespace, argv: Sequence[str]) -> None:
    """Every check that can fail on the user's input, done before any episode or odometer runs."""
    if args.split not in SPLITS:
        raise UsageError(f"--split {args.split!r} is not a split; choose one of {', '.join(SPLITS)}")
    if args.tum is not None:
        ignored = _given(argv, SIMULATOR_OPTIONS)
        if ignored:
            raise UsageError(f"{', '.join(ignored)}: simulator option{'s' if len(ignored) > 1 else ''}, "
                             "meaningless with --tum (a TUM folder is one real recording); drop "
                             f"{'them' if len(ignored) > 1 else 'it'}")
    else:
        if not args.no_cache:
            check_output_dir(args.cache, "--cache")
        if args.ray_address is not None and not args.serial:
            from odolab.parallel import check_ray_address

            try:
                check_ray_address(args.ray_address)
            except ValueError as exc:
                raise UsageError(str(exc)) from None
    check_output_dir(args.out, "--out")


def _odometer_names(spec: str | None) -> list[str]:
    names = available_odometers()
    chosen = names if spec is None else [n.strip() for n in spec.split(",") if n.strip()]
    if not chosen:
        raise UsageError(f"--odometers is empty; available: {', '.join(names)}")
    unknown = [n for n in chosen if n not in names and ":" not in n]  # "module:Class" loads on demand
    if unknown:
        raise UsageError(f"unknown odometer {unknown[0]!r}; available: {', '.join(names)}")
    return chosen


def _load_odometers(chosen: list[str]) -> dict:
    out = {}
    for n in chosen:
        try:
            out[n] = load_odometer(n)
        except Exception as exc:  # a broken plugin is reported, not a traceback
            raise UsageError(f"could not load odometer {n!r}: {type(exc).__name__}: {exc}") from None
    return out


def _floor_plan(scene_seed: int):
    from odolab.report import FloorPlan
    from odolab.sim.scenes import generate_scene

    scene = generate_scene(scene_seed)
    return FloorPlan(scene.free, scene.origin, scene.resolution)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    names = _odometer_names(args.odometers)
    _check_before_work(args, argv)
    odometers = _load_odometers(names)

    from odolab import runner, summary
    from odolab.report import format_table, write_report

    if args.tum is not None:
        from odolab.api import load_tum_sequence
        from odolab.io.errors import FileFormatError

        try:
            sequences = [load_tum_sequence(args.tum)]
        except (FileFormatError, ValueError) as exc:
            raise UsageError(str(exc)) from None
        plans, total = None, None
        title = f"odolab compare on TUM folder {args.tum}"
        dropped = sequences[0].dropped
        notes = ["Real data: no actions; 'action-prior' is therefore the no-motion row.",
                 "Rows marked oracle read ground truth.",
                 f"{len(sequences[0])} frames; colour images left out: {dropped['no depth']} without a depth "
                 f"image and {dropped['no ground truth']} without a ground-truth pose within 0.02 s."]
        if any(dropped.values()):
            print(f"note: {notes[-1]}", file=sys.stderr)
    else:
        from odolab.io.errors import FileFormatError
        from odolab.episodes import (EpisodeCache, EpisodeSpec, NoiseConfig, generate_episodes, load_episodes,
                                     stream_episodes)

        noise = NoiseConfig(rgb=args.rgb_noise, depth=args.depth_noise, actuation=args.actuation_noise)
        specs = [EpisodeSpec(split=args.split, index=i, seed=args.seed, max_steps=args.max_steps, noise=noise)
                 for i in range(args.episodes)]
        make = dict(ray_address=args.ray_address, parallel=not args.serial, progress=not args.quiet)
        if args.no_cache:
            episodes, total = load_episodes(specs, None, **make), None
        else:  # generate what is missing, then read one episode at a time: memory holds one
            cache = EpisodeCache(args.cache)
            generate_episodes(specs, cache, **make)
            episodes, total = stream_episodes(specs, cache), sum(cache.steps(s) for s in specs)
        scenes: dict[str, int] = {}

        def noted(stream):
            for ep in stream:
                scenes[ep.name] = ep.info["scene_seed"]
                yield ep

        sequences = noted(episodes)
        title = f"odolab compare: {args.episodes} {args.split} episodes, seed {args.seed}"
        notes = ["Errors are x 1e-2 (m, m, rad), mean absolute error over all steps; "
                 "rows marked oracle read ground truth.",
                 f"Noise multipliers: RGB {noise.rgb:g}, depth {noise.depth:g}, actuation {noise.actuation:g} "
                 "(the action prior was fitted at 1, 1, 0.5).",
                 f"Command: python -m odolab.compare --episodes {args.episodes} --seed {args.seed} "
                 f"--split {args.split} --max-steps {args.max_steps} --rgb-noise {noise.rgb:g} "
                 f"--depth-noise {noise.depth:g} --actuation-noise {noise.actuation:g}"]

    try:
        results = runner.run(odometers, sequences, progress=not args.quiet, total_steps=total)
    except FileFormatError as exc:  # an image that went bad after the folder was checked
        raise UsageError(str(exc)) from None
    if args.tum is None:
        plans = {name: _floor_plan(s) for name, s in scenes.items()}
        one = [r for r in results if r.odometer == results[0].odometer]
        steps = sum(len(r.actions) for r in one)
        collided = sum(int(r.collisions.sum()) for r in one)
        notes.insert(0, f"{steps} steps, {collided} of them collisions ({100 * collided / max(steps, 1):.1f}%).")
    rows = summary.summarize(results)
    action_rows = summary.summarize_actions(results) if args.tum is None else []
    print(title)  # the table first: nothing that follows can lose it
    print(format_table(rows, real_data=args.tum is not None))
    write_report(args.out, rows, action_rows, results, title, notes, plans)
    for r in results:
        for e in r.errors[:1]:
            print(f"note: {r.odometer} raised on {r.sequence}: {e}")
    print(f"wrote {args.out / 'table.csv'} and {args.out / 'report.html'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(run_cli(main, "odolab.compare"))
