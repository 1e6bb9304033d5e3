"""The navigation study's tables and figures, from its saved episode rows (plain dicts, as
:func:`odolab.navigation.study.run_task` writes them).

Files written under the output folder: ``nav.csv`` (per odometer: success, SPL, SoftSPL, final
geodesic distance and final belief error, each with its 95 % interval; the failures by kind; the
drift per metre of path), ``nav.md`` (the same as
the README's Markdown table), ``episodes.csv``,
``metrics.png`` (bars with intervals), ``belief.png`` (success against the final belief error),
``paths-<episode>.png`` (one panel per odometer: the scene, start, goal, the true path and, dashed,
where the agent believed it was), ``paired.csv`` and ``paired.md`` (each composite against each of
its inputs in the run, on the episodes both ran: :func:`paired_rows`) and ``report.html``.
"""

from __future__ import annotations

import csv
import html
import io
import unicodedata
from pathlib import Path
from typing import Any

import numpy as np

from odolab.config import describe
from odolab.core.stats import mean_ci
from odolab.io.atomic import save_figure_atomic, write_text_atomic
from odolab.io.owned import owned_path
from odolab.navigation.agent import PolicyConfig
from odolab.navigation.metrics import belief_error
from odolab.sim.episodes import EpisodeSpec

METRICS = ("success", "spl", "soft_spl", "d_end", "belief_error")
UNBOUNDED = {"d_end", "belief_error"}  # metres: their intervals are clipped at 0 only
DRIFT_MIN_PATH = 1.0  # m: drift per metre is taken over the episodes whose true path is longer


def summarize(rows: list[dict], odometers: list[str]) -> list[dict]:
    """Per odometer: each metric's mean and 95 % interval (``belief_error`` included: rows without it
    get it from their paths), steps, collisions and failed steps (means and sums); the failures by
    kind, ``stopped_elsewhere`` (STOP outside the success radius) and ``ran_out`` (no STOP before the
    last action); and ``drift_per_m``, the median over the episodes whose true path is longer than
    ``DRIFT_MIN_PATH`` of the final belief error over the path length (m per m)."""
    rows = [r if "belief_error" in r else {**r, "belief_error": belief_error(r)} for r in rows]
    table = []
    for name in odometers:
        mine = [r for r in rows if r["odometer"] == name]
        entry: dict[str, Any] = {"odometer": name, "episodes": len(mine)}
        for m in METRICS:
            ci = mean_ci(np.array([r[m] for r in mine], np.float64), binary=m == "success")
            top = np.inf if m in UNBOUNDED else 1.0  # the interval stays where the metric can be
            entry.update(
                {
                    m: ci.mean,
                    f"{m}_low": float(np.clip(ci.low, 0.0, top)),
                    f"{m}_high": float(np.clip(ci.high, 0.0, top)),
                }
            )
        entry["steps"] = float(np.mean([r["steps"] for r in mine])) if mine else float("nan")
        entry["collisions"] = float(np.mean([r["collisions"] for r in mine])) if mine else float("nan")
        entry["failed_steps"] = int(sum(r["failed_steps"] for r in mine))
        entry["stopped_elsewhere"] = sum(1 for r in mine if r["stopped"] and not r["success"])
        entry["ran_out"] = sum(1 for r in mine if not r["stopped"])
        long = [r["belief_error"] / r["path"] for r in mine if r["path"] > DRIFT_MIN_PATH]
        entry["drift_per_m"] = float(np.median(long)) if long else float("nan")
        table.append(entry)
    return table


def _csv(rows: list[dict], keys: list[str]) -> str:
    """CSV text (names such as ``fused(a,b)`` quoted), floats to 4 decimals."""

    def cell(v):
        return f"{v:.4f}" if isinstance(v, float) else str(v)

    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(keys)
    writer.writerows([cell(r[k]) for k in keys] for r in rows)
    return buf.getvalue()


