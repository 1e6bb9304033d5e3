"""Study: how much each odometer's per-step error grows when the sensors get noisier.

The paper's claim (Zhao et al. 2021, section 5): the learned VO degrades more gracefully than
classical odometry. Every odometer runs on the same test-split episodes at sensor-noise multiplier
1 (the challenge's RGB sigma 0.1 and Redwood depth noise) and at each other ``--levels`` value (RGB
and depth noise both multiplied; actuation noise and paths unchanged, so the episodes differ only
in their pixels). Per odometer and component: the per-step error as used (mean |error| x 1e-2 of
dx m, dz m, dyaw rad; failed steps scored with the action prior that replaced them), the failure
share, and the growth factor error(level) / error(1).

    python -m studies.noise_robustness --out reports/noise-robustness            # 20 x 100 steps

Resumable: each (level, odometer) result is written to ``results.json`` as it finishes and not run
again (unless a learned odometer's model file changed: each row records its digest); the table
(``table.md``) and figure (``growth.png``) are redrawn from it at the end. ``--redraw`` (with the
command's other options) redraws them from ``results.json`` alone, computing nothing.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from odolab.api import (
    ComparisonConfig,
    Execution,
    NoiseConfig,
    load_odometer,
    run_comparison,
    write_bytes_atomic,
    write_json_atomic,
)
from odolab.io.inputs import read_input_json
from odolab.io.owned import UnsafeOutputError, check_owned_path, owned_path

COMPONENTS = ("dx", "dz", "dyaw")
DEFAULT_ODOMETERS = "action-prior,feature-essential,icp,open3d-rgbd,robust-vo,deepvo"


def _weights(odometers: list[str], options: dict) -> dict[str, str | None]:
    """Name -> ``Odometer.identity_digest``: the digest of its model file or settings, else None."""
    loaded = {n: load_odometer(n, **options.get(n, {})) for n in odometers}
    return {n: o.identity_digest for n, o in loaded.items()}


ROW_KEYS = ("level", "odometer", "steps", *COMPONENTS, *(f"{c}_own" for c in COMPONENTS), "failure_share", "ate_m")


def _size(value: object) -> bool:
    """A finite number >= 0 (not a bool, not an integer too large for a float)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(value) and value >= 0
    except OverflowError:  # an integer of hundreds of digits
        return False


def _whole(row: object) -> bool:
    """A saved row with every number the table needs (finite where a run always gives a number: an
    odometer whose every step failed has no own error, NaN, and is written as null); errors, counts
    and shares are never negative, a share never above 1."""
    if not isinstance(row, dict):
        return False
    need = [k for k in ROW_KEYS if k != "odometer" and not k.endswith("_own")]
    return (
        all(_size(row.get(k)) for k in need)
        and row["failure_share"] <= 1
        and all(row.get(k) is None or _size(row.get(k)) for k in ROW_KEYS if k.endswith("_own"))
    )


def _settings(config: object) -> str:
    """A results file's settings as the options that set them: "--episodes 20 --max-steps 100"
    (the split and seed are fixed by the study, named only when a file differs in them)."""
    if not isinstance(config, dict):
        return "unknown settings"
    said = [f"--{k.replace('_', '-')} {config.get(k)}" for k in ("episodes", "max_steps")]
    said += [f"{k} {config.get(k)}" for k in ("split", "seed") if config.get(k) != {"split": "test", "seed": 0}[k]]
    return " ".join(said)


def run_study(
    out: Path,
    odometers: list[str],
    levels: list[float],
    episodes: int,
    max_steps: int,
    options: dict | None = None,
    execution: Execution = Execution(),
    weights: dict[str, str | None] | None = None,
) -> dict:
    """Run what ``out/results.json`` lacks; returns ``{"config": ..., "results": {"<level>/<odometer>": row}}``."""
    path = out / "results.json"
    config = {"episodes": episodes, "max_steps": max_steps, "split": "test", "seed": 0}
    doc = json.loads(path.read_text()) if path.exists() else {"config": config, "results": {}}
    if doc.get("config") != config:
        raise ValueError(
            f"{path} was made with {_settings(doc.get('config'))}, not {_settings(config)}; choose another --out"
        )
    weights = weights if weights is not None else _weights(odometers, options or {})
    for level in sorted({1.0, *levels}):
        for name in odometers:
            key = f"{level:g}/{name}"
            done = doc["results"].get(key)
            if _whole(done) and done.get("weights") == weights[name]:
                continue  # done with these weights (a retrained model's rows, or damaged ones, are run again)
            result = run_comparison(
                ComparisonConfig(
                    odometers=[name],
                    options={name: (options or {}).get(name, {})},
                    episodes=episodes,
                    max_steps=max_steps,
                    noise=NoiseConfig(rgb=level, depth=level),
                    execution=execution,
                )
            )
            row = next(r for r in result.rows if r.odometer == name)
            doc["results"][key] = {
                "level": level,
                "odometer": name,
                "steps": row.steps,
                **{c: getattr(row, c) for c in COMPONENTS},
                **{f"{c}_own": getattr(row, f"{c}_own") for c in COMPONENTS},
                "failure_share": row.failure_share,
                "ate_m": row.ate_m,
                "weights": weights[name],
            }
            write_json_atomic(owned_path(out, "results.json"), doc)  # NaN (no own error) as null; never through a link
            if execution.progress:
                print(
                    f"level {level:g} {name}: " + ", ".join(f"{c} {getattr(row, c):.2f}" for c in COMPONENTS),
                    flush=True,
                )
    return doc


