"""Study: how often each odometer fails a turn, and how far off it is, by how far the view reaches.

    python -m studies.turns_by_depth [--scale ci|cpu|paper] [--out reports/turns-by-depth] [--ray-address ADDR] [--redraw]

Navigation turns the agent in front of walls and in large rooms far more often than the episode
generator's shortest-path follower does, and those turns decide where the agent believes it is.
Every odometer sees the same turns: in each scene of the scale's split (the scenes of its first
episodes), random navigable poses with random headings, one noisy TURN_LEFT or TURN_RIGHT each (the
challenge's actuation, RGB and depth noise). Turns are binned by the median depth of the first
frame (m). Per odometer and bin: turns, failed share (invalid, raising, or not a rigid motion: what
the runner would replace by the prior) and, over the answered turns, the RMS yaw error (deg) and the
share more than 2 degrees off. One unit of work is one odometer on one scene's turns; its result is
saved as it finishes and reused while the odometer's options and model or settings (its identity
digest) stay the same.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from odolab.api import StepByStep, invert, transform_to_planar, wrap_angle
from odolab.config import check, setting
from studies import framework

#: Bins of the first frame's median depth, m.
BINS = ((0.0, 1.0), (1.0, 2.0), (2.0, 4.0), (4.0, np.inf))
COLUMNS = ["odometer", "bin", "turns", "failed_share", "yaw_rms_deg", "over_2deg_share"]


@dataclass(frozen=True)
class Scale:
    """A scale's parameters (``[scales.*]`` of ``studies/turns_by_depth.toml``): ``per_scene`` turns
    in each of the first ``scenes`` scenes of ``split`` from ``seed``, the ``odometers`` and their
    constructor ``options`` (name -> {key: value})."""

    split: Literal["train", "val", "test"] = setting(doc="the split whose scenes are drawn")
    seed: int = setting(range=(0, 2**31 - 1), doc="the seed of the scenes and turns")
    scenes: int = setting(range=(1, 1000), doc="scenes")
    per_scene: int = setting(range=(1, 1000), doc="turns per scene")
    odometers: tuple[str, ...] = setting(min_items=1, distinct=True, doc="the odometers, by name")
    options: dict[str, dict[str, Any]] = setting(doc="option tables, one per odometer among the odometers")

    def __post_init__(self) -> None:
        check(self)
        if not (
            isinstance(self.options, dict)
            and set(self.options) <= set(self.odometers)
            and all(isinstance(o, dict) for o in self.options.values())
        ):
            raise ValueError(
                f"options must be a table of option tables, one per odometer among the odometers, got {self.options!r:.80}"
            )


def turn_pairs(split: str, seed: int, scenes: int, per_scene: int, first: int = 0) -> Iterator[tuple]:
    """Yield (scene index, median depth m, action, prev frame, cur frame, true yaw rad) for random
    turns in the scenes of ``split``'s first ``scenes`` episodes, from scene ``first`` on (each
    scene's turns are the same whichever scene the run starts from)."""
    from odolab.core.types import Action
    from odolab.sim.agent import AgentState
    from odolab.sim.episodes import EpisodeSpec, start_environment

    for e in range(first, scenes):
        env, _ = start_environment(EpisodeSpec(split=split, index=e, seed=seed, max_steps=1))
        sc = env.scene
        rng = np.random.default_rng([seed, e])
        rows, cols = np.nonzero(sc.navigable)
        for _ in range(per_scene):
            i = int(rng.integers(len(rows)))
            x, y = sc.cell_to_world(rows[i], cols[i])
            env.state = AgentState(float(x), float(y), float(rng.uniform(-np.pi, np.pi)))
            prev = env.observe(0.0)
            action = Action.TURN_LEFT if rng.random() < 0.5 else Action.TURN_RIGHT
            env.step(action)
            cur = env.observe(1.0)
            true_yaw = transform_to_planar(invert(prev.gt_pose) @ cur.gt_pose)[2]
            seen = prev.depth[prev.depth > 0]
            yield e, float(np.median(seen)) if seen.size else 0.0, action, prev, cur, float(true_yaw)


def label(odometer: str, scene: int) -> str:
    """A unit's name: ``"icp scene 3"``."""
    return f"{odometer} scene {scene}"


def units(scale: Scale, identity: dict[str, str | None]) -> list[framework.Unit]:
    """One unit per (odometer, scene); its key holds everything its result depends on."""
    return [
        framework.Unit(
            label(odo, e),
            {
                "odometer": odo,
                "options": scale.options.get(odo, {}),
                "identity": identity[odo],
                "split": scale.split,
                "seed": scale.seed,
                "scene": e,
                "per_scene": scale.per_scene,
            },
        )
        for odo in scale.odometers
        for e in range(scale.scenes)
    ]


