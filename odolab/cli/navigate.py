"""``python -m odolab.navigate``: PointGoal navigation with each odometer as the agent's only sense of
its own motion; success, SPL, SoftSPL and the final belief error per odometer with 95 % intervals.

    python -m odolab.navigate --odometers ground-truth,action-prior,robust-vo --episodes 100 --out reports/navigation

Every odometer drives the same episodes (same scenes, starts, goals and noise laws; --seed), one Ray
task per (odometer, episode) on a local instance or the cluster at --ray-address. Each finished
episode is saved at once; the same command resumes. Writes nav.csv, nav.md, episodes.csv, metrics.png,
belief.png, paths-*.png and report.html under --out (see odolab.navigation.study).
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
    check_ray_option,
    check_report_dir,
    execution_of,
    exit_process,
    hold_folder,
    path_arg,
    run_cli,
    scenes_of,
)
from odolab.reporting.report import counted
from odolab.sim.scenes import SPLITS

#: The options that set what the library calls a navigation run's settings (odolab.navigation.study.Setting).
SETTING_OPTIONS = {
    "episodes": "--episodes",
    "seed": "--seed",
    "split": "--split",
    "max_steps": "--max-steps",
    "policy": "--policy",
}


def main(argv: Sequence[str] | None = None) -> int:
    from odolab.config import describe
    from odolab.navigation.agent import PolicyConfig, PolicyError
    from odolab.navigation.study import NavEpisodes, NavTask
    from odolab.odometry.odometer import REGISTRY, OdometerListError, parse_odometer_list
    from odolab.odometry.options import (
        OptionError,
        merge_options,
        naming_the_file,
        parse_assignments,
        read_options_file,
        without_defaults,
    )
    from odolab.reporting.pipeline import ComparisonError, load_odometers
    from odolab.sim.episodes import NoiseConfig

    ap = ArgumentParser(prog="python -m odolab.navigate", description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument(
        "--odometers",
        default="ground-truth,action-prior",
        help="comma-separated odometers, fused(a,b) included (default: %(default)s)",
    )
    add_setting(ap, "--episodes", NavEpisodes, "episodes")
    add_setting(ap, "--seed", NavEpisodes, "seed")
    ap.add_argument("--split", default="test", help=f"{' | '.join(SPLITS)} (default test)")
    add_scene_options(ap)
    add_setting(ap, "--max-steps", NavEpisodes, "max_steps")
    ap.add_argument(
        "--out",
        type=path_arg("--out"),
        default=Path("runs/navigation"),
        help="report folder; a rerun into it computes only the episodes it lacks (default runs/navigation)",
    )
    add_odometer_option(ap, "robust-vo.checkpoint=runs/model.pt (repeatable)")
    ap.add_argument(
        "--policy",
        action="append",
        default=[],
        metavar="key=value",
        help="a parameter of the map-and-plan policy (odolab.navigation.agent.PolicyConfig), "
        "e.g. heading_tolerance=45 (repeatable). Keys, defaults and ranges: "
        + "; ".join(f"{s.name} {s.value} {s.range}" for s in describe(PolicyConfig))
        + " (fallback_radius below agent_radius; 0 turns the fallback off). Results made before "
        "fallback_radius existed were made with fallback_radius=0",
    )
    ap.add_argument(
        "--config", type=path_arg("--config"), default=None, metavar="FILE.toml", help='[odometers."NAME"] key = value'
    )
    ap.add_argument("--ray-address", default=None, help="Ray cluster address (default: a local instance)")
    ap.add_argument("--serial", action="store_true", help="run the episodes in this process, without Ray")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    if args.split not in SPLITS:
        raise UsageError(f"--split {args.split!r} is not a split; choose one of {', '.join(SPLITS)}")
    try:
        from_file = read_options_file(args.config) if args.config else {}
    except OptionError as exc:
        raise UsageError(f"--config {exc}") from None  # the file's problem, under the option that named it
    try:
        policy = PolicyConfig.from_assignments(args.policy)
        names = parse_odometer_list(args.odometers)
        options = merge_options(from_file, parse_assignments(args.odometer_option))
    except PolicyError as exc:
        raise UsageError(exc.named("--policy")) from None
    except OdometerListError as exc:
        raise UsageError(exc.named("--odometers")) from None
    except (ValueError, OptionError) as exc:
        raise UsageError(str(exc)) from None
    check_ray_option(args.ray_address, args.serial)  # and RAY_ADDRESS: before --out is made
    try:
        loaded = load_odometers(names, options)  # every name and option checked here, before --out is made
    except ComparisonError as exc:
        raise UsageError(naming_the_file(str(exc), args.config, bool(args.odometer_option))) from None
    options = {n: without_defaults(REGISTRY.resolve(n), o) for n, o in options.items()}  # a named default is no change
    noise, scenes = NoiseConfig(), scenes_of(args, argv)
    chosen = NavEpisodes(args.episodes, args.seed, args.max_steps)
    specs = chosen.specs(args.split, noise=noise, scenes=scenes, family=args.scene_family)
    tasks = [NavTask(n, options.get(n, {}), s, policy, loaded[n].identity_digest) for n in names for s in specs]
    check_report_dir(args.out, "--out", manifest="config.json")  # another's files, links, pipes: refused now
    with hold_folder(args.out, "--out"):  # a second run into --out is refused until this one has written
        return _run(args, argv, tasks, names, specs, policy, options)


def _run(
    args: argparse.Namespace,
    argv: Sequence[str] | None,
    tasks: list,
    names: list[str],
    specs: list,
    policy: object,
    options: dict[str, dict],
) -> int:
    """Run the episodes ``--out`` lacks and write the report (``--out`` held by the caller)."""
    from odolab.io.owned import UnsafeOutputError, check_owned_path
    from odolab.navigation.report import output_files, write_outputs
    from odolab.navigation.study import RunFolderError, config_doc, run_navigation
    from odolab.running.summary import failed_steps_text

    try:
        for name in output_files(specs):  # the report's files, found unusable now rather than after every episode
            check_owned_path(args.out, name)
        rows = run_navigation(
            args.out,
            tasks,
            config_doc(names, options, specs, policy),
            execution=execution_of(args),
        )
    except UnsafeOutputError as exc:
        raise UsageError(f"--out: {exc}; remove it or choose another --out") from None
    except RunFolderError as exc:
        raise UsageError(exc.named("--out", SETTING_OPTIONS)) from None
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    command = "python -m odolab.navigate " + " ".join(
        shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:])
    )
    table = write_outputs(args.out, rows, names, specs, command, policy=policy)
    for r in table:
        print(
            f"{r['odometer']:>28}: success {r['success']:.2f} [{r['success_low']:.2f}, {r['success_high']:.2f}]  "
            f"SPL {r['spl']:.2f}  SoftSPL {r['soft_spl']:.2f}  final belief error {r['belief_error']:.2f} m  "
            f"{failed_steps_text(r['failed_steps'], r['steps'] * r['episodes'])}  ({counted(r['episodes'], 'episode')})"
        )
    for name in names:  # why an odometer's steps failed, once, as compare says it
        said = next((e for r in rows if r["odometer"] == name for e in r.get("errors", []) if isinstance(e, str)), None)
        if said:
            print(f"note: {name}: {said[:300]}", file=sys.stderr)
    print(f"wrote {args.out}/report.html")
    return 0


if __name__ == "__main__":
    exit_process(run_cli(main, "python -m odolab.navigate"))
