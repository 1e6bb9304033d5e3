"""Study: every odometer's per-step error on test episodes, mean and spread over seeds, beside the
paper's Table S4 (E1 feature matching, E2 feature matching with the true rotation, E3 the robust VO).

    python -m studies.e_table [--scale ci|cpu|paper] [--out reports/e-table] [--ray-address ADDR] [--redraw]

One unit of work is one odometer on one seed's episodes (``python -m odolab.compare`` on the test
split, the challenge's noise); its result is saved as it finishes and reused while the odometer's
model or settings (its identity digest) and the scale's episodes stay the same. Errors are mean
absolute errors of (dx m, dz m, dyaw rad) x 1e-2, as used (a failed step scored with the action
prior that replaced it), on the odometer's own answered steps, and under the paper's protocol
(``*_raw``: every step scored with the odometer's own motion, the unverified one where it refused;
``raw_missing`` steps had none and keep the prior's); the spread is the standard deviation over
seeds. The paper's numbers are on its validation set (50,000 pairs, its own simulator data), ours
on test episodes: the ordering is what compares, not the values.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from odolab.config import check, setting
from odolab.sim.free_scenes import FAMILIES
from odolab.sim.mesh_scenes import SceneFiles
from odolab.sim.scenes import MAX_EPISODE_STEPS
from studies import framework

COMPONENTS = ("dx", "dz", "dyaw")
ACTIONS = ("all", "move_forward", "turn_left", "turn_right")
#: The paper's Table S4 (x 1e-2, its validation set) and which of our odometers each row is.
PAPER = {
    "feature-essential": ("E1", (15.9, 21.3, 8.51)),
    "feature-essential-oracle-rot": ("E2", (3.97, 10.6, 0.00)),
    "robust-vo": ("E3", (1.22, 0.86, 0.66)),
}


def unit_result(key: dict[str, Any]) -> dict[str, Any]:
    """Run one odometer on one seed's test episodes: per action ("all" included) its errors as used
    and own and its bias (signed mean error as used; x 1e-2), steps and failure share."""
    from odolab.api import SERIAL, ComparisonConfig, run_comparison

    scenes = framework.scenes_of_key(key)
    result = run_comparison(
        ComparisonConfig(
            odometers=[key["odometer"]],
            episodes=key["episodes"],
            max_steps=key["max_steps"],
            seed=key["seed"],
            split="test",
            family=key.get("family", "boxes"),
            scenes=scenes,
            cache=framework.episode_cache(key),
            execution=SERIAL,
        )
    )
    out: dict[str, Any] = {}
    for r in result.rows:
        if r.odometer == key["odometer"]:
            out["all"] = _numbers(r, r.steps, r.failure_share)
    for a in result.action_rows:
        if a.odometer == key["odometer"] and a.action in ACTIONS:
            out[a.action] = _numbers(a, a.steps, a.failures / a.steps if a.steps else 0.0)
    return out


def valid_result(value: Any) -> bool:
    """Whether a saved ``value`` has :func:`unit_result`'s shape, its errors finite and >= 0 (the own
    errors may be None: an odometer that never answered; the biases finite, of either sign), its
    steps and ``raw_missing`` counts and its failure share in [0, 1]: a results file edited or
    damaged by hand (or saved before a column existed) is computed again rather than breaking the table."""

    def number(v: Any) -> bool:
        return type(v) in (int, float) and math.isfinite(v) and v >= 0

    def shaped(entry: Any) -> bool:
        return (
            isinstance(entry, dict)
            and type(entry.get("steps")) is int
            and entry["steps"] >= 0
            and all(number(entry.get(c)) for c in COMPONENTS)
            and all(number(entry.get(f"{c}_raw")) for c in COMPONENTS)
            and all(entry.get(f"{c}_own") is None or number(entry.get(f"{c}_own")) for c in COMPONENTS)
            and all(
                type(entry.get(f"{c}_bias")) in (int, float) and math.isfinite(entry[f"{c}_bias"]) for c in COMPONENTS
            )
            and number(entry.get("failure_share"))
            and entry["failure_share"] <= 1
            and type(entry.get("raw_missing")) is int
            and 0 <= entry["raw_missing"] <= round(entry["failure_share"] * entry["steps"])  # of the failed steps
        )

    return isinstance(value, dict) and "all" in value and all(shaped(value[a]) for a in value if a in ACTIONS)


def _numbers(row: Any, steps: int, failure_share: float) -> dict[str, float]:
    own = {f"{c}_own": _finite(getattr(row, f"{c}_own")) for c in COMPONENTS}
    return {
        **{c: float(getattr(row, c)) for c in COMPONENTS},
        **own,
        **{f"{c}_bias": float(getattr(row, f"{c}_bias")) for c in COMPONENTS},
        **{f"{c}_raw": float(getattr(row, f"{c}_raw")) for c in COMPONENTS},
        "raw_missing": int(row.raw_missing),
        "steps": int(steps),
        "failure_share": failure_share,
    }


def _finite(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None  # JSON has no NaN: an odometer that never answered


@dataclass(frozen=True)
class Scale:
    """A scale's parameters (``[scales.*]`` of ``studies/e_table.toml``)."""

    seeds: tuple[int, ...] = setting(
        range=(0, 2**32 - 1), min_items=1, distinct=True, doc="test seeds: each draws other episodes and noise"
    )
    episodes: int = setting(range=(1, 1000), doc="test episodes per seed")
    max_steps: int = setting(range=(1, MAX_EPISODE_STEPS), doc="steps per episode at most")
    odometers: tuple[str, ...] = setting(min_items=1, distinct=True, doc="the odometers, by name")
    families: tuple[str, ...] = setting(
        ("boxes",), min_items=1, distinct=True, doc=f"procedural scene families: of {', '.join(FAMILIES)}"
    )

    def __post_init__(self) -> None:
        check(self)
        odd = [f for f in self.families if f not in FAMILIES]
        if odd:
            raise ValueError(f"families: expected some of {', '.join(FAMILIES)}, got {odd[0]!r:.40}")