def unit_result(key: dict[str, Any]) -> list[list]:
    """One odometer on one scene's turns: per turn [median depth m, answered, |yaw error| deg or None]."""
    from odolab.api import load_odometer
    from odolab.sim.episodes import EpisodeSpec

    pairs = turn_pairs(key["split"], key["seed"], key["scene"] + 1, key["per_scene"], first=key["scene"])
    with StepByStep(load_odometer(key["odometer"], **key["options"]), key["odometer"]) as asked:
        asked.reset(EpisodeSpec().camera.intrinsics)  # turn_pairs' episodes use the default camera
        return [[depth, *_answer(asked, prev, cur, action, yaw)] for _, depth, action, prev, cur, yaw in pairs]


def _answer(asked: StepByStep, prev, cur, action, true_yaw: float) -> tuple[bool, float | None]:
    """(answered, |yaw error| deg or None) of one turn, asked under the runner's guards (frames as
    the runner shows them, a raising, timed-out or invalid answer fails the pair)."""
    est = asked.step(asked.frame(prev), asked.frame(cur), action)
    if est is None:
        return False, None
    return True, float(np.degrees(abs(wrap_angle(transform_to_planar(est.transform)[2] - true_yaw))))


def _number(v: object) -> bool:
    """A finite number (not a bool, not an integer too large for a float)."""
    try:
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
    except OverflowError:
        return False


def row_ok(row: object) -> bool:
    """A saved turn: [median depth m >= 0, answered, |yaw error| deg in [0, 180] or None when not answered]."""
    return (
        isinstance(row, list)
        and len(row) == 3
        and _number(row[0])
        and row[0] >= 0
        and isinstance(row[1], bool)
        and ((row[1] and _number(row[2]) and 0 <= row[2] <= 180) or (not row[1] and row[2] is None))
    )


def valid_result(value: Any, per_scene: int) -> bool:
    """Whether a saved ``value`` is one scene's ``per_scene`` turns (a results file edited or damaged
    by hand is computed again, or missing with ``--redraw``)."""
    return isinstance(value, list) and len(value) == per_scene and all(map(row_ok, value))


def stats(rows: list, name: str) -> dict[str, Any]:
    """Turns, failed share, RMS yaw error (deg) and share > 2 deg off of the answered, of ``rows``."""
    errs = np.array([r[2] for r in rows if r[1]], float)
    return {
        "bin": name,
        "turns": len(rows),
        "failed_share": 1 - len(errs) / len(rows) if rows else float("nan"),
        "yaw_rms_deg": float(np.sqrt(np.mean(errs**2))) if errs.size else float("nan"),
        "over_2deg_share": float(np.mean(errs > 2.0)) if errs.size else float("nan"),
    }


def bin_stats(rows: list) -> list[dict[str, Any]]:
    """:func:`stats` per depth bin of :data:`BINS`."""
    return [
        stats([r for r in rows if lo <= r[0] < hi], f"{lo:g}-{hi:g} m" if np.isfinite(hi) else f"> {lo:g} m")
        for lo, hi in BINS
    ]


def turns_of(scale: Scale, results: dict[str, Any]) -> dict[str, list]:
    """Odometer -> its saved turns, scene after scene (the scenes with a result)."""
    return {
        odo: [t for e in range(scale.scenes) for t in results.get(label(odo, e), [])]
        for odo in scale.odometers
        if any(label(odo, e) in results for e in range(scale.scenes))
    }


def table(turns: dict[str, list]) -> list[dict[str, Any]]:
    """Rows odometer x depth bin (and "all")."""
    return [{"odometer": odo, **s} for odo, rows in turns.items() for s in [*bin_stats(rows), stats(rows, "all")]]


def findings(rows: list[dict[str, Any]]) -> list[str]:
    """The paper has no table to compare; per odometer, where it fails most and where it is furthest off."""
    out = ["The paper has no table of turns by depth: there are no paper numbers to agree or differ with."]
    for odo in dict.fromkeys(r["odometer"] for r in rows):
        bins = [r for r in rows if r["odometer"] == odo and r["bin"] != "all" and r["turns"]]
        answered = [r for r in bins if math.isfinite(r["yaw_rms_deg"])]
        worst = max(bins, key=lambda r: r["failed_share"], default=None)
        off = max(answered, key=lambda r: r["yaw_rms_deg"], default=None)
        if worst is None or worst["failed_share"] == 0:
            said = f"{odo}: answers every turn"
        else:
            said = f"{odo}: fails most at {worst['bin']} ({100 * worst['failed_share']:.1f} % of its turns)"
        said += f"; furthest off at {off['bin']} ({off['yaw_rms_deg']:.2f} deg RMS)" if off else "; answered no turn"
        out.append(said)
    return out


def share_text(share: float) -> str:
    """A failed share (a fraction) as the figure writes it, in %: ``0``, ``0.9``, ``12``, ``100``;
    ``-`` where there is none (no turn in the bin)."""
    if not math.isfinite(share):
        return "-"
    percent = 100 * share
    if percent == 0 or percent >= 9.95:
        return f"{percent:.0f}"
    return f"{percent:.1f}"


