"""Study: how each odometer's per-step error grows when the sensors get noisier, against the paper's
claim (Zhao et al. 2021, section 5) that the learned VO degrades more gracefully than classical
odometry.

    python -m studies.noise_robustness [--scale ci|cpu|paper] [--out reports/noise-robustness] [--ray-address ADDR] [--redraw]

Every odometer runs on the same test-split episodes at each sensor-noise level of the scale: RGB
sigma 0.1 x level and the Redwood depth noise x level (actuation noise and paths unchanged, so the
episodes differ only in their pixels). One unit of work is one odometer at one level; its result is
saved as it finishes and reused while the odometer's model or settings (its identity digest) and
the scale's episodes stay the same. Errors are per-step mean absolute errors of (dx m, dz m, dyaw
rad) x 1e-2 as used (a failed step scored with the action prior that replaced it); the growth factor
is a level's error divided by the error at level 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from odolab.config import check, setting
from odolab.sim.scenes import MAX_EPISODE_STEPS
from studies import framework

COMPONENTS = ("dx", "dz", "dyaw")
UNITS = {"dx": "m", "dz": "m", "dyaw": "rad"}
#: The numbers a unit's result holds (the own errors may be None: an odometer that never answered).
NUMBERS = ("steps", *COMPONENTS, *(f"{c}_own" for c in COMPONENTS), "failure_share", "ate_m")
COLUMNS = [
    "odometer", "level", "steps", "dx", "dz", "dyaw", "growth_dx", "growth_dz", "growth_dyaw",
    "failure_share", "ate_m",
]  # fmt: skip


@dataclass(frozen=True)
class Scale:
    """A scale's parameters (``[scales.*]`` of ``studies/noise_robustness.toml``); ``levels`` are kept sorted."""

    levels: tuple[float, ...] = setting(
        range=(0.0, 10.0), min_items=1, distinct=True, doc="noise multipliers, 1 among them (the growth's base)"
    )
    episodes: int = setting(range=(1, 1000), doc="test episodes")
    max_steps: int = setting(range=(1, MAX_EPISODE_STEPS), doc="steps per episode at most")
    odometers: tuple[str, ...] = setting(min_items=1, distinct=True, doc="the odometers, by name")
    learned: tuple[str, ...] = setting(distinct=True, doc="which of the odometers are learned")

    def __post_init__(self) -> None:
        check(self)
        if 1 not in self.levels:
            raise ValueError(f"levels must hold 1 (the base of the growth factors), got {list(self.levels)}")
        if not set(self.learned) <= set(self.odometers):
            raise ValueError(f"learned must name odometers among the odometers, got {list(self.learned)}")
        object.__setattr__(self, "levels", tuple(sorted(self.levels)))


def label(odometer: str, level: float) -> str:
    """A unit's name: ``"icp x1.5"``."""
    return f"{odometer} x{level:g}"


def units(scale: Scale, identity: dict[str, str | None], scenes=None) -> list[framework.Unit]:
    """One unit per (level, odometer); its key holds everything its result depends on (mesh
    ``scenes`` by their digests, their paths the task's inputs). Odometer after odometer, the first
    (the cheap action prior) at every level first: each level's episodes are then rendered once, by
    its unit, and found in the episode cache by the others."""
    return [
        framework.Unit(
            label(odo, level),
            {
                "odometer": odo,
                "identity": identity[odo],
                "level": level,
                "episodes": scale.episodes,
                "max_steps": scale.max_steps,
                "split": "test",
                "seed": 0,
                **framework.scene_key(scenes),
            },
            framework.scene_inputs(scenes),
        )
        for odo in scale.odometers
        for level in scale.levels
    ]


def unit_result(key: dict[str, Any]) -> dict[str, Any]:
    """One odometer on the key's test episodes with RGB and depth noise x ``level``: steps, errors as
    used and own (x 1e-2), failure share and ATE (m)."""
    from odolab.api import SERIAL, ComparisonConfig, NoiseConfig, run_comparison

    name = key["odometer"]
    result = run_comparison(
        ComparisonConfig(
            odometers=[name],
            episodes=key["episodes"],
            max_steps=key["max_steps"],
            seed=key["seed"],
            split=key["split"],
            noise=NoiseConfig(rgb=key["level"], depth=key["level"]),
            scenes=framework.scenes_of_key(key),
            cache=framework.episode_cache(key),
            execution=SERIAL,
        )
    )
    row = next(r for r in result.rows if r.odometer == name)
    own = {f"{c}_own": getattr(row, f"{c}_own") for c in COMPONENTS}
    return {
        "steps": int(row.steps),
        **{c: float(getattr(row, c)) for c in COMPONENTS},
        **{k: float(v) if math.isfinite(v) else None for k, v in own.items()},  # JSON has no NaN
        "failure_share": float(row.failure_share),
        "ate_m": float(row.ate_m),
    }