def label(odometer: str, seed: int, family: str) -> str:
    """A unit's label; the boxes family's as it was before families."""
    return f"{odometer} seed {seed}" + ("" if family == "boxes" else f" {family}")


def families(scale: Scale, scenes: SceneFiles | None = None) -> tuple[str, ...]:
    """The scale's procedural scene families, or ``("mesh",)`` for episodes in mesh ``scenes``."""
    return scale.families if scenes is None else ("mesh",)


def units(scale: Scale, identity: dict[str, str | None], scenes: SceneFiles | None = None) -> list[framework.Unit]:
    """One unit per (family, odometer, seed); its key holds everything its result depends on (the
    family only when not boxes: their keys are as before families; mesh ``scenes`` by their digests,
    the files' paths handed to the task as its inputs)."""

    def where(family: str) -> dict[str, Any]:
        if scenes is not None:
            return framework.scene_key(scenes)
        return {} if family == "boxes" else {"family": family}

    inputs = framework.scene_inputs(scenes)
    return [
        framework.Unit(
            label(odo, seed, family),
            {
                "odometer": odo,
                "identity": identity[odo],
                "seed": seed,
                "episodes": scale.episodes,
                "max_steps": scale.max_steps,
                **where(family),
            },
            inputs,
        )
        for family in families(scale, scenes)
        for odo in scale.odometers
        for seed in scale.seeds
    ]


def table(scale: Scale, results: dict[str, Any], scenes: SceneFiles | None = None) -> list[dict[str, Any]]:
    """Rows family x odometer x action: mean and standard deviation over the seeds that have a result."""
    rows = []
    for family, odo in ((f, o) for f in families(scale, scenes) for o in scale.odometers):
        for action in ACTIONS:
            done = [results.get(label(odo, s, family), {}) for s in scale.seeds]
            got = [r[action] for r in done if action in r]
            if not got:
                continue
            row: dict[str, Any] = {"family": family, "odometer": odo, "action": action, "seeds": len(got)}
            for c in (
                *COMPONENTS,
                *(f"{c}_own" for c in COMPONENTS),
                *(f"{c}_bias" for c in COMPONENTS),
                *(f"{c}_raw" for c in COMPONENTS),
                "failure_share",
            ):
                values = np.array([np.nan if g[c] is None else g[c] for g in got], float)
                row[c] = float(np.mean(values))
                row[f"{c}_sd"] = float(np.std(values)) if len(values) > 1 else float("nan")
            row["steps"] = int(sum(g["steps"] for g in got))
            row["raw_missing"] = int(sum(g["raw_missing"] for g in got))
            paper = PAPER.get(odo)
            row["paper"] = f"{paper[0]} ({', '.join(f'{v:g}' for v in paper[1])})" if paper and action == "all" else ""
            rows.append(row)
    return rows


