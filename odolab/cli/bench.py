"""``python -m odolab.bench``: speed of the simulator, the odometers, closed-loop navigation, the
evaluator and training (:mod:`odolab.benchmarks` times them)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from odolab.benchmarks import speed as bench
from odolab.cli.args import (
    ArgumentParser,
    UsageError,
    check_output_file,
    check_replaceable,
    file_arg,
    number,
    run_cli,
)
from odolab.core.machine import machine


def _table(rows: list[dict]) -> str:
    if not rows:
        return ""
    from odolab.running.summary import text_table

    keys = list(dict.fromkeys(k for r in rows for k in r))  # every row's columns ('-' where one has none)
    return text_table(
        keys,
        [[f"{r[k]:.2f}" if isinstance(r.get(k), float) else str(r.get(k, "-")) for k in keys] for r in rows],
        markdown=True,
    )


def main(argv: Sequence[str] | None = None) -> int:
    from odolab.odometry.odometer import (
        OdometerListError,
        available_odometers,
        parse_odometer_list,
        standalone_odometers,
        unknown_odometer,
    )

    ap = ArgumentParser(prog="python -m odolab.bench", description=bench.__doc__.splitlines()[0])
    ap.add_argument(
        "--only",
        choices=["simulator", "odometers", "navigation", "evaluate", "training"],
        action="append",
        help="run only these parts (repeatable; default all)",
    )
    ap.add_argument(
        "--recipe",
        type=file_arg("--recipe"),
        action="append",
        default=None,
        metavar="FILE.toml",
        help="robust-VO recipe the training part times (repeatable; default: "
        + " and ".join(bench.TRAINING_RECIPES)
        + ")",
    )
    ap.add_argument(
        "--train-threads",
        type=number("--train-threads", int, 1, 256),
        default=None,
        metavar="N",
        help="torch threads for the training part (default: torch's own choice; the ablations "
        "study's cpu scale trains with 1 per unit)",
    )
    ap.add_argument(
        "--bench-data",
        default=None,
        metavar="FOLDER",
        help="training data (python -m odolab.training_data, of the recipes' frame size; a few episodes: "
        "every shard is checked first) the training part's end-to-end epoch reads, its pairs repeated "
        "where too few (default: 20 val episodes rendered for each recipe)",
    )
    ap.add_argument("--odometers", default=None, help="comma-separated odometers (default: all)")
    ap.add_argument(
        "--json",
        type=file_arg("--json"),
        default=None,
        metavar="FILE.json",
        help="also write the figures here (a .json file, replaced atomically)",
    )
    ap.add_argument(
        "--odometer-option",
        action="append",
        default=[],
        metavar="NAME.key=value",
        help="constructor option of one odometer, e.g. 'fused(icp,robust-vo).calibration=cal.json'",
    )
    args = ap.parse_args(argv)
    if args.json is not None:
        check_output_file(args.json, "--json", [".json"])
        check_replaceable(args.json, "--json", _bench_json, "a bench JSON file (python -m odolab.bench --json)")
    parts = args.only or ["simulator", "odometers", "navigation", "evaluate", "training"]
    recipes = args.recipe or bench.default_recipes()
    if "training" in parts:
        from odolab.learned.robust_vo.config import load_train_config
        from odolab.learned.training import ConfigError

        configs = []
        for r in recipes:
            try:
                configs.append((str(r), load_train_config(str(r))))
            except ConfigError as exc:
                raise UsageError(f"--recipe: {exc}") from None
        if args.bench_data is not None:
            from odolab.learned.robust_vo.speed import open_bench_data

            try:
                args.bench_data = open_bench_data(args.bench_data, configs)
            except ValueError as exc:
                raise UsageError(f"--bench-data: {exc}") from None
    elif args.recipe or args.train_threads or args.bench_data:
        option = "--recipe" if args.recipe else "--train-threads" if args.train_threads else "--bench-data"
        raise UsageError(
            f"{option} chooses how the training part runs; --only {' '.join(dict.fromkeys(parts))} does not run it"
        )
    if "odometers" not in parts and (args.odometers is not None or args.odometer_option):
        raise UsageError(
            f"--odometers and --odometer-option choose what the odometer part times; "
            f"--only {' '.join(dict.fromkeys(parts))} does not run it"
            + (
                " (navigation always times ground-truth and action-prior, with their defaults)"
                if "navigation" in parts
                else ""
            )
        )
    try:
        names = standalone_odometers() if args.odometers is None else parse_odometer_list(args.odometers)
    except OdometerListError as exc:
        raise UsageError(exc.named("--odometers")) from None
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    unknown = [u for u in map(unknown_odometer, names) if u]
    if unknown or not names:
        raise UsageError(
            f"unknown odometer {(unknown or [args.odometers])[0]!r}; available: {', '.join(available_odometers())}"
        )
    from odolab.odometry.options import OptionError, parse_assignments
    from odolab.reporting.pipeline import ComparisonError, load_odometers

    try:
        options = parse_assignments(args.odometer_option)
        if "odometers" in parts:
            load_odometers(names, options)  # every name and option checked before anything is timed
    except (OptionError, ComparisonError) as exc:
        raise UsageError(str(exc)) from None

    report: dict = {"machine": machine()}
    print(f"machine: {report['machine']}")

    running: set[str] = set()

    def save() -> None:  # after every part, so that a stop keeps the parts already timed
        report["parts_pending"] = [p for p in parts if p not in report or p in running]
        if args.json:
            from odolab.io.atomic import write_json_atomic

            write_json_atomic(args.json, report, indent=2)

    save()  # at once: a stop before the first part ends leaves no older, complete-looking file
    if "simulator" in parts:
        report["simulator"] = bench.bench_simulator()
        print(
            "\n## Simulator (341x192, ms per frame; ratio = noisy frame / bare cast_rays; 1thread: depth path not in a second thread)\n"
        )
        print(_table(report["simulator"]))
        report["episodes"] = bench.bench_episodes()
        print("\n## Episode generation, end to end, one process\n")
        print(_table([report["episodes"]]))
        save()
    if "odometers" in parts:
        running.add("odometers")  # saved odometer by odometer, pending until the last is timed
        bench.bench_odometers(names, options=options, rows=report.setdefault("odometers", []), after_each=save)
        running.discard("odometers")
        print("\n## Odometers (steps/s of step() on test-split episodes, 341x192)\n")
        print(_table(report["odometers"]))
        save()
    if "navigation" in parts:
        report["navigation"] = bench.bench_navigation()
        print(
            "\n## Navigation, closed loop, one process (first 3 test episodes, at most 100 steps; ms per step; "
            "planning is part of the policy; planning_share of the whole time)\n"
        )
        print(_table(report["navigation"]))
        save()
    if "evaluate" in parts:
        from odolab.benchmarks.evaluate_speed import run as bench_evaluate

        report["evaluate"] = bench_evaluate()
        print("\n## Trajectory evaluation on KITTI 00 (wall seconds per command)\n")
        print(_table([report["evaluate"]]))
        save()
    if "training" in parts:
        report["training"] = bench.bench_training(recipes, threads=args.train_threads, data=args.bench_data)
        print(
            "\n## Robust-VO training (pairs/s: bare network step on resident random inputs, and the trainer's "
            "own epoch end to end; fp32 bare beside the chosen precision)\n"
        )
        print(_table(report["training"]))
        save()
    return 0


def _bench_json(path: Path) -> bool:
    """Whether ``path`` holds what ``--json`` writes: an object with the machine and timed parts only."""
    import json

    doc = json.loads(path.read_text(encoding="utf-8"))
    parts = {"machine", "parts_pending", "simulator", "episodes", "odometers", "navigation", "evaluate", "training"}
    return isinstance(doc, dict) and "machine" in doc and set(doc) <= parts


if __name__ == "__main__":
    raise SystemExit(run_cli(main, "python -m odolab.bench"))