def _size(value: Any) -> bool:
    """A finite number >= 0 (not a bool, not an integer too large for a float)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(value) and value >= 0
    except OverflowError:  # an integer of hundreds of digits
        return False


def valid_result(value: Any) -> bool:
    """Whether a saved ``value`` has :func:`unit_result`'s shape: every number finite and >= 0 (an
    own error may be None), a share at most 1 (a results file edited or damaged by hand is computed
    again, or missing with ``--redraw``)."""
    return (
        isinstance(value, dict)
        and type(value.get("steps")) is int
        and all(_size(value.get(k)) or (k.endswith("_own") and value.get(k) is None) for k in NUMBERS)
        and value["failure_share"] <= 1
    )


def table(scale: Scale, results: dict[str, Any]) -> list[dict[str, Any]]:
    """Rows odometer x level: errors, growth factors against level 1, failure share, ATE."""
    rows = []
    for odo in scale.odometers:
        base = results.get(label(odo, 1.0))
        for level in scale.levels:
            r = results.get(label(odo, level))
            if r is None:
                continue
            growth = {
                f"growth_{c}": r[c] / base[c] if base is not None and base[c] > 0 else float("nan") for c in COMPONENTS
            }
            rows.append({"odometer": odo, "level": level, **{k: r[k] for k in NUMBERS}, **growth})
    return rows


def growth_label(base: float, value: float) -> str:
    """The change from ``base`` to ``value`` in percent: one decimal below 10 %, whole percent
    above ("+4.6 %", "-2.0 %", "+35 %", "0.0 %"); empty when ``base`` is not positive."""
    if not base > 0:
        return ""
    change = 100.0 * (value / base - 1.0)
    if abs(change) < 0.05:
        return "0.0 %"
    return f"{change:+.1f} %" if abs(change) < 9.95 else f"{change:+.0f} %"


def _blind(rows: list[dict[str, Any]]) -> bool:
    """Whether an odometer's errors are the same at every level (it does not read the frames)."""
    return len({tuple(r[c] for c in COMPONENTS) for r in rows}) == 1


def findings(scale: Scale, rows: list[dict[str, Any]]) -> list[str]:
    """Per component, at the highest level, whether every learned odometer's growth factor is below
    every classical one's (the paper's claim); odometers blind to the frames are named apart."""
    by_odo = {o: [r for r in rows if r["odometer"] == o] for o in scale.odometers}
    top = max((r["level"] for r in rows), default=1.0)
    at_top = {o: next((r for r in rs if r["level"] == top), None) for o, rs in by_odo.items()}
    blind = [o for o, rs in by_odo.items() if len(rs) > 1 and _blind(rs)]
    learned = [o for o in scale.learned if at_top.get(o) is not None]
    classical = [o for o in scale.odometers if o not in scale.learned and o not in blind and at_top.get(o) is not None]
    out = []
    if top == 1.0 or not learned or not classical:
        out.append(
            "The paper's claim (section 5) that the learned VO degrades more gracefully than classical odometry "
            f"is not tested at this scale: it needs a level above 1 and learned and classical odometers with results "
            f"(learned: {', '.join(learned) or 'none'}; classical: {', '.join(classical) or 'none'})."
        )
    else:
        agree = 0
        for c in COMPONENTS:
            g = {o: at_top[o][f"growth_{c}"] for o in (*learned, *classical)}
            holds = max(g[o] for o in learned) < min(g[o] for o in classical)
            agree += holds
            said = "; ".join(
                f"{kind} " + ", ".join(f"{o} {g[o]:.2f}" for o in sorted(names, key=g.get))
                for kind, names in (("learned", learned), ("classical", classical))
            )
            verdict = "agrees with" if holds else "differs from"
            out.append(f"{c} at noise x{top:g}, growth against x1: {said}; {verdict} the paper's claim")
        out.append(
            f"The paper's claim (section 5), learned VO degrades more gracefully than classical odometry: ours "
            f"agrees in {agree} of 3 components (every learned odometer's growth below every classical one's)."
        )
    if blind:
        out.append(f"{', '.join(blind)}: the same error at every level (does not read the frames; a reference row).")
    return out


def _plot_lines(ax: Any, scale: Scale, rows: list[dict[str, Any]], column: str, growth_of: str = "") -> None:
    """One line per odometer of ``column`` against the noise level, in its colour (C0, C1, ... in
    the scale's order; solid: learned, dashed: the others); ``growth_of``: a component whose change
    from x1 to the top level each line's label carries."""
    for k, odo in enumerate(scale.odometers):
        mine = [r for r in rows if r["odometer"] == odo]
        if not mine:
            continue
        name = odo + (" (learned)" if odo in scale.learned else "")
        if growth_of and mine[0]["level"] == 1.0:
            name += f": {growth_label(mine[0][growth_of], mine[-1][growth_of])}"
        ax.plot(
            [r["level"] for r in mine],
            [r[column] for r in mine],
            "-" if odo in scale.learned else "--",
            marker="o",
            color=f"C{k}",
            label=name,
        )
    ax.set_xlabel("sensor-noise multiplier")
    ax.set_xticks(scale.levels, [f"x{v:g}" for v in scale.levels])
    ax.grid(alpha=0.3)