COLUMNS = [
    "family", "odometer", "action", "seeds", "steps", "dx", "dx_sd", "dz", "dz_sd", "dyaw", "dyaw_sd",
    "dx_own", "dz_own", "dyaw_own", "dx_raw", "dz_raw", "dyaw_raw", "raw_missing", "dx_bias", "dz_bias",
    "dyaw_bias", "failure_share", "paper",
]  # fmt: skip


def findings(rows: list[dict[str, Any]]) -> list[str]:
    """Per family, :func:`order_findings`; with several families, :func:`family_findings` after."""
    families = list(dict.fromkeys(r["family"] for r in rows))
    if len(families) <= 1:
        return order_findings(rows)
    out = [f"{f}: {line}" for f in families for line in order_findings([r for r in rows if r["family"] == f])]
    return out + family_findings(rows, families[0])


def order_findings(rows: list[dict[str, Any]]) -> list[str]:
    """Per component, whether our E1 / E2 / E3 come in the paper's order, with mean +- sd over seeds
    (the sd "-" with one seed), as used (a refused step scored with the action prior) and under the
    paper's protocol (``*_raw``: every step's own estimate, unverified where refused); a verdict needs
    two of them at least."""
    overall = {r["odometer"]: r for r in rows if r["action"] == "all"}
    have = [o for o in PAPER if o in overall]
    if len(have) < 2:
        named = ", ".join(f"{PAPER[o][0]} ({o})" for o in PAPER)
        return [f"No order to compare: the paper's table ranks {named}; this table holds {len(have)} of them."]
    out = []
    for suffix, protocol in (("", "as used"), ("_raw", "the paper's protocol")):
        for k, c in enumerate(COMPONENTS):
            column = c + suffix
            paper_order = sorted(have, key=lambda o: PAPER[o][1][k])
            ours = sorted(have, key=lambda o: overall[o][column])
            said = ", ".join(
                f"{PAPER[o][0]} {overall[o][column]:.2f} +- {_sd(overall[o][f'{column}_sd'])}" for o in ours
            )
            verdict = "agrees with" if ours == paper_order else "differs from"
            paper_said = " < ".join(PAPER[o][0] for o in paper_order)
            out.append(f"{c}, {protocol}: ours {said} (x 1e-2, lowest first); {verdict} the paper's order {paper_said}")
    return out


def family_findings(rows: list[dict[str, Any]], base: str) -> list[str]:
    """Per odometer, its error as used (all steps) in each other family against ``base``'s, per
    component: ``higher`` or ``lower`` where the two ranges mean +- sd over seeds do not overlap,
    else ``undecided`` (a range of one seed is its value)."""
    overall = {(r["family"], r["odometer"]): r for r in rows if r["action"] == "all"}
    out = []
    for (family, odo), row in overall.items():
        ref = overall.get((base, odo))
        if family == base or ref is None:
            continue
        said = []
        for c in COMPONENTS:
            lo, hi = (_range(r, c) for r in (ref, row))
            verdict = "higher" if hi[0] > lo[1] else "lower" if hi[1] < lo[0] else "undecided"
            said.append(f"{c} {ref[c]:.2f} -> {row[c]:.2f} ({verdict})")
        out.append(f"{odo}, {base} -> {family} (x 1e-2, as used): {'; '.join(said)}")
    return out