def metrics_figure(table: list[dict], path: Path) -> None:
    """Bars of success, SPL and SoftSPL per odometer with their 95 % intervals; the legend sits
    outside the axes, right of them, so it hides no bar or interval."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(max(5.5, 1.3 * len(table) + 2), 4.4))
    width = 0.26
    x = np.arange(len(table))
    for k, (m, label) in enumerate((("success", "success"), ("spl", "SPL"), ("soft_spl", "SoftSPL"))):
        mean = np.array([r[m] for r in table])
        err = np.array([[r[m] - r[f"{m}_low"] for r in table], [r[f"{m}_high"] - r[m] for r in table]])
        ax.bar(x + (k - 1) * width, mean, width, yerr=np.maximum(np.nan_to_num(err), 0.0), capsize=3, label=label)
    ax.set_xticks(x, [r["odometer"] for r in table], rotation=20, ha="right", fontsize=8)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("mean over episodes (95 % interval)")
    ax.set_title(f"PointGoal navigation, {table[0]['episodes'] if table else 0} episodes per odometer", fontsize=10)
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(title="metric", fontsize=8, title_fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    fig.tight_layout()
    save_figure_atomic(fig, path)
    plt.close(fig)


def belief_figure(table: list[dict], path: Path) -> None:
    """Success against the final belief error, one point per odometer with both 95 % intervals:
    how much drift each success rate comes with."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    floor = 0.01  # m: ground truth's 0 is drawn here, on the log axis
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    cmap = plt.get_cmap("tab10")
    for k, r in enumerate(table):
        if not r["episodes"]:
            continue
        x, y = max(r["belief_error"], floor), r["success"]
        xerr = [[max(x - max(r["belief_error_low"], floor), 0.0)], [max(r["belief_error_high"] - x, 0.0)]]
        yerr = [[y - r["success_low"]], [r["success_high"] - y]]
        marker = "osD^v"[(k // 10) % 5]  # a colour and marker pair each, past ten odometers too
        ax.errorbar(x, y, xerr=xerr, yerr=yerr, fmt=marker, color=cmap(k % 10), capsize=3, label=r["odometer"])
    ax.set_xscale("log")
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel(
        "final belief error: |true - believed position| at the end\n(m, mean, log scale; below 0.01 m drawn at 0.01)"
    )
    ax.set_ylabel("success (share of episodes)")
    ax.set_title("Navigation success against the odometry's closed-loop drift (95 % intervals)", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.25), ncol=2, frameon=False)
    fig.tight_layout()
    save_figure_atomic(fig, path)
    plt.close(fig)


def paths_figure(rows: list[dict], odometers: list[str], spec: EpisodeSpec, path: Path) -> None:
    """Top-down views of one episode, one panel per odometer (the paper's qualitative figure): free
    space, start, goal, the true path (solid) and where the agent believed it was (dashed), all
    panels on the same axes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from odolab.reporting.report import FloorPlan, draw_floor_plan
    from odolab.sim.episodes import start_environment

    env, begin = start_environment(spec, sensors=False)
    scene = env.scene
    runs = [
        (name, next((r for r in rows if r["odometer"] == name and r["episode"] == spec.index), None))
        for name in odometers
    ]
    runs = [(name, r) for name, r in runs if r is not None] or [("no odometer", None)]
    pts = [np.array([[begin.start.x, begin.start.y], begin.goal])]
    pts += [np.array(r[k]) for _, r in runs if r is not None for k in ("true_xy", "believed_xy")]
    allp = np.concatenate(pts)
    centre, half = (allp.min(0) + allp.max(0)) / 2, np.ptp(allp, axis=0).max() / 2 + 1.0
    cols = min(3, len(runs))
    rows_n = -(-len(runs) // cols)
    fig, axes = plt.subplots(
        rows_n, cols, figsize=(3.6 * cols, 3.6 * rows_n + 0.9), squeeze=False, sharex=True, sharey=True
    )
    plan = FloorPlan(scene.navigable, scene.origin, scene.resolution)
    for ax, (name, row) in zip(axes.flat, runs):
        draw_floor_plan(ax, plan)
        verdict = ""
        if row is not None:
            true, belief = np.array(row["true_xy"]), np.array(row["believed_xy"])
            ax.plot(true[:, 0], true[:, 1], "-", color="tab:blue", lw=1.4, label="true path")
            ax.plot(belief[:, 0], belief[:, 1], "--", color="tab:orange", lw=1.1, label="believed path")
            verdict = (
                "success" if row["success"] else ("stopped" if row["stopped"] else "no stop")
            ) + f", {row['steps']} steps"
        ax.plot(begin.start.x, begin.start.y, "ko", ms=6, label="start")
        ax.plot(*begin.goal, "r*", ms=11, label="goal")
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_aspect("equal", adjustable="box")
        label = name if len(name) <= 34 else name[:31] + "..."
        ax.set_title(f"{label}\n{verdict}", fontsize=8)
    for ax in axes.flat[len(runs) :]:
        ax.axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("world x (m)")
    for ax in axes[:, 0]:
        ax.set_ylabel("world y (m)")
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.suptitle(
        f"{spec.split} episode {spec.index}: geodesic start distance {begin.start_distance:.1f} m", fontsize=10
    )
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    save_figure_atomic(fig, path)
    plt.close(fig)


#: The tables and figures every navigation report has (and ``paths-<episode>.png`` of a few episodes).
REPORT_FILES = (
    "nav.csv",
    "nav.md",
    "episodes.csv",
    "paired.csv",
    "paired.md",
    "metrics.png",
    "belief.png",
    "report.html",
)
#: paired.csv's columns.
PAIRED_KEYS = (
    "composite", "input", "episodes", "composite_only", "input_only", "success_p", "success",
    "spl_diff", "spl_low", "spl_high", "spl", "belief_diff", "belief_low", "belief_high", "belief",
)  # fmt: skip
#: Below this McNemar p-value the success of a composite and its input differ.
ALPHA = 0.05


def paired_rows(rows: list[dict], odometers: list[str]) -> list[dict]:
    """Each composite of ``odometers`` against each odometer inside it (at any depth) that the run
    has too, on the episodes both ran: successes by McNemar's exact test (the episodes only the
    composite, or only the input, succeeded in, and p), SPL and the final belief error (m) by the
    mean paired difference composite - input with its 95 % Student-t interval; each verdict is
    ``higher``, ``lower`` or ``undecided`` (success: p < :data:`ALPHA`; the others: the interval
    clear of 0)."""
    from odolab.core.stats import mcnemar, verdict
    from odolab.odometry.odometer import inner_names

    by = {(r["odometer"], (r["split"], r["seed"], r["episode"])): r for r in rows}
    out = []
    for composite in odometers:
        for inner in [o for o in odometers if o in inner_names(composite)]:
            shared = sorted(k for (o, k) in by if o == composite and (inner, k) in by)
            if not shared:
                continue
            a = [by[(composite, k)] for k in shared]
            b = [by[(inner, k)] for k in shared]
            a_only, b_only, p = mcnemar([float(r["success"]) > 0.5 for r in a], [float(r["success"]) > 0.5 for r in b])
            row = {"composite": composite, "input": inner, "episodes": len(shared), "composite_only": a_only}
            row |= {"input_only": b_only, "success_p": p}
            row["success"] = "undecided" if p >= ALPHA else "higher" if a_only > b_only else "lower"
            for name, key in (("spl", "spl"), ("belief", "belief_error")):
                ci = mean_ci(np.array([float(x[key]) - float(y[key]) for x, y in zip(a, b, strict=True)]))
                row |= {f"{name}_diff": ci.mean, f"{name}_low": ci.low, f"{name}_high": ci.high, name: verdict(ci)}
            out.append(row)
    return out


def paired_markdown(paired: list[dict]) -> str:
    """:func:`paired_rows` as a Markdown table ("" when there is no pair)."""
    if not paired:
        return ""
    lines = [
        "| composite - input | episodes | success: only the composite / only the input (McNemar p) | SPL | final belief error m |",
        "|---|---|---|---|---|",
    ]
    for r in paired:
        spl = f"{r['spl_diff']:+.3f} ({r['spl_low']:+.3f} to {r['spl_high']:+.3f}) {r['spl']}"
        bel = f"{r['belief_diff']:+.2f} ({r['belief_low']:+.2f} to {r['belief_high']:+.2f}) {r['belief']}"
        success = f"{r['composite_only']} / {r['input_only']} (p = {r['success_p']:.2g}) {r['success']}"
        lines.append(
            f"| {markdown_cell(r['composite'])} - {markdown_cell(r['input'])} | {r['episodes']} | {success} | {spl} | {bel} |"
        )
    return "\n".join(lines) + "\n"


def paths_file(spec: EpisodeSpec) -> str:
    """The name of an episode's paths figure."""
    return f"paths-{spec.index:04d}.png"