def redraw_results(out: Path, odometers: list[str], levels: list[float], episodes: int, max_steps: int) -> dict:
    """``out/results.json`` for ``--redraw``: made with these settings, with a whole row of every
    odometer at every level (else ``ValueError`` naming what is missing); nothing is computed."""
    path = out / "results.json"
    doc = json.loads(path.read_text(encoding="utf-8"))
    config = {"episodes": episodes, "max_steps": max_steps, "split": "test", "seed": 0}
    if doc.get("config") != config:
        raise ValueError(
            f"{path} was made with {_settings(doc.get('config'))}, not {_settings(config)}; "
            "give its settings with --redraw"
        )
    missing = [
        f"{level:g}/{name}"
        for level in sorted({1.0, *levels})
        for name in odometers
        if not _whole(doc["results"].get(f"{level:g}/{name}"))
    ]
    if missing:
        raise ValueError(
            f"--redraw: {path} has no result for {', '.join(missing[:4])}"
            f"{' ...' if len(missing) > 4 else ''}; run without --redraw to compute them"
        )
    return doc


def growth_table(doc: dict, odometers: list[str], levels: list[float]) -> str:
    """Markdown: per odometer, errors at level 1 and each level, growth factors, failure shares."""
    res = doc["results"]
    lines = [
        "| odometer | noise | dx | dz | dyaw | growth dx | growth dz | growth dyaw | failed steps | ATE m |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name in odometers:
        base = res.get(f"1/{name}")
        for level in sorted({1.0, *levels}):
            r = res.get(f"{level:g}/{name}")
            if r is None or base is None:
                continue
            growth = [r[c] / base[c] if base[c] > 0 else float("nan") for c in COMPONENTS]
            lines.append(
                f"| {name} | x{level:g} | "
                + " | ".join(f"{r[c]:.2f}" for c in COMPONENTS)
                + " | "
                + " | ".join(f"{g:.2f}" for g in growth)
                + f" | {100 * r['failure_share']:.0f}% | {r['ate_m']:.3f} |"
            )
    return "\n".join(lines) + "\n"


def growth_label(base: float, value: float) -> str:
    """The change from ``base`` to ``value`` in percent: one decimal below 10 %, whole percent
    above ("+4.6 %", "-2.0 %", "+35 %", "0.0 %"); empty when ``base`` is not positive."""
    if not base > 0:
        return ""
    change = 100.0 * (value / base - 1.0)
    if abs(change) < 0.05:
        return "0.0 %"
    return f"{change:+.1f} %" if abs(change) < 9.95 else f"{change:+.0f} %"


def growth_figure(doc: dict, odometers: list[str], level: float, path: Path) -> None:
    """Grouped bars: per component, each odometer's error at noise x1 (light) and x``level`` (dark)."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    res = doc["results"]
    names = [n for n in odometers if f"1/{n}" in res and f"{level:g}/{n}" in res]
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.2), constrained_layout=True)
    width = 0.38
    for ax, comp, unit in zip(axes, COMPONENTS, ("lateral dx, m", "forward dz, m", "yaw, rad")):
        x = np.arange(len(names))
        lo = [res[f"1/{n}"][comp] for n in names]
        hi = [res[f"{level:g}/{n}"][comp] for n in names]
        ax.bar(x - width / 2, lo, width, color="C0", alpha=0.45, label="sensor noise x1")
        ax.bar(x + width / 2, hi, width, color="C0", label=f"sensor noise x{level:g}")
        for xi, a, b in zip(x, lo, hi):
            ax.text(xi + width / 2, b, growth_label(a, b), ha="center", va="bottom", fontsize=8)
        ax.set_ylim(0, 1.12 * max([*lo, *hi, 1e-9]))  # room for the labels
        ax.set_xticks(x, names, rotation=25, ha="right", fontsize=8)
        ax.set_ylabel(f"mean |error| x 1e-2 ({unit})")
        ax.set_title(f"{comp}: per-step error as used (label: change at x{level:g})", fontsize=10)
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend(fontsize=8)
    n = doc["config"]["episodes"]
    fig.suptitle(
        f"Per-step error at sensor noise x1 and x{level:g} (RGB sigma and Redwood depth noise; "
        f"{n} test episode{'s' if n != 1 else ''} x {doc['config']['max_steps']} steps)",
        fontsize=10,
    )
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    plt.close(fig)
    write_bytes_atomic(path, buffer.getvalue())


def main(argv: list[str] | None = None) -> int:
    from odolab.cli import ArgumentParser, UsageError, check_report_dir, execution_of, number, path_arg
    from odolab.comparison import ComparisonError, odometer_names
    from odolab.odometer import parse_odometer_list

    ap = ArgumentParser(prog="python -m studies.noise_robustness", description=__doc__.split("\n")[0])
    ap.add_argument(
        "--out",
        type=path_arg("--out"),
        default=Path("reports/noise-robustness"),
        help="results.json, table.md, growth.png (default reports/noise-robustness)",
    )
    ap.add_argument("--odometers", default=DEFAULT_ODOMETERS, help=f"comma-separated (default {DEFAULT_ODOMETERS})")
    ap.add_argument("--levels", default="2", help="sensor-noise multipliers in [0, 10] besides 1 (default 2)")
    ap.add_argument(
        "--episodes", type=number("--episodes", int, 1, 1000), default=20, help="test episodes (default 20)"
    )
    ap.add_argument(
        "--max-steps", type=number("--max-steps", int, 1, 500), default=100, help="steps each (default 100)"
    )
    ap.add_argument("--serial", action="store_true", help="generate episodes in this process, without Ray")
    ap.add_argument(
        "--quiet", action="store_true", help="no progress bars or per-row lines (the table is still printed)"
    )
    ap.add_argument(
        "--redraw",
        action="store_true",
        help="rebuild table.md and the figures from --out's results.json of the same settings, computing nothing",
    )
    args = ap.parse_args(argv)
    parse_level = number("--levels", float, 0.0, 10.0)
    try:
        # one level per printed key ("2" and "2.0000001" are both "2/..."); -0 is 0
        levels = {}
        for value in (parse_level(v) + 0.0 for v in args.levels.split(",")):
            levels.setdefault(f"{value:g}", value)
        levels = list(levels.values())
    except argparse.ArgumentTypeError as exc:
        raise UsageError(f"{exc} (in --levels {args.levels!r}: comma-separated numbers)") from None
    others = [v for v in levels if v != 1.0]
    if not others:
        raise UsageError(
            f"--levels {args.levels!r}: name at least one multiplier besides 1 (1 is the base "
            "every growth factor divides by, and is always run)"
        )
    if args.redraw and not (args.out / "results.json").is_file():
        raise UsageError(f"--redraw: {args.out / 'results.json'}: no such results file; run the study first")
    try:
        odometers = odometer_names(parse_odometer_list(args.odometers))
        weights = {} if args.redraw else _weights(odometers, {})  # "module:Class" names load here, before any episode
    except (ValueError, KeyError, TypeError, ImportError, ComparisonError) as exc:
        raise UsageError(f"--odometers: {exc.args[0] if isinstance(exc, KeyError) and exc.args else exc}") from None
    check_report_dir(args.out, "--out", manifest="results.json")
    figures = {level: "growth.png" if level == others[-1] else f"growth-x{level:g}.png" for level in others}
    try:  # found now, not after the whole run
        for name in ("results.json", "table.md", *figures.values()):
            check_owned_path(args.out, name)
    except UnsafeOutputError as exc:
        raise UsageError(f"--out: {exc}; remove it or choose another --out") from None
    results = args.out / "results.json"
    if results.exists():
        try:  # a regular file of a sane size, JSON nested a sane depth: else one line, not a traceback
            doc = read_input_json(results, "results file of this study")
        except ValueError as exc:
            raise UsageError(f"{exc}; delete it or choose another --out") from None
        if not (isinstance(doc, dict) and isinstance(doc.get("results"), dict)):
            raise UsageError(f"{results}: not a results file of this study; delete it or choose another --out")
    try:
        if args.redraw:
            doc = redraw_results(args.out, odometers, levels, args.episodes, args.max_steps)
        else:
            doc = run_study(
                args.out,
                odometers,
                levels,
                args.episodes,
                args.max_steps,
                execution=execution_of(args),
                weights=weights,
            )
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    table = growth_table(doc, odometers, levels)
    write_bytes_atomic(owned_path(args.out, "table.md"), table.encode())
    for level in others:  # the last one named is growth.png, any others growth-x<level>.png
        growth_figure(doc, odometers, level, owned_path(args.out, figures[level]))
    print(table)
    return 0


if __name__ == "__main__":
    from odolab.cli import run_cli

    sys.exit(run_cli(main, "python -m studies.noise_robustness"))
