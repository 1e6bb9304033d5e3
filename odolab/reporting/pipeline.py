"""Run odometers side by side on identical episodes (or a TUM RGB-D folder): one library call.

``run_comparison(ComparisonConfig(...))`` does what ``python -m odolab.compare`` does before it
prints and writes: it loads the odometers with their options, makes the episode specs, generates
the missing episodes into the cache (or keeps them in memory without one), streams them through
the runner, and summarises. A study, a notebook or a navigation loop calls it directly::

    from odolab.reporting.pipeline import ComparisonConfig, run_comparison
    result = run_comparison(ComparisonConfig(odometers=["icp"], episodes=2, max_steps=20, cache=None))
    result.rows[0].ate_m

Every mistake in the configuration raises :class:`ComparisonError` with one line naming it.
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
import threading
import time
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from odolab.config import SEED_RANGE, check, setting
from odolab.core.parallel import SERIAL, Execution
from odolab.io.tum_rgbd import DEPTH_SCALE_RANGE
from odolab.odometry.odometer import (
    REGISTRY,
    IncompleteOdometerError,
    Odometer,
    OracleInputError,
    UnknownOdometerError,
    available_odometers,
    inner_names,
    standalone_odometers,
    unknown_odometer,
)
from odolab.odometry.options import OptionError, check_options
from odolab.reporting.report import FloorPlan
from odolab.running import paired, runner, summary
from odolab.running.runner import RunObserver, SequenceResult
from odolab.sim.mesh_scenes import SceneFiles
from odolab.sim.scenes import MAX_EPISODE_STEPS, SPLITS

if TYPE_CHECKING:  # the simulator's modules load only when episodes are made
    from odolab.sim.episodes import Episode, EpisodeSpec, NoiseConfig

__all__ = [
    "DEFAULT_CACHE",
    "ComparisonConfig",
    "ComparisonError",
    "ComparisonResult",
    "empty_depth_warnings",
    "failure_reasons",
    "load_odometers",
    "odometer_names",
    "run_comparison",
    "tum_sequences",
    "warn_on_stderr",
]

#: Where episodes are cached unless told otherwise.
#: Most episodes one comparison runs: its tables are read by people, and a larger study is a study.
MAX_EPISODES = 1000

DEFAULT_CACHE = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "odolab" / "episodes"


class ComparisonError(ValueError):
    """A configuration the comparison cannot run; the message is one line naming the problem."""


@dataclass(frozen=True)
class ComparisonConfig:
    """What to compare on what. ``odometers``: names or ``module:Class`` (None = all available);
    ``options``: constructor keyword arguments per odometer name. Simulator episodes: ``episodes``
    of ``split`` from ``seed``, at most ``max_steps`` steps, ``noise`` multipliers (None = the
    challenge's defaults, :class:`~odolab.sim.episodes.NoiseConfig`); ``cache``: the
    episode cache folder, or None to keep episodes in memory only. ``tum``: a TUM RGB-D folder
    instead of the simulator, its depth PNG values per metre ``tum_depth_scale`` (None: TUM's 5000)
    and its camera ``tum_intrinsics`` ``(fx, fy, cx, cy)`` (None: the TUM camera its name says).
    ``execution``: where missing episodes are generated and the odometers run, and whether with
    progress bars (:class:`~odolab.core.parallel.Execution`): in parallel on a local Ray instance,
    each odometer runs each simulator episode as a task of its own (made anew from its name and
    ``options``; the tables are the serial run's but for the steps/s). ``command``: the command line that asked
    (its caller's words, recorded in the notes), or None. ``step_timeout``: seconds one step of an
    odometer may take before it fails as ``timed-out`` (None: no limit; :mod:`odolab.running.runner`).
    ``scenes``: mesh files to run the episodes in (:func:`odolab.sim.mesh_scenes.scene_files`), or
    None for the split's procedural scenes of ``family`` (:data:`odolab.sim.free_scenes.FAMILIES`)."""

    odometers: list[str] | None = None
    options: dict[str, dict[str, Any]] = field(default_factory=dict)
    episodes: int = setting(5, range=(1, MAX_EPISODES), doc="number of episodes")
    seed: int = setting(0, range=SEED_RANGE, doc="episode seed")
    split: str = "test"
    max_steps: int = setting(60, range=(1, MAX_EPISODE_STEPS), doc="steps per episode")
    noise: NoiseConfig | None = None
    tum: Path | None = None
    tum_depth_scale: float | None = setting(None, range=DEPTH_SCALE_RANGE, doc="depth PNG values per metre")
    tum_intrinsics: tuple[float, float, float, float] | None = None
    cache: Path | None = DEFAULT_CACHE
    execution: Execution = Execution()
    command: str | None = None
    step_timeout: float | None = setting(
        runner.DEFAULT_STEP_TIMEOUT,
        range=(0.001, 86400.0),
        doc="seconds one step of an odometer may take before it fails as timed-out (None: no limit); after 3 "
        "such steps the odometer is stopped for the sequence",
    )
    scenes: SceneFiles | None = None
    family: str = "boxes"

    def __post_init__(self) -> None:
        try:
            check(self)
        except ValueError as exc:
            raise ComparisonError(str(exc)) from None


@dataclass(frozen=True, kw_only=True)
class ComparisonResult:
    """Per-sequence results, the summary tables, a title and notes for reports, floor plans
    (sequence name -> :class:`~odolab.reporting.report.FloorPlan`, simulator only) and warnings."""

    results: list[SequenceResult]
    rows: list[summary.Row]
    action_rows: list[summary.ActionRow]
    title: str
    notes: list[str]
    plans: dict[str, FloorPlan] | None
    warnings: list[str] = field(default_factory=list)
    """What a person should hear at once (e.g. frames a TUM folder had to leave out)."""
    configs: dict[str, str] = field(default_factory=dict)
    """Each configurable odometer's settings (:func:`odometer_configs`), for the report."""
    paired_rows: list[paired.PairedRow] = field(default_factory=list)
    """Each composite against its inputs on the same steps (:mod:`odolab.running.paired`)."""
    phases: dict[str, float] = field(default_factory=dict)
    """Wall seconds of the run's phases, in order: ``load_odometers`` (made and checked here; about 0
    when they were given made), then with the odometers as Ray tasks ``motions`` (planned here),
    ``ray_start`` (a local instance's start, this process rendering the first missing episodes
    meanwhile; 0 where Ray was running before), ``tasks`` (the rest of the rendering and every
    odometer on every episode) and ``ray_shutdown`` (0 where Ray was running before and is left so), else ``run`` (episodes and odometers in this
    process). The summary after them is in none."""


def odometer_names(names: list[str] | None) -> list[str]:
    """The names to run (None = all available), checked without importing anything."""
    known = available_odometers()
    chosen = standalone_odometers() if names is None else list(names)
    if not chosen:
        raise ComparisonError(f"no odometer chosen; available: {', '.join(known)}")
    try:
        unknown = [u for u in map(unknown_odometer, chosen) if u]  # "module:Class" loads on demand
    except ValueError as exc:  # nested too deep
        raise ComparisonError(str(exc)) from None
    if unknown:
        raise ComparisonError(
            f"unknown odometer {unknown[0]!r}; available: {', '.join(known)} (and fused(a,b,...) of any of them)"
        )
    return chosen


def warn_on_stderr(line: str) -> None:
    """Print one warning line on standard error."""
    print(line, file=sys.stderr)


def load_odometers(
    names: list[str] | None,
    options: dict[str, dict[str, Any]] | None = None,
    warn: Callable[[str], None] = warn_on_stderr,
) -> dict[str, Odometer]:
    """Instantiate odometers by name (None = all available) with their constructor options.

    Named odometers must all load (:class:`ComparisonError` with one line otherwise). Of all
    available ones (``names`` None), one that cannot be imported or made with its defaults (a
    broken third-party entry point) is left out, with one line to ``warn`` naming it and why; one
    given options must still load. :class:`ComparisonError` when none is left."""
    options = options or {}
    chosen = odometer_names(names)
    holders = {n: [c for c in chosen if n in inner_names(c)] for n in options}  # composites that take n as an input
    stray = [n for n in options if n not in chosen]
    if stray:
        name, holder = stray[0], (holders[stray[0]] or [""])[0]
        hint = f"; it is an input of {holder!r}: {_options_file_advice(name, holder)}" if holder else ""
        raise ComparisonError(
            f"options given for {name!r}, which is not among the odometers: {', '.join(chosen)}{hint}"
        )
    for name in options:
        if options[name] and holders[name]:
            raise ComparisonError(
                f"options given for {name!r} reach the {name!r} row only, not the {name} inside {holders[name][0]!r}, "
                f"which would run with its defaults; {_options_file_advice(name, holders[name][0])}"
            )
    out: dict[str, Odometer] = {}
    for name in chosen:
        opts = options.get(name, {})
        try:
            out[name] = _load_one(name, opts)
        except ComparisonError as exc:
            if names is not None or opts:
                raise
            warn(f"warning: left out of the default list of odometers: {exc}")
    if not out:
        raise ComparisonError(f"no odometer could be loaded; available: {', '.join(available_odometers())}")
    return out


def _load_one(name: str, opts: dict[str, Any]) -> Odometer:
    """Odometer ``name`` made with options ``opts``; :class:`ComparisonError` with one line otherwise."""
    try:
        factory = REGISTRY.resolve(name)
        check_options(name, factory, opts)
        return REGISTRY.load(name, **opts)
    except (UnknownOdometerError, OptionError, IncompleteOdometerError, OracleInputError) as exc:
        raise ComparisonError(str(exc)) from None
    except (Exception, SystemExit) as exc:  # noqa: BLE001 - a broken plugin or a bad option value is reported, not a traceback
        detail = f" with options {_short(opts)}" if opts else ""
        # a refused value or type says why itself; anything else is named by its kind
        kind = "" if isinstance(exc, (ValueError, TypeError)) else f"{type(exc).__name__}: "
        raise ComparisonError(f"could not load odometer {name!r}{detail}: {kind}{exc}") from None


def _options_file_advice(name: str, holder: str) -> str:
    """Where the options of ``name``, an input of the composite ``holder``, go instead."""
    return f"give it its options in a TOML file ([odometers.\"{name}\"]) as '{holder}.options_file=FILE'"


def _short(value: object) -> str:
    """``repr(value)`` cut short: a 20,000-item option is not echoed whole."""
    text = repr(value)
    return text if len(text) <= 200 else text[:200] + "...}"


def failure_reasons(results: list[SequenceResult]) -> dict[str, dict[str, int]]:
    """Failed steps per reason (:data:`odolab.running.runner.FAILURE_REASONS`), summed per odometer; odometers
    without failures are left out."""
    out: dict[str, dict[str, int]] = {}
    for r in results:
        for reason, count in r.failure_reasons.items():
            mine = out.setdefault(r.odometer, {})
            mine[reason] = mine.get(reason, 0) + count
    return out


def _floor_plan(scene_seed: int, goal: tuple[float, float] | None, spec: EpisodeSpec) -> FloorPlan:
    """The floor plan of scene ``scene_seed`` where episodes of ``spec`` run."""
    from odolab.sim.episodes import scene_of

    scene = scene_of(spec, scene_seed)
    return FloorPlan(scene.free, scene.origin, scene.resolution, goal)


def tum_sequences(config: ComparisonConfig) -> list:
    """The TUM RGB-D sequence of ``config.tum``, read and checked (:class:`ComparisonError` with one
    line, also for a folder of fewer than two usable frames: no step to compare)."""
    from odolab.io.errors import FileFormatError
    from odolab.io.tum_rgbd import TUM_DEPTH_SCALE, load_tum_sequence

    scale = TUM_DEPTH_SCALE if config.tum_depth_scale is None else config.tum_depth_scale
    try:
        sequence = load_tum_sequence(config.tum, config.tum_intrinsics, depth_scale=scale)
    except (FileFormatError, ValueError) as exc:
        raise ComparisonError(str(exc)) from None
    if len(sequence) < 2:
        raise ComparisonError(
            f"{len(sequence)} usable frame (a colour image with a depth image and a ground-truth pose); "
            "a comparison needs at least 2, one step between them"
        )
    return [sequence]


def empty_depth_warnings(results: list[SequenceResult]) -> list[str]:
    """One line per sequence with frames whose every depth pixel is 0 (counted by the runner)."""
    empty: dict[str, tuple[int, int]] = {}
    for r in results:
        frames = len(r.actions) + 1
        empty[r.sequence] = max(empty.get(r.sequence, (0, frames)), (r.empty_depth, frames))
    return [
        f"{name}: {count} of {frames} frames have no depth at all (every depth pixel is 0); "
        "odometers that use depth cannot use them"
        for name, (count, frames) in empty.items()
        if count
    ]


def _needs_action(name: str, odometer: Odometer) -> bool:
    """Whether ``odometer`` says it needs actions; :class:`ComparisonError` when reading it raises."""
    try:
        return bool(getattr(odometer, "needs_action", False))
    except Exception as exc:  # noqa: BLE001 - a plug-in's property may raise anything
        raise ComparisonError(f"odometer {name!r}: reading needs_action raised {type(exc).__name__}: {exc}") from None


def _episode_stream(config: ComparisonConfig, specs: list[EpisodeSpec]) -> tuple[Iterator, int | None]:
    """Episodes in spec order and the total step count (for the progress bar). With a cache the
    missing ones are generated first and each is read back when its turn comes, so memory holds
    one; without one, all are made and held."""
    from odolab.sim.episodes import EpisodeCache, generate_episodes, load_episodes, stream_episodes

    if config.cache is None:  # every episode in memory: the total is known too
        episodes = load_episodes(specs, None, execution=config.execution)
        return iter(episodes), sum(len(ep) - 1 for ep in episodes)
    cache = EpisodeCache(config.cache)
    generate_episodes(specs, cache, execution=config.execution)
    return stream_episodes(specs, cache), sum(cache.steps(s) for s in specs)


def fans_out(config: ComparisonConfig, names: Collection[str]) -> bool:
    """Whether odometers ``names`` run as Ray tasks (:func:`_run_fanned`): simulated episodes (not
    ``config.tum``), in parallel, on a local instance (a cluster's nodes cannot read this machine's
    episode cache), more than one odometer or episode, every odometer one a task can make anew by
    its name (a registered one or a ``module:Class``, with ``config.options``)."""
    from odolab.core.parallel import RAY_ADDRESS

    local = config.execution.ray_address is None and not os.environ.get(RAY_ADDRESS)
    named = all(unknown_odometer(name) is None for name in names)
    simulated = config.tum is None
    return simulated and config.execution.parallel and local and named and len(names) * config.episodes > 1


@dataclass(frozen=True)
class _Unit:
    """One odometer (by name, with its options) on one cached episode."""

    name: str
    options: dict[str, Any]
    spec: EpisodeSpec
    cache: Path
    step_timeout: float | None


def _run_unit(unit: _Unit, rendered: Episode | None = None) -> tuple[SequenceResult, dict, str]:
    """A Ray task: a fresh odometer of ``unit`` on its episode (an odometer starts each sequence
    anew at ``reset``, so it answers as one that ran other episodes before), the episode's scene
    seed and goal, and what the task wrote on stderr (a damaged cache entry, say: the driver says
    it again, where a worker's stderr is not seen). ``rendered``: what the task that rendered the
    episode returned (Ray runs this one after it): the episode, where the cache could not keep it."""
    from odolab.sim.episodes import EpisodeCache, load_episodes

    with contextlib.redirect_stderr(io.StringIO()) as said:
        odometer = load_odometers([unit.name], {unit.name: unit.options})[unit.name]
        (episode,) = (
            [rendered]
            if rendered is not None
            else load_episodes([unit.spec], EpisodeCache(unit.cache), execution=SERIAL)
        )
        (result,) = runner.run({unit.name: odometer}, [episode], step_timeout=unit.step_timeout)
    return result, {k: episode.info.get(k) for k in ("scene_seed", "goal")}, said.getvalue()


def _render_into(spec: EpisodeSpec, motion: Any, folder: Path) -> tuple[Episode | None, str]:
    """A Ray task: render the episode of ``spec`` along ``motion`` into the cache at ``folder``; the
    episode where the cache could not keep it (else None), and what the task wrote on stderr."""
    with contextlib.redirect_stderr(io.StringIO()) as said:
        episode, lines = _render_kept(spec, motion, folder)
    return episode, "".join(f"{line}\n" for line in lines) + said.getvalue()


def _render_kept(spec: EpisodeSpec, motion: Any, folder: Path) -> tuple[Episode | None, list[str]]:
    """Render the episode of ``spec`` along ``motion`` into the cache at ``folder`` (in this thread;
    standard error left as it is): the episode where the cache could not keep it (else None), and
    the cache's notices."""
    from odolab.sim.episodes import EpisodeCache, render_episode

    lines: list[str] = []
    episode = render_episode(spec, motion)
    kept = EpisodeCache(folder, say=lines.append).put(episode)
    return (episode if kept is None else None), lines


def _said(text: str, seen: set[str]) -> None:
    """Say again on stderr what a Ray task wrote on its own, each line once (``seen``: lines said)."""
    for line in text.splitlines():
        if line not in seen:
            seen.add(line)
            print(line, file=sys.stderr)


def _run_fanned(
    config: ComparisonConfig,
    specs: list[EpisodeSpec],
    names: list[str],
    observer: RunObserver | None,
    step_timeout: float | None,
    note: Callable[[str, dict], None],
    phases: dict[str, float],
) -> list[SequenceResult]:
    """Every odometer on every episode as Ray tasks on a local instance, one per (episode,
    odometer), each started as soon as its episode is in the cache (a temporary one without
    ``config.cache``): the episodes the cache lacks are rendered from their motion, planned here
    first so that the step count is known from the start; while a local Ray instance starts (seconds
    of waiting for its processes) this process renders the first of them itself, Ray tasks the rest
    once it is up. Results in the
    serial runner's order. ``observer`` hears of each finished task's steps and their own time;
    ``note(name, info)`` of each episode; ``phases`` gains the seconds of ``motions``, ``ray_start``,
    ``tasks`` and ``ray_shutdown``."""
    import tempfile

    from odolab.core.parallel import fan_out, shutdown_ray, start_ray_beside
    from odolab.sim.episodes import EpisodeCache, rollout

    with contextlib.ExitStack() as stack:
        folder = config.cache or Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="odolab-episodes-")))
        cache = EpisodeCache(folder)
        with _phase(phases, "motions"):
            motions = {k: rollout(s) for k, s in enumerate(specs) if not cache.has(s)}
        steps = sum(len(motions[k].actions) if k in motions else cache.steps(s) for k, s in enumerate(specs))
        units = [_Unit(n, config.options.get(n, {}), s, folder, step_timeout) for s in specs for n in names]
        results: list[SequenceResult | None] = [None] * len(units)
        seen: set[str] = set()
        if observer is not None:  # the bar's clock starts here: Ray's start is part of the wait
            observer.start(len(names) * steps)
            stack.callback(observer.close)

        def done(k: int, value: tuple[SequenceResult, dict, str]) -> None:
            results[k], info, said = value
            _said(said, seen)
            note(results[k].sequence, info)
            if observer is not None:
                observer.advance(units[k].name, len(results[k].actions), float(np.sum(results[k].step_seconds)))

        import ray

        def render_here(up: threading.Event) -> dict[int, tuple[Episode | None, list[str]]]:
            """The missing episodes, in order, rendered here while Ray starts (until it is up)."""
            return {k: _render_kept(specs[k], motions[k], folder) for k in motions if not up.is_set()}

        with _phase(phases, "ray_start"):
            here, ours = start_ray_beside(render_here, quiet=not config.execution.progress)
        if ours:
            stack.callback(_timed, shutdown_ray, phases, "ray_shutdown")
        with _phase(phases, "tasks"):
            for _, lines in here.values():
                _said("\n".join(lines), seen)
            render = ray.remote(num_returns=2)(_render_into)
            rendered = {k: render.remote(specs[k], motion, folder) for k, motion in motions.items() if k not in here}
            handed = {k: ray.put(episode) for k, (episode, _) in here.items() if episode is not None}  # not kept
            handed |= {k: episode for k, (episode, _) in rendered.items()}
            inputs = [handed.get(k) for k in range(len(specs)) for _ in names]
            fan_out(
                _run_unit, units, inputs=inputs, on_result=done, execution=replace(config.execution, progress=False)
            )
            for _, said in rendered.values():
                _said(ray.get(said), seen)
    phases.setdefault("ray_shutdown", 0.0)  # Ray was running before: left so
    return [r for r in results if r is not None]


@contextlib.contextmanager
def _phase(phases: dict[str, float], name: str) -> Iterator[None]:
    """The block's wall seconds kept as ``phases[name]``."""
    started = time.perf_counter()
    try:
        yield
    finally:
        phases[name] = time.perf_counter() - started


def _timed(call: Callable[[], Any], phases: dict[str, float], name: str) -> None:
    """``call()``, its wall seconds kept as ``phases[name]``."""
    with _phase(phases, name):
        call()


def _run(
    odometers: dict[str, Odometer],
    sequences,
    observer: RunObserver | None,
    step_timeout: float | None,
    total: int | None = None,
) -> list[SequenceResult]:
    from odolab.io.errors import FileFormatError

    try:
        return runner.run(odometers, sequences, observer=observer, total_steps=total, step_timeout=step_timeout)
    except FileFormatError as exc:  # an image that went bad after the folder was checked
        raise ComparisonError(str(exc)) from None


def _options_note(config: ComparisonConfig) -> list[str]:
    return (
        [
            "Odometer options: "
            + "; ".join(
                f"{name}: " + ", ".join(f"{k}={v!r}" for k, v in opts.items()) for name, opts in config.options.items()
            )
        ]
        if config.options
        else []
    )


def odometer_configs(odometers: dict) -> dict[str, str]:
    """Name -> settings (flattened ``key=value`` list, :func:`odolab.config.describe` of each nested
    config) of each odometer exposing a dataclass ``config``."""
    import dataclasses

    from odolab.config import describe

    def flat(prefix: str, config) -> list[str]:
        return [
            item
            for s in describe(config)
            for item in (
                flat(f"{prefix}{s.name}.", s.value)
                if dataclasses.is_dataclass(s.value) and not isinstance(s.value, type)
                else [f"{prefix}{s.name}={s.value!r}"]
            )
        ]

    def config_of(odo: Odometer) -> object:
        try:
            return getattr(odo, "config", None)
        except Exception:  # noqa: BLE001 - a plug-in's property that raises: nothing to show
            return None

    configs = {name: config_of(odo) for name, odo in odometers.items()}
    return {name: ", ".join(flat("", c)) for name, c in configs.items() if dataclasses.is_dataclass(c)}


def run_comparison(
    config: ComparisonConfig,
    observer: RunObserver | None = None,
    odometers: dict[str, Odometer] | None = None,
    sequences: list | None = None,
) -> ComparisonResult:
    """Run every odometer of ``config`` on its sequences and summarise (nothing is written);
    ``odometers``: those of ``config`` already made by :func:`load_odometers`, else made here;
    ``sequences``: with ``config.tum``, the folder already read by :func:`tum_sequences`."""
    if config.split not in SPLITS:
        raise ComparisonError(f"split {config.split!r} is not a split; choose one of {', '.join(SPLITS)}")
    step_timeout = config.step_timeout
    phases: dict[str, float] = {}
    with _phase(phases, "load_odometers"):
        if odometers is None:
            odometers = load_odometers(config.odometers, config.options)
    if config.tum is not None:
        blind = [name for name, odo in odometers.items() if _needs_action(name, odo)]
        if blind and config.odometers is not None:
            raise ComparisonError(
                f"{blind[0]} needs the action of every step, and real data has none; leave it out of a --tum comparison"
            )
        odometers = {name: odo for name, odo in odometers.items() if name not in blind}  # all, by default
        sequences = sequences if sequences is not None else tum_sequences(config)
        depth_warning = sequences[0].depth_warning()  # read before the run: a few frames
        results = _run(odometers, sequences, observer, step_timeout)
        no_depth = empty_depth_warnings(results)
        title = f"odolab compare on TUM folder {config.tum}"
        dropped = sequences[0].dropped
        left_out = (
            f"{len(sequences[0])} frames; colour images left out: {dropped['no depth']} without a depth "
            f"image and {dropped['no ground truth']} without a ground-truth pose within 0.02 s."
        )
        k = sequences[0].intrinsics
        camera = (
            f"Camera fx {k.fx:g}, fy {k.fy:g}, cx {k.cx:g}, cy {k.cy:g} ({k.width}x{k.height}); depth "
            f"{sequences[0].depth_scale:g} PNG values per metre."
        )
        notes = [
            "Real data: no actions; 'action-prior' is therefore the no-motion row.",
            *([f"Left out, as they need actions: {', '.join(blind)}."] if blind else []),
            "Rows marked oracle read ground truth.",
            left_out,
            camera,
            *_options_note(config),
            *([depth_warning] if depth_warning else []),
            *no_depth,
        ]
        warnings = ([left_out] if any(dropped.values()) else []) + ([depth_warning] if depth_warning else []) + no_depth
        return ComparisonResult(
            results=results,
            rows=summary.summarize(results),
            action_rows=[],
            title=title,
            notes=notes,
            plans=None,
            warnings=warnings,
            configs=odometer_configs(odometers),
            paired_rows=_paired_rows(results),
        )

    from odolab.sim.datasets import episode_specs
    from odolab.sim.episodes import NoiseConfig
    from odolab.sim.redwood import default_table

    try:
        default_table()  # a bad ODOLAB_REDWOOD_TABLE is named before any episode is made
    except ValueError as exc:
        raise ComparisonError(str(exc)) from None
    noise = config.noise or NoiseConfig()
    specs = episode_specs(
        config.split,
        config.episodes,
        seed=config.seed,
        max_steps=config.max_steps,
        noise=noise,
        scenes=config.scenes,
        family=config.family,
    )
    scenes: dict[str, int] = {}
    goals: dict[str, tuple[float, float]] = {}

    def note(name: str, info: dict) -> None:
        scenes[name] = info["scene_seed"]
        if info.get("goal") is not None:
            goals[name] = (float(info["goal"][0]), float(info["goal"][1]))

    if fans_out(config, odometers):
        results = _run_fanned(config, specs, list(odometers), observer, step_timeout, note, phases)
    else:

        def noted(stream):
            for ep in stream:
                note(ep.name, ep.info)
                yield ep

        with _phase(phases, "run"):
            episodes, total = _episode_stream(config, specs)
            results = _run(odometers, noted(episodes), observer, step_timeout, total)
    no_depth = empty_depth_warnings(results)
    one = [r for r in results if r.odometer == results[0].odometer]
    steps = sum(len(r.actions) for r in one)
    collided = sum(int(r.collisions.sum()) for r in one if r.collisions is not None)
    notes = [
        f"{steps} steps, {collided} of them collisions ({100 * collided / max(steps, 1):.1f}%).",
        "Errors are x 1e-2 (m, m, rad), mean absolute error over all steps; rows marked oracle read ground truth.",
        (
            f"Noise multipliers: RGB {noise.rgb:g}, depth {noise.depth:g}, actuation {noise.actuation:g} "
            "(the action prior was fitted at 1, 1, 0.5)."
        ),
    ]
    notes += [f"Command: {config.command}"] if config.command else []
    notes += _options_note(config)
    notes += no_depth
    plans = {name: _floor_plan(seed, goals.get(name), specs[0]) for name, seed in scenes.items()}
    from odolab.reporting.report import counted

    title = f"odolab compare: {counted(config.episodes, config.split + ' episode')}, seed {config.seed}"
    return ComparisonResult(
        results=results,
        rows=summary.summarize(results),
        action_rows=summary.summarize_actions(results),
        title=title,
        notes=notes,
        plans=plans,
        warnings=no_depth,
        configs=odometer_configs(odometers),
        paired_rows=_paired_rows(results),
        phases=phases,
    )


def _paired_rows(results: list[SequenceResult]) -> list[paired.PairedRow]:
    """Each composite row against each of its inputs that ran too (:func:`odolab.running.paired.default_pairs`)."""
    names = list(dict.fromkeys(r.odometer for r in results))
    return paired.paired_differences(results, paired.default_pairs(names))