def output_files(specs: list[EpisodeSpec], sample_episodes: int = 2) -> list[str]:
    """Every file :func:`write_outputs` writes for ``specs`` (relative to its folder)."""
    return [*REPORT_FILES, *(paths_file(s) for s in specs[:sample_episodes])]


def write_outputs(
    out: Path,
    rows: list[dict],
    odometers: list[str],
    specs: list[EpisodeSpec],
    command: str,
    sample_episodes: int = 2,
    policy: PolicyConfig | None = None,
) -> list[dict]:
    """Tables, figures and ``report.html`` under ``out`` (``policy``: the policy, whose parameters the
    report lists with their ranges and meanings, since a command's defaults change between versions), each through
    :func:`odolab.io.owned.owned_path` (never through a link); returns the per-odometer table."""
    rows = [{**r, "belief_error": belief_error(r)} for r in rows]
    table = summarize(rows, odometers)
    keys = (
        ["odometer", "episodes"]
        + [f"{m}{s}" for m in METRICS for s in ("", "_low", "_high")]
        + ["steps", "collisions", "failed_steps", "stopped_elsewhere", "ran_out", "drift_per_m"]
    )
    write_text_atomic(owned_path(out, "nav.csv"), _csv(table, keys))
    write_text_atomic(owned_path(out, "nav.md"), markdown_table(table))
    ep_keys = [
        "odometer",
        "episode",
        "split",
        "seed",
        "d0",
        "d_end",
        "path",
        "stopped",
        "steps",
        "collisions",
        "success",
        "spl",
        "soft_spl",
        "failed_steps",
        "belief_error",
    ]
    write_text_atomic(owned_path(out, "episodes.csv"), _csv(rows, ep_keys))
    paired = paired_rows(rows, odometers)
    write_text_atomic(owned_path(out, "paired.csv"), _csv(paired, list(PAIRED_KEYS)))
    write_text_atomic(owned_path(out, "paired.md"), paired_markdown(paired))
    metrics_figure(table, owned_path(out, "metrics.png"))
    belief_figure(table, owned_path(out, "belief.png"))
    figures = []
    for spec in specs[:sample_episodes]:
        name = paths_file(spec)
        paths_figure(rows, odometers, spec, owned_path(out, name))
        figures.append(name)
    write_text_atomic(owned_path(out, "report.html"), _html(table, figures, command, policy, paired))
    return table


