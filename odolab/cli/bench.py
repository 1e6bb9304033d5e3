"""``python -m odolab.bench``: speed of the simulator, odometers, navigation, evaluation and training.

:mod:`odolab.benchmarks` times them; this module is the command line."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from odolab.benchmarks import speed as bench
from odolab.benchmarks.commands import CommandFailed
from odolab.cli.args import (
    ArgumentParser,
    UsageError,
    add_odometer_option,
    check_output_file,
    check_replaceable,
    exit_process,
    file_arg,
    run_cli,
    setting_help,
    setting_type,
)
from odolab.config import check, setting
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


#: The parts, in the order they run.
PARTS = ("simulator", "odometers", "navigation", "evaluate", "training", "compare")
#: Each table's heading, by its key in the report.
TITLES = {
    "simulator": "Simulator (341x192, ms per frame; ratio = noisy frame / bare cast_rays; 1thread: depth path "
    "not in a second thread)",
    "episodes": "Episode generation, end to end, one process",
    "odometers": "Odometers (steps/s of step() on test-split episodes, 341x192)",
    "navigation": "Navigation, closed loop, one process (first 3 test episodes, at most 100 steps; ms per step; "
    "planning is part of the policy; planning_share of the whole time; planning_to_sensors: planning over the sensors' time)",
    "evaluate": "Trajectory evaluation on KITTI 00 (wall seconds per command)",
    "training": "Robust-VO training (pairs/s: bare network step on resident random inputs, and the trainer's "
    "own epoch end to end; fp32 bare beside the chosen precision)",
    "compare": "The default comparison: python -m odolab.compare --no-cache timed from its start to its exit "
    "(command_), then its pipeline alone in this process with its phases; wall seconds, and their ratio to the "
    "odometers' own step times summed over the cores",
}


@dataclass(frozen=True)
class Plan:
    """What a run times, every input checked: the ``parts``, the training part's ``recipes`` (path,
    config), ``data`` and torch ``train_threads`` (None: torch's own choice), the odometer part's
    ``names`` and ``options``."""

    parts: tuple[str, ...]
    recipes: list[Path]
    data: object
    names: list[str]
    options: dict
    train_threads: int | None = setting(None, range=(1, 256), doc="torch threads for the training part")
    policy: object = None  # the navigation part's PolicyConfig (None: the default)

    def __post_init__(self) -> None:
        check(self)


def build_parser() -> ArgumentParser:
    """The command line of ``python -m odolab.bench``."""
    ap = ArgumentParser(prog="python -m odolab.bench", description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=PARTS, action="append", help="run only these parts (repeatable; default all)")
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
        type=setting_type("--train-threads", Plan, "train_threads"),
        default=None,
        metavar="N",
        help=setting_help(
            Plan, "train_threads", "torch's own choice; the ablations study's cpu scale trains with 1 per unit"
        ),
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
    add_odometer_option(ap, "'fused(icp,robust-vo).calibration=cal.json'")
    ap.add_argument(
        "--policy",
        action="append",
        default=[],
        metavar="key=value",
        help="a parameter of the navigation part's map-and-plan policy, as python -m odolab.navigate takes it "
        "(repeatable; e.g. plan_step=2)",
    )
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


def run(args) -> int:
    """Time the asked parts, printing each table and saving the JSON after each (a stop keeps the
    parts already timed); 0 when done."""
    plan = _plan(args)
    report: dict = {"machine": machine()}
    print(f"machine: {report['machine']}")
    running: set[str] = set()

    def save() -> None:
        report["parts_pending"] = [p for p in plan.parts if p not in report or p in running]
        if args.json:
            from odolab.io.atomic import write_json_atomic

            write_json_atomic(args.json, report, indent=2)

    save()  # at once: a stop before the first part ends leaves no older, complete-looking file
    for part in plan.parts:
        running.add(part)  # the odometer part saves odometer by odometer, pending until the last is timed
        try:
            timed = _time(part, plan, plan.train_threads, report, save)
        except CommandFailed as exc:  # its own message is above, or in the line
            raise UsageError(f"the {part} part: {exc}") from None
        running.discard(part)
        for key, rows in timed.items():
            report[key] = rows
            print(f"\n## {TITLES[key]}\n")
            print(_table(rows if isinstance(rows, list) else [rows]))
        save()
    return 0


def _time(part: str, plan: Plan, threads: int | None, report: dict, save) -> dict:
    """Time one part: its tables by report key."""
    if part == "simulator":
        return {"simulator": bench.bench_simulator(), "episodes": bench.bench_episodes()}
    if part == "odometers":
        rows = report.setdefault("odometers", [])
        bench.bench_odometers(plan.names, options=plan.options, rows=rows, after_each=save)
        return {"odometers": rows}
    if part == "navigation":
        return {"navigation": bench.bench_navigation(policy=plan.policy)}
    if part == "evaluate":
        from odolab.benchmarks.evaluate_speed import run as bench_evaluate

        return {"evaluate": bench_evaluate()}
    if part == "compare":
        return {"compare": bench.bench_compare()}
    return {"training": bench.bench_training(plan.recipes, threads=threads, data=plan.data)}


def _plan(args) -> Plan:
    """Every input checked before anything is timed; ``UsageError`` in one line."""
    if args.json is not None:
        check_output_file(args.json, "--json", [".json"])
        check_replaceable(args.json, "--json", _bench_json, "a bench JSON file (python -m odolab.bench --json)")
    parts = tuple(p for p in PARTS if p in (args.only or PARTS))
    asked = " ".join(dict.fromkeys(args.only or PARTS))
    recipes, data = args.recipe or bench.default_recipes(), None
    if "training" in parts:
        data = _training_data(recipes, args.bench_data)
    elif args.recipe or args.train_threads or args.bench_data:
        option = "--recipe" if args.recipe else "--train-threads" if args.train_threads else "--bench-data"
        raise UsageError(f"{option} chooses how the training part runs; --only {asked} does not run it")
    if "odometers" not in parts and (args.odometers is not None or args.odometer_option):
        raise UsageError(
            f"--odometers and --odometer-option choose what the odometer part times; --only {asked} does not run it"
            + (
                " (navigation always times ground-truth and action-prior, with their defaults)"
                if "navigation" in parts
                else ""
            )
        )
    names, options = _odometers(args.odometers, args.odometer_option, load="odometers" in parts)
    policy = None
    if args.policy:
        from odolab.navigation.agent import PolicyConfig, PolicyError

        if "navigation" not in parts:
            raise UsageError(f"--policy chooses how the navigation part plans; --only {asked} does not run it")
        try:
            policy = PolicyConfig.from_assignments(args.policy)
        except PolicyError as exc:
            raise UsageError(exc.named("--policy")) from None
    return Plan(parts, recipes, data, names, options, args.train_threads, policy)


def _training_data(recipes: list[Path], bench_data: str | None) -> object:
    """Check the training part's recipes and open ``--bench-data`` (None: the part renders its own)."""
    from odolab.learned.robust_vo.config import load_train_config
    from odolab.learned.training import ConfigError

    configs = []
    for r in recipes:
        try:
            configs.append((str(r), load_train_config(str(r))))
        except ConfigError as exc:
            raise UsageError(f"--recipe: {exc}") from None
    if bench_data is None:
        return None
    from odolab.learned.robust_vo.speed import open_bench_data

    try:
        return open_bench_data(bench_data, configs)
    except ValueError as exc:
        raise UsageError(f"--bench-data: {exc}") from None


def _odometers(text: str | None, assignments: list[str], load: bool) -> tuple[list[str], dict]:
    """The odometer part's names (``--odometers``; default every standalone one) and options, each
    loaded once (when the part runs) so that a bad name or option stops the run before any timing."""
    from odolab.odometry.odometer import (
        OdometerListError,
        available_odometers,
        parse_odometer_list,
        standalone_odometers,
        unknown_odometer,
    )
    from odolab.odometry.options import OptionError, parse_assignments
    from odolab.reporting.pipeline import ComparisonError, load_odometers

    try:
        names = standalone_odometers() if text is None else parse_odometer_list(text)
    except OdometerListError as exc:
        raise UsageError(exc.named("--odometers")) from None
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    unknown = [u for u in map(unknown_odometer, names) if u]
    if unknown or not names:
        raise UsageError(f"unknown odometer {(unknown or [text])[0]!r}; available: {', '.join(available_odometers())}")
    try:
        options = parse_assignments(assignments)
        if load:
            load_odometers(names, options)
    except (OptionError, ComparisonError) as exc:
        raise UsageError(str(exc)) from None
    return names, options


def _bench_json(path: Path) -> bool:
    """Whether ``path`` holds what ``--json`` writes: an object with the machine and timed parts only."""
    import json

    doc = json.loads(path.read_text(encoding="utf-8"))
    parts = {"machine", "parts_pending", "simulator", "episodes", *PARTS}
    return isinstance(doc, dict) and "machine" in doc and set(doc) <= parts


if __name__ == "__main__":
    exit_process(run_cli(main, "python -m odolab.bench"))