def figure(scale: Scale, rows: list[dict[str, Any]], growth: bool) -> Any:
    """Per component, one line per odometer against the noise level, in one colour per odometer
    throughout: with ``growth``, the growth factor (error / error at x1) in the top row of panels
    and the per-step error itself (as used, x 1e-2) below it, so that a small error that grows is
    not read as worse than a large one that does not; else the error alone. The odometers'
    legend sits under the panels; each growth panel's legend also gives the change from x1 to the
    top level. Returns the figure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    top = max((r["level"] for r in rows), default=1.0)
    panels = 2 if growth else 1
    fig, axes = plt.subplots(panels, 3, figsize=(14, 4.3 * panels + 0.9), sharex=True, squeeze=False)
    for j, c in enumerate(COMPONENTS):
        if growth:
            ax = axes[0][j]
            _plot_lines(ax, scale, rows, f"growth_{c}", growth_of=c)
            ax.axhline(1.0, color="grey", lw=0.8, zorder=0)
            ax.set_ylabel(f"{c}: error / error at x1")
            ax.set_title(f"{c}: growth of the error", fontsize=10)
            ax.legend(fontsize=7, title=f"change x1 -> x{top:g}", title_fontsize=7, loc="upper left")
        ax = axes[-1][j]
        _plot_lines(ax, scale, rows, c)
        ax.set_ylim(bottom=0)
        ax.set_ylabel(f"{c}: mean abs. error ({UNITS[c]} x 1e-2)")
        ax.set_title(f"{c}: per-step error as used ({UNITS[c]} x 1e-2)", fontsize=10)
        if growth:
            axes[0][j].tick_params(labelbottom=True)
    handles, labels = axes[-1][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 6) or 1, fontsize=9, frameon=False)
    what = "Growth of the per-step error (top) and the error itself (bottom)" if growth else "Per-step error as used"
    episodes = f"{scale.episodes} test episode{'s' if scale.episodes != 1 else ''}"
    fig.suptitle(
        f"{what} against sensor noise: RGB sigma 0.1 x and Redwood depth noise x the multiplier\n"
        f"({episodes} x at most {scale.max_steps} steps; one colour per odometer; solid lines: learned, "
        "dashed: the others)",
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0.45 / (4.3 * panels + 0.9), 1, 1))
    return fig


def _draw(scale: Scale, rows: list[dict[str, Any]], path: Path, growth: bool) -> None:
    """:func:`figure`, saved to ``path``."""
    fig = figure(scale, rows, growth)
    import matplotlib.pyplot as plt

    from odolab.io.atomic import save_figure_atomic

    save_figure_atomic(fig, path)
    plt.close(fig)


def study_config() -> framework.StudyConfig:
    """``studies/noise_robustness.toml`` (``ValueError`` names the file and field)."""
    return framework.load_study("noise_robustness")


def run(args) -> int:
    """The study as its command line (:mod:`odolab.cli.study`) asks; 0 when its report is written."""
    scenes = framework.mesh_scenes(args, "reports/noise-robustness")
    study = framework.begin("noise_robustness", args, Scale)
    scale: Scale = study.scale
    outcome = study.run(unit_result, units(scale, study.identity, scenes), valid_result)
    rows = table(scale, outcome.results)
    levels = ", ".join(f"x{v:g}" for v in scale.levels)
    study.publish(
        outcome,
        intro=[
            " ".join(__doc__.split("\n\n")[2].split()).replace("``", ""),
            (
                f"Scale {study.args.scale}: noise {levels}; {scale.episodes} test "
                f"episode{'s' if scale.episodes != 1 else ''} of at most "
                f"{scale.max_steps} steps (seed 0"
                + ("" if scenes is None else f", in the test split of {len(scenes.files)} mesh file(s): {args.scenes}")
                + f"); learned: {', '.join(scale.learned) or 'none'}."
            ),
        ],
        columns=COLUMNS,
        rows=rows,
        figures={
            "errors.png": (
                "Per-step error as used against the sensor-noise multiplier, per component, one line per odometer",
                lambda p: _draw(scale, rows, p, growth=False),
            ),
            "growth.png": (
                (
                    "Growth factor (error / error at x1, top) beside the per-step error itself (as used, "
                    "x 1e-2, bottom) against the sensor-noise multiplier, one line per odometer in the same "
                    "colour in every panel: a small error that grows may still be below a large one that does not"
                ),
                lambda p: _draw(scale, rows, p, growth=True),
            ),
        },
        findings=findings(scale, rows),
    )
    return 0


if __name__ == "__main__":  # python -m studies.noise_robustness: the command line is odolab.cli.study's
    import importlib

    study = importlib.import_module("odolab.cli.study")
    study.exit_process(study.command("noise-robustness"))