def figure(scale: Scale, turns: dict[str, list]) -> Any:
    """Failed share (top) and RMS yaw error of the answered turns (bottom) per depth bin, one bar
    per odometer in its colour; above every bar (and where a bar is missing, at its foot) the
    failed share in %, so that a small RMS over few answered turns is read as such. The labels are
    the figure's texts with the gid ``failed-share``. Returns the figure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(2, 1, figsize=(12, 8.8))
    names = list(turns)
    width = 0.8 / max(len(names), 1)
    tops = {a: 0.0, b: 0.0}
    for k, n in enumerate(names):
        per_bin = bin_stats(turns[n])
        x = np.arange(len(per_bin)) + (k - (len(names) - 1) / 2) * width
        failed = [100 * s["failed_share"] for s in per_bin]
        rms = [s["yaw_rms_deg"] for s in per_bin]
        for ax, heights in ((a, failed), (b, rms)):
            ax.bar(x, heights, width, label=n, color=f"C{k}")
            for xi, h, s in zip(x, heights, per_bin):
                ax.annotate(
                    share_text(s["failed_share"]),
                    (xi, h if math.isfinite(h) else 0.0),
                    xytext=(0, 2),
                    textcoords="offset points",
                    ha="center",
                    va="bottom",
                    rotation=90 if len(names) > 3 else 0,  # narrow bars: upright text
                    fontsize=8 if len(names) > 3 else 9,
                    color="0.15",
                    gid="failed-share",
                )
            tops[ax] = max([tops[ax], *(h for h in heights if math.isfinite(h))])

    def count(k: int, word: str) -> str:
        return f"{k} {word}{'' if k == 1 else 's'}"

    first = bin_stats(turns[names[0]]) if names else bin_stats([])
    ticks = [f"{s['bin']}\n({count(s['turns'], 'turn')})" for s in first]
    for ax, ylabel, title in (
        (a, "failed turns (%)", "Failed share of the turns (number above each bar: failed %)"),
        (
            b,
            "yaw error of answered turns, RMS (deg)",
            "RMS yaw error of the answered turns (number above each bar: failed % it leaves out)",
        ),
    ):
        ax.set_xticks(np.arange(len(ticks)), ticks, fontsize=8)
        ax.set_xlabel("median depth of the first frame (no bar: no turn, or none answered)", fontsize=8)
        ax.set_ylabel(ylabel)
        ax.set_title(title, fontsize=9)
        ax.set_ylim(0, (tops[ax] or 1.0) * 1.22)  # room for the labels above the highest bar
        ax.grid(axis="y", alpha=0.3)
    rows = -(-len(names) // 4)  # at most four names per legend row
    fig.legend(*a.get_legend_handles_labels(), loc="lower center", ncol=min(len(names), 4), fontsize=9, frameon=False)
    given = "; ".join(f"{n} " + ", ".join(f"{k}={v}" for k, v in o.items()) for n, o in scale.options.items() if o)
    fig.suptitle(
        f"Turns from random poses: {count(scale.scenes, scale.split + ' scene')} x {count(scale.per_scene, 'turn')}"
        + (f" (options: {given[:120]})" if given else ""),
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0.025 + 0.02 * rows, 1, 1))
    return fig


def draw(scale: Scale, turns: dict[str, list], path: Path) -> None:
    """:func:`figure`, saved to ``path``."""
    fig = figure(scale, turns)
    import matplotlib.pyplot as plt

    from odolab.io.atomic import save_figure_atomic

    save_figure_atomic(fig, path)
    plt.close(fig)


def study_config() -> framework.StudyConfig:
    """``studies/turns_by_depth.toml`` (``ValueError`` names the file and field)."""
    return framework.load_study("turns_by_depth")


def run(args) -> int:
    """The study as its command line (:mod:`odolab.cli.study`) asks; 0 when its report is written."""
    from odolab.reporting.report import counted

    study = framework.begin("turns_by_depth", args, Scale)
    scale: Scale = study.scale
    valid = functools.partial(valid_result, per_scene=scale.per_scene)
    outcome = study.run(unit_result, units(scale, study.identity), valid)
    turns = turns_of(scale, outcome.results)
    rows = table(turns)
    given = "; ".join(f"{n}: {o}" for n, o in scale.options.items() if o)
    study.publish(
        outcome,
        intro=[
            " ".join(__doc__.split("\n\n")[2].split()),
            (
                f"Scale {study.args.scale}: {counted(scale.per_scene, 'turn')} in each of "
                f"{counted(scale.scenes, scale.split + ' scene')} "
                f"(seed {scale.seed}); options: {given or 'none'}. Shares are fractions; the RMS and the share "
                "over 2 deg are over the answered turns."
            ),
        ],
        columns=COLUMNS,
        rows=rows,
        figures={
            "turns.png": (
                (
                    "Failed share (top) and RMS yaw error of the answered turns (bottom) per median-depth bin, "
                    "one bar per odometer; the number above each bar is its failed share in %"
                ),
                lambda p: draw(scale, turns, p),
            )
        },
        findings=findings(rows),
    )
    return 0


if __name__ == "__main__":  # python -m studies.turns_by_depth: the command line is odolab.cli.study's
    import importlib

    study = importlib.import_module("odolab.cli.study")
    study.exit_process(study.command("turns-by-depth"))
