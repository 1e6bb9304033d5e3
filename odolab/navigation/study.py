"""Navigation over many episodes and odometers: one Ray task per (odometer, episode), each result
saved as it finishes (a rerun does only what is missing), then the tables and figures.

Files under the output folder: ``config.json`` (what the results were made with; another config is
refused), ``episodes/<odometer>/<episode>.json`` (one run each, with its paths), ``episodes.csv``,
``nav.csv`` (per odometer: success, SPL, SoftSPL, final geodesic distance and final belief error,
each with its 95 % interval), ``metrics.png`` (bars with intervals), ``belief.png`` (success against
the final belief error) and ``paths-<episode>.png`` (top-down: the scene, start, goal, each
odometer's true path and, dashed, where it believed it was).
"""
from __future__ import annotations

import csv
import dataclasses
import hashlib
import html
import io
import json
import re
import reprlib
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from odolab.episodes import EpisodeSpec
from odolab.io.atomic import save_figure_atomic, write_text_atomic
from odolab.io.inputs import read_input_json
from odolab.navigation.agent import PolicyConfig
from odolab.navigation.metrics import EpisodeOutcome, mean_ci

METRICS = ("success", "spl", "soft_spl", "d_end", "belief_error")
UNBOUNDED = {"d_end", "belief_error"}  # metres: their intervals are clipped at 0 only


@dataclass(frozen=True)
class NavTask:
    """One closed-loop episode to run: odometer name and constructor options, episode, policy."""

    odometer: str
    options: dict
    spec: EpisodeSpec
    policy: PolicyConfig
    weights: str | None = None  # Odometer.weights: a retrained model's or changed setting's episodes rerun


def run_task(task: NavTask) -> dict[str, Any]:
    """Run one task (in a Ray worker or here): a plain-data row with the outcome and the paths."""
    from odolab.navigation.episode import navigate
    from odolab.odometer import load_odometer

    run = navigate(task.spec, load_odometer(task.odometer, **task.options), task.policy)
    o = run.outcome
    return {"odometer": task.odometer, "episode": task.spec.index, "split": task.spec.split, "seed": task.spec.seed,
            "d0": o.d0, "d_end": o.d_end, "path": o.path, "stopped": o.stopped, "steps": o.steps,
            "collisions": o.collisions, "success": o.success, "spl": o.spl, "soft_spl": o.soft_spl,
            "failed_steps": run.failed_steps, "weights": task.weights, "goal": list(run.goal), "true_xy": run.true_xy.round(4).tolist(),
            "believed_xy": run.believed_xy.round(4).tolist()}


def _safe(name: str) -> str:
    """A folder name for an odometer name; names that differ only in other characters (a space in
    ``fused(a, b)``) still get different folders (a short hash of the exact name is appended)."""
    clean = re.sub(r"[^A-Za-z0-9_.-]", "_", name)
    return clean if clean == name else f"{clean}-{hashlib.sha1(name.encode()).hexdigest()[:8]}"


ROW_KEYS = ("odometer", "episode", "split", "seed", "d0", "d_end", "path", "stopped", "steps", "collisions", "success",
            "spl", "soft_spl", "failed_steps", "goal", "true_xy", "believed_xy")