def _range(row: dict[str, Any], c: str) -> tuple[float, float]:
    sd = row[f"{c}_sd"] if math.isfinite(row[f"{c}_sd"]) else 0.0
    return row[c] - sd, row[c] + sd


def _sd(v: float) -> str:
    return f"{v:.2f}" if math.isfinite(v) else "-"


def draw(rows: list[dict[str, Any]], path: Path) -> None:
    """Bars of each odometer's error per component (all steps), with the spread over seeds; each
    odometer's label says the share of its steps that failed (scored with the action prior)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from odolab.io.atomic import save_figure_atomic

    overall = [r for r in rows if r["action"] == "all"]
    fig, axes = plt.subplots(1, 3, figsize=(14, 0.6 * len(overall) + 2), sharey=True)
    y = np.arange(len(overall))
    order = list(dict.fromkeys(r["family"] for r in overall))
    colours = [f"C{order.index(r['family'])}" for r in overall]
    for ax, c, unit in zip(axes, COMPONENTS, ("m", "m", "rad")):
        ax.barh(
            y,
            [r[c] for r in overall],
            xerr=[0 if r[f"{c}_sd"] != r[f"{c}_sd"] else r[f"{c}_sd"] for r in overall],
            color=colours,
            alpha=0.8,
        )
        ax.set_xlabel(f"{c}: mean abs. error ({unit} x 1e-2)")
        ax.grid(axis="x", alpha=0.3)
    several = len({r["family"] for r in overall}) > 1
    names = [f"{r['odometer']}" + (f" [{r['family']}]" if several else "") for r in overall]
    axes[0].set_yticks(y, [f"{n}\n({100 * r['failure_share']:.0f} % of steps failed)" for n, r in zip(names, overall)])
    axes[0].invert_yaxis()
    if len(order) > 1:
        from matplotlib.patches import Patch

        axes[-1].legend(
            handles=[Patch(color=f"C{k}", alpha=0.8, label=f"{f} scenes") for k, f in enumerate(order)],
            loc="lower right",
        )
    fig.suptitle(
        "Per-step error as used (a failed step scored with the action prior), all test steps:\n"
        "bars are the mean over seeds, lines one standard deviation"
    )
    fig.tight_layout(rect=(0, 0, 1, 0.99))
    save_figure_atomic(fig, path)
    plt.close(fig)


def study_config() -> framework.StudyConfig:
    """``studies/e_table.toml`` (``ValueError`` names the file and field)."""
    return framework.load_study("e_table")


def run(args) -> int:
    """The study as its command line (:mod:`odolab.cli.study`) asks; 0 when its report is written."""
    from odolab.reporting.report import counted

    scenes = framework.mesh_scenes(args, "reports/e-table")
    study = framework.begin("e_table", args, Scale)
    scale: Scale = study.scale
    outcome = study.run(unit_result, units(scale, study.identity, scenes), valid_result)
    rows = table(scale, outcome.results, scenes)
    study.publish(
        outcome,
        intro=[
            " ".join(__doc__.split("\n\n")[2].split()).replace("``", ""),
            (
                f"Scale {study.args.scale}: {'seed' if len(scale.seeds) == 1 else 'seeds'} "
                f"{', '.join(map(str, scale.seeds))}, {counted(scale.episodes, 'test episode')} of at most "
                f"{counted(scale.max_steps, 'step')} each per seed, in "
                + (
                    f"the procedural scene {'family' if len(scale.families) == 1 else 'families'} "
                    f"{', '.join(scale.families)} (docs/simulator.md#scene-families)"
                    if scenes is None
                    else f"the test split of {counted(len(scenes.files), 'mesh file')} ({args.scenes})"
                )
                + "; the learned odometers as shipped, trained in boxes scenes."
            ),
        ],
        columns=COLUMNS,
        rows=rows,
        figures={
            "errors.png": ("Per-step error of each odometer (all steps, mean over seeds)", lambda p: draw(rows, p))
        },
        findings=findings(rows),
    )
    return 0


if __name__ == "__main__":  # python -m studies.e_table: the command line is odolab.cli.study's
    import importlib

    study = importlib.import_module("odolab.cli.study")
    study.exit_process(study.command("e-table"))