def _ci(r: dict, m: str) -> str:
    """``0.83 [0.74, 0.89]``: a metric's mean and 95 % interval, to 2 decimals (the mean alone when
    there is no interval, as over one episode; ``-`` without episodes)."""
    if not np.isfinite(r[m]):
        return "-"
    if not (np.isfinite(r[m + "_low"]) and np.isfinite(r[m + "_high"])):
        return f"{r[m]:.2f}"
    return f"{r[m]:.2f} [{r[m + '_low']:.2f}, {r[m + '_high']:.2f}]"


def markdown_cell(text: str) -> str:
    """``text`` safe in one Markdown table cell: whitespace runs (newlines too) as one space, control
    characters as ``?``, backslashes and pipes escaped; ``-`` when nothing is left."""
    text = "".join("?" if unicodedata.category(ch) == "Cc" and not ch.isspace() else ch for ch in text)
    text = " ".join(text.split()).replace("\\", "\\\\").replace("|", "\\|")
    return text or "-"


def markdown_table(table: list[dict], oracle: str = "ground-truth") -> str:
    """The per-odometer table in Markdown, as the README shows it: episodes; success, SPL and
    SoftSPL with their intervals, in each of these columns the best value among the odometers other
    than ``oracle`` in bold (when at least two compete and they differ); failed steps (the odometer
    refused, and the action prior stood in) with their share of all steps."""
    head = (
        "| odometer | episodes | success | SPL | SoftSPL | final distance to goal m | final belief error m | "
        "steps | collisions | failed steps |\n|---|---|---|---|---|---|---|---|---|---|\n"
    )
    rivals = [r for r in table if r["odometer"] != oracle and r["episodes"]]
    best = {}
    for m in ("success", "spl", "soft_spl"):
        shown = {f"{r[m]:.2f}" for r in rivals if np.isfinite(r[m])}
        if len(shown) > 1:  # one contender, or a tie of all, is no "best"
            best[m] = max(shown, key=float)
    lines = []
    for r in table:
        cells = [_ci(r, m) for m in METRICS]
        for k, m in enumerate(("success", "spl", "soft_spl")):
            if r in rivals and m in best and f"{r[m]:.2f}" == best[m]:
                cells[k] = f"**{cells[k]}**"
        total = r["steps"] * r["episodes"] if r["episodes"] else 0
        failed = (
            f"{r['failed_steps']} ({100 * r['failed_steps'] / total:.0f} %)"
            if r["failed_steps"] and total
            else str(r["failed_steps"])
        )
        name = markdown_cell(r["odometer"])
        steps = f"{r['steps']:.0f}" if r["episodes"] else "-"
        coll = f"{r['collisions']:.1f}" if r["episodes"] else "-"
        lines.append(f"| {name} | {r['episodes']} | {' | '.join(cells)} | {steps} | {coll} | {failed} |\n")
    return head + "".join(lines)