def _number(v: Any, low: float = -np.inf, high: float = np.inf) -> bool:
    """A finite int or float in [low, high] (NaN and infinities fail)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and bool(np.isfinite(v)) and low <= v <= high


def _path(v: Any) -> bool:
    """(x, y) rows of finite JSON numbers (not text, not bools), no step longer than the runner's
    bound on a step (:data:`odolab.runner.MAX_STEP_TRANSLATION`)."""
    from odolab.runner import MAX_STEP_TRANSLATION

    if not isinstance(v, list) or not v or not all(isinstance(p, list) and len(p) == 2 and all(map(_number, p))
                                                   for p in v):
        return False
    a = np.asarray(v, np.float64)
    return bool(np.isfinite(a).all()) and (len(a) < 2 or float(np.abs(np.diff(a, axis=0)).max()) <= MAX_STEP_TRANSLATION)


def _sane(row: dict) -> bool:
    """Values a real run can have: success 0/1, stopped a bool, SPL and SoftSPL in [0, 1], distances >= 0
    (d_end may be inf off the navigable space), counts >= 0, paths as finite (x, y) rows, one more than
    the steps, the believed one starting on the true start."""
    return (row["success"] in (0, 1) and not isinstance(row["success"], bool) and isinstance(row["stopped"], bool)
            and _number(row["spl"], 0, 1) and _number(row["soft_spl"], 0, 1)
            and (_number(row["d_end"], 0) or row["d_end"] == np.inf) and _number(row["d0"], 0) and _number(row["path"], 0)
            and all(isinstance(row[k], int) and not isinstance(row[k], bool) and row[k] >= 0
                    for k in ("steps", "collisions", "failed_steps"))
            and _path(row["true_xy"]) and _path(row["believed_xy"]) and len(row["true_xy"]) == row["steps"] + 1
            and len(row["believed_xy"]) == len(row["true_xy"]) and row["believed_xy"][0] == row["true_xy"][0]
            and _path([row["goal"]]))


def _same(value: Any, want: int) -> bool:
    """``value`` is the int ``want`` (not ``true`` for 1, not ``1.0``)."""
    return type(value) is int and value == want


def read_row(path: Path, task: NavTask, rejected: list[Path] | None = None) -> dict | None:
    """A saved result if it is whole and belongs to ``task``; None if it is missing or damaged, so
    that the episode is run again (a damaged file is appended to ``rejected``, for the caller's note)."""
    if path.is_symlink():  # navigate writes no links; writing the rerun's result would go through it
        raise ValueError(f"{path} is a symbolic link where an episode's result file belongs; delete it or choose "
                         "another --out")
    if not path.exists():
        return None
    if path.is_dir():  # a note and a rerun would end in "Is a directory" when the result is written
        raise ValueError(f"{path} is a folder where an episode's result file belongs; delete it or choose another --out")
    if not path.is_file():  # a pipe or device (or a link to one): the rerun's result could not replace it
        raise ValueError(f"{path} is not a regular file (a pipe, device or link to one) where an episode's result "
                         "file belongs; delete it or choose another --out")
    try:
        row = read_input_json(path, "navigation result")  # size-capped, duplicate keys refused
        ok = (isinstance(row, dict) and all(k in row for k in ROW_KEYS) and row["odometer"] == task.odometer
              and _same(row["episode"], task.spec.index) and row["split"] == task.spec.split
              and _same(row["seed"], task.spec.seed) and row.get("weights") == task.weights and _sane(row))
    except ValueError:  # damaged, not a regular file, too large, or numbers too long to read
        ok = False
    if not ok:
        if rejected is not None:
            rejected.append(path)
        return None
    return row


def _episode_changes(saved: Any, episodes: list[dict]) -> list[str]:
    """Which command-line settings make ``episodes`` differ from a folder's saved ones."""
    if saved == episodes:
        return []
    if not isinstance(saved, list) or not saved or not all(isinstance(e, dict) for e in saved):
        return ["the episodes"]
    said = [f"--episodes ({len(saved)} there, {len(episodes)} now)"] if len(saved) != len(episodes) else []
    for key, option in (("seed", "--seed"), ("split", "--split"), ("max_steps", "--max-steps")):
        if saved[0].get(key) != episodes[0].get(key):
            said.append(f"{option} ({saved[0].get(key)} there, {episodes[0].get(key)} now)")
    return said or ["the episodes' noise or camera"]


def _policy_changes(saved: Any, policy: dict) -> list[str]:
    """Which ``--policy`` parameters make ``policy`` differ from a folder's saved one."""
    if saved == policy:
        return []
    if not isinstance(saved, dict):
        return ["the policy"]
    def said(k: str) -> str:
        there = f"{saved[k]} there" if k in saved else "not recorded there: that folder predates this parameter"
        now = f"{policy[k]} now" if k in policy else "no such parameter now"
        return f"--policy {k} ({there}, {now})"

    return [said(k) for k in sorted(set(saved) | set(policy)) if saved.get(k) != policy.get(k)] or ["the policy"]


def _option_changes(odometer: str, saved: Any, options: dict) -> str:
    """Which ``--odometer-option`` values of ``odometer`` differ from a folder's saved ones."""
    if not isinstance(saved, dict):
        return f"options of {odometer}"
    short = reprlib.Repr()
    short.maxstring, short.maxlist = 40, 6
    keys = sorted(k for k in set(saved) | set(options) if saved.get(k) != options.get(k))
    said = ", ".join(f"{k}: {short.repr(saved[k]) if k in saved else 'default'} there, "
                     f"{short.repr(options[k]) if k in options else 'default'} now" for k in keys[:3])
    return f"options of {odometer} ({said}{', ...' if len(keys) > 3 else ''})"


def result_path(out: Path, odometer: str, index: int) -> Path:
    return out / "episodes" / _safe(odometer) / f"{index:04d}.json"


def run_navigation(out: Path, tasks: list[NavTask], config: dict, *, ray_address: str | None = None,
                   parallel: bool = True, progress: bool = True) -> list[dict]:
    """Run the tasks whose results ``out`` lacks; returns every task's row, in task order."""
    from odolab.parallel import fan_out

    out.mkdir(parents=True, exist_ok=True)
    cfg_path = out / "config.json"
    if not cfg_path.exists() and any(out.iterdir()):
        raise ValueError(f"{out} holds files that odolab navigate did not write (no config.json); choose an empty "
                         "or new --out")
    if cfg_path.exists():
        try:
            saved = read_input_json(cfg_path, "navigation config")  # its errors name the file
        except ValueError as exc:
            raise ValueError(f"{exc}; choose another --out") from None
        problem = ("not a JSON object" if not isinstance(saved, dict) else
                   "its 'options' is not a JSON object" if not isinstance(saved.get("options", {}), dict) else None)
        if problem:
            raise ValueError(f"{cfg_path}: not a navigation config ({problem}); choose another --out")
        changed = _episode_changes(saved.get("episodes"), config["episodes"])
        changed += _policy_changes(saved.get("policy"), config.get("policy"))
        changed += [_option_changes(n, saved["options"][n], o) for n, o in config["options"].items()
                    if n in saved.get("options", {}) and saved["options"][n] != o]
        if changed:
            raise ValueError(f"{out} holds navigation results made with other settings ({', '.join(changed)}); "
                             "choose another --out or delete it")
        config = {**config, "options": {**saved.get("options", {}), **config["options"]}}
    for folder in {result_path(out, t.odometer, t.spec.index).parent for t in tasks}:
        for p in (folder.parent, folder):  # checked before any episode runs, not when its result is written
            if p.exists() and not p.is_dir():
                raise ValueError(f"{p} is a file where navigate keeps a folder of episode results; delete it or "
                                 "choose another --out")
    write_text_atomic(cfg_path, json.dumps(config, indent=1) + "\n")
    rejected: list[Path] = []
    todo = [t for t in tasks if read_row(result_path(out, t.odometer, t.spec.index), t, rejected) is None]
    for folder in sorted({p.parent for p in rejected}):  # one line per odometer, not one per episode
        names = sorted(p.name for p in rejected if p.parent == folder)
        print(f"note: {len(names)} saved episode(s) in {folder} ({names[0]}{' ...' if len(names) > 1 else ''}) are damaged "
              "or belong to another run, model file, calibration or setting; running them again", file=sys.stderr)

    def done(k: int, row: dict) -> None:
        p = result_path(out, todo[k].odometer, todo[k].spec.index)
        p.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(p, json.dumps(row) + "\n")

    fan_out(run_task, todo, on_result=done, parallel=parallel, ray_address=ray_address, progress=progress,
            desc="navigation episodes")
    return [json.loads(result_path(out, t.odometer, t.spec.index).read_text(encoding="utf-8")) for t in tasks]


def belief_error(row: dict) -> float:
    """How far the agent's belief is from the truth when the episode ends: the distance (m, world
    frame) between its true and its believed final position, the odometry's closed-loop drift (the
    believed path starts on the true start, so this is the error the odometer accumulated)."""
    return float(np.hypot(*(np.asarray(row["true_xy"][-1], np.float64) - np.asarray(row["believed_xy"][-1], np.float64))))


def summarize(rows: list[dict], odometers: list[str]) -> list[dict]:
    """Per odometer: each metric's mean and 95 % interval (``belief_error`` included: rows without it
    get it from their paths), steps, collisions and failed steps."""
    rows = [r if "belief_error" in r else {**r, "belief_error": belief_error(r)} for r in rows]
    table = []
    for name in odometers:
        mine = [r for r in rows if r["odometer"] == name]
        entry: dict[str, Any] = {"odometer": name, "episodes": len(mine)}
        for m in METRICS:
            ci = mean_ci(np.array([r[m] for r in mine], np.float64), binary=m == "success")
            top = np.inf if m in UNBOUNDED else 1.0  # the interval stays where the metric can be
            entry.update({m: ci.mean, f"{m}_low": float(np.clip(ci.low, 0.0, top)),
                          f"{m}_high": float(np.clip(ci.high, 0.0, top))})
        entry["steps"] = float(np.mean([r["steps"] for r in mine])) if mine else float("nan")
        entry["collisions"] = float(np.mean([r["collisions"] for r in mine])) if mine else float("nan")
        entry["failed_steps"] = int(sum(r["failed_steps"] for r in mine))
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
    ax.legend(fontsize=8, loc="upper right", ncol=3, frameon=True)
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
        ax.errorbar(x, y, xerr=xerr, yerr=yerr, fmt="o", color=cmap(k % 10), capsize=3, label=r["odometer"])
    ax.set_xscale("log")
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel("final belief error: |true - believed position| at the end\n(m, mean, log scale; below 0.01 m drawn at 0.01)")
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

    from odolab.episodes import start_environment

    env, begin = start_environment(spec, sensors=False)
    scene = env.scene
    runs = [(name, next((r for r in rows if r["odometer"] == name and r["episode"] == spec.index), None))
            for name in odometers]
    runs = [(name, r) for name, r in runs if r is not None] or [("no odometer", None)]
    pts = [np.array([[begin.start.x, begin.start.y], begin.goal])]
    pts += [np.array(r[k]) for _, r in runs if r is not None for k in ("true_xy", "believed_xy")]
    allp = np.concatenate(pts)
    centre, half = (allp.min(0) + allp.max(0)) / 2, np.ptp(allp, axis=0).max() / 2 + 1.0
    cols = min(3, len(runs))
    rows_n = -(-len(runs) // cols)
    fig, axes = plt.subplots(rows_n, cols, figsize=(3.6 * cols, 3.6 * rows_n + 0.9), squeeze=False,
                             sharex=True, sharey=True)
    h, w = scene.navigable.shape
    extent = (scene.origin[0], scene.origin[0] + w * scene.resolution, scene.origin[1],
              scene.origin[1] + h * scene.resolution)
    for ax, (name, row) in zip(axes.flat, runs):
        ax.imshow(np.where(scene.navigable, 1.0, 0.75), cmap="gray", vmin=0, vmax=1, origin="lower",
                  interpolation="nearest", extent=extent)
        verdict = ""
        if row is not None:
            true, belief = np.array(row["true_xy"]), np.array(row["believed_xy"])
            ax.plot(true[:, 0], true[:, 1], "-", color="tab:blue", lw=1.4, label="true path")
            ax.plot(belief[:, 0], belief[:, 1], "--", color="tab:orange", lw=1.1, label="believed path")
            verdict = ("success" if row["success"] else ("stopped" if row["stopped"] else "no stop")) + \
                f", {row['steps']} steps"
        ax.plot(begin.start.x, begin.start.y, "ko", ms=6, label="start")
        ax.plot(*begin.goal, "r*", ms=11, label="goal")
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_aspect("equal", adjustable="box")
        label = name if len(name) <= 34 else name[:31] + "..."
        ax.set_title(f"{label}\n{verdict}", fontsize=8)
    for ax in axes.flat[len(runs):]:
        ax.axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("world x (m)")
    for ax in axes[:, 0]:
        ax.set_ylabel("world y (m)")
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.suptitle(f"{spec.split} episode {spec.index}: geodesic start distance {begin.start_distance:.1f} m", fontsize=10)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    save_figure_atomic(fig, path)
    plt.close(fig)


def write_outputs(out: Path, rows: list[dict], odometers: list[str], specs: list[EpisodeSpec], command: str,
                  sample_episodes: int = 2) -> list[dict]:
    """Tables, figures and ``report.html`` under ``out``; returns the per-odometer table."""
    rows = [{**r, "belief_error": belief_error(r)} for r in rows]
    table = summarize(rows, odometers)
    keys = ["odometer", "episodes"] + [f"{m}{s}" for m in METRICS for s in ("", "_low", "_high")] + [
        "steps", "collisions", "failed_steps"]
    write_text_atomic(out / "nav.csv", _csv(table, keys))
    ep_keys = ["odometer", "episode", "split", "seed", "d0", "d_end", "path", "stopped", "steps", "collisions",
               "success", "spl", "soft_spl", "failed_steps", "belief_error"]
    write_text_atomic(out / "episodes.csv", _csv(rows, ep_keys))
    metrics_figure(table, out / "metrics.png")
    belief_figure(table, out / "belief.png")
    figures = []
    for spec in specs[:sample_episodes]:
        name = f"paths-{spec.index:04d}.png"
        paths_figure(rows, odometers, spec, out / name)
        figures.append(name)
    write_text_atomic(out / "report.html", _html(table, figures, command))
    return table


def _html(table: list[dict], figures: list[str], command: str) -> str:
    def ci(r, m, scale=1.0, digits=2):
        return (f"{scale * r[m]:.{digits}f} [{scale * r[m + '_low']:.{digits}f}, "
                f"{scale * r[m + '_high']:.{digits}f}]")
    head = "<tr>" + "".join(f"<th>{h}</th>" for h in ("odometer", "episodes", "success", "SPL", "SoftSPL",
                                                     "final distance to goal (m)", "final belief error (m)",
                                                     "steps", "collisions", "failed odometer steps")) + "</tr>"
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(str(v))}</td>" for v in (r["odometer"], r["episodes"], ci(r, "success"), ci(r, "spl"),
                                                   ci(r, "soft_spl"), ci(r, "d_end"), ci(r, "belief_error"),
                                                   f"{r['steps']:.0f}",
                                                   f"{r['collisions']:.1f}", r["failed_steps"])) + "</tr>"
        for r in table)
    imgs = "".join(f'<p><img src="{html.escape(f)}" alt="{html.escape(f)}"></p>' for f in ["metrics.png", "belief.png", *figures])
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>odolab navigation</title>"
            "<style>body{font-family:sans-serif;max-width:960px;margin:2em auto}td,th{padding:3px 8px;"
            "border-bottom:1px solid #ccc}img{max-width:100%}</style></head><body>"
            "<h1>PointGoal navigation with each odometer</h1>"
            f"<p><code>{html.escape(command)}</code></p><p>Means with 95 % intervals (Wilson for success, Student t otherwise). "
            "Success: STOP within 0.36 m (geodesic) of the goal; SPL and SoftSPL as habitat-lab defines them. "
            "Final belief error: the distance between the agent's true and believed positions when the episode "
            "ends (the odometry's drift in the closed loop).</p>"
            f"<table>{head}{body}</table>{imgs}</body></html>\n")


def config_doc(odometers: list[str], options: dict, specs: list[EpisodeSpec], policy: PolicyConfig) -> dict:
    """What the results depend on (compared with a folder's ``config.json`` before reuse: the same
    episodes and policy, and the same options for an odometer run before; new odometers may join)."""
    return {"options": {n: options.get(n, {}) for n in odometers}, "episodes": [dataclasses.asdict(s) for s in specs],
            "policy": dataclasses.asdict(policy)}