def _policy_html(policy: PolicyConfig) -> str:
    """The policy's parameters as a table: name, value, valid values and meaning (:func:`odolab.config.describe`)."""
    rows = "".join(
        f"<tr><td><code>{html.escape(s.name)}</code></td><td>{html.escape(repr(s.value))}</td>"
        f"<td>{html.escape(s.range)}</td><td>{html.escape(s.doc)}</td></tr>"
        for s in describe(policy)
    )
    return (
        "<details><summary>Policy (<code>PolicyConfig</code>; change one with <code>--policy key=value</code>)"
        f"</summary><table><tr><th>parameter</th><th>value</th><th>valid</th><th>meaning</th></tr>{rows}</table>"
        "</details>"
    )


def _html(
    table: list[dict], figures: list[str], command: str, policy: PolicyConfig | None = None, paired: list[dict] = ()
) -> str:
    head = (
        "<tr>"
        + "".join(
            f"<th>{h}</th>"
            for h in (
                "odometer",
                "episodes",
                "success",
                "SPL",
                "SoftSPL",
                "final distance to goal (m)",
                "final belief error (m)",
                "steps",
                "collisions",
                "failed odometer steps",
                "failures: stopped elsewhere / ran out",
                "drift per m of path (median)",
            )
        )
        + "</tr>"
    )
    body = "".join(
        "<tr>"
        + "".join(
            f"<td>{html.escape(str(v))}</td>"
            for v in (
                r["odometer"],
                r["episodes"],
                _ci(r, "success"),
                _ci(r, "spl"),
                _ci(r, "soft_spl"),
                _ci(r, "d_end"),
                _ci(r, "belief_error"),
                f"{r['steps']:.0f}",
                f"{r['collisions']:.1f}",
                r["failed_steps"],
                f"{r['stopped_elsewhere']} / {r['ran_out']}",
                f"{100 * r['drift_per_m']:.1f} %",
            )
        )
        + "</tr>"
        for r in table
    )
    imgs = "".join(
        f'<p><img src="{html.escape(f)}" alt="{html.escape(f)}"></p>' for f in ["metrics.png", "belief.png", *figures]
    )
    return (
        f"<!doctype html><html><head><meta charset='utf-8'><title>odolab navigation</title>"
        "<style>body{font-family:sans-serif;max-width:1280px;margin:2em auto}table{font-size:13px}td,th{padding:3px 6px;"
        "border-bottom:1px solid #ccc}img{max-width:100%}</style></head><body>"
        "<h1>PointGoal navigation with each odometer</h1>"
        f"<p><code>{html.escape(command)}</code></p>"
        + (_policy_html(policy) if policy is not None else "")
        + "<p>Means with 95 % intervals (Wilson for success, Student t otherwise). "
        "Success: STOP within 0.36 m (geodesic) of the goal; SPL and SoftSPL as habitat-lab defines them. "
        "Final belief error: the distance between the agent's true and believed positions when the episode "
        "ends (the odometry's drift in the closed loop).</p>"
        f"<table>{head}{body}</table>" + _paired_html(paired) + f"{imgs}</body></html>\n"
    )


def _paired_html(paired: list[dict]) -> str:
    """The composites against their inputs (:func:`paired_rows`) as an HTML section ("" without any)."""
    if not paired:
        return ""
    head = "".join(
        f"<th>{h}</th>"
        for h in (
            "composite - input",
            "episodes",
            "success: only A / only B (McNemar p)",
            "SPL difference",
            "belief error difference (m)",
        )
    )
    body = "".join(
        "<tr>"
        + "".join(
            f"<td>{html.escape(v)}</td>"
            for v in (
                f"{r['composite']} - {r['input']}",
                str(r["episodes"]),
                f"{r['composite_only']} / {r['input_only']} (p = {r['success_p']:.2g}) {r['success']}",
                f"{r['spl_diff']:+.3f} ({r['spl_low']:+.3f} to {r['spl_high']:+.3f}) {r['spl']}",
                f"{r['belief_diff']:+.2f} ({r['belief_low']:+.2f} to {r['belief_high']:+.2f}) {r['belief']}",
            )
        )
        + "</tr>"
        for r in paired
    )
    return (
        "<h2>Each composite against its inputs, on the same episodes</h2><p>A: the composite, B: its input. "
        f"Success by McNemar's exact test (a verdict where p &lt; {ALPHA:g}); SPL and the final belief error "
        "by the mean paired difference A - B with its 95 % Student-t interval.</p>"
        f"<table><tr>{head}</tr>{body}</table>"
    )
