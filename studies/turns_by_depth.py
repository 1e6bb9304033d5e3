"""Study: how often each odometer fails a turn, and how far off it is, by how far the view reaches.

Navigation turns the agent in front of walls and in large rooms far more often than the episode
generator's shortest-path follower does, and those turns decide where the agent believes it is.
Here every odometer sees the same turn pairs: in each of ``--scenes`` scenes of ``--split`` (the
scenes of its first episodes, seed ``--seed``), ``--per-scene`` random navigable poses with random
headings, one noisy TURN_LEFT or TURN_RIGHT each (the challenge's actuation, RGB and depth noise).
Pairs are binned by the median depth of the first frame (m). Per odometer and bin: pairs, failed
share (invalid, raising, or not a rigid motion: what the runner would replace by the prior) and,
over the answered pairs, the RMS yaw error and the share more than 2 degrees off.

    python -m studies.turns_by_depth --out reports/turns-by-depth        # 20 scenes x 20 turns, ~1 min per odometer

Writes ``results.json`` (every pair: bin depth, answered, yaw error), ``table.md`` and
``turns.png``. Serial: a few minutes in one process.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from odolab.api import Odometer, invert, transform_to_planar, wrap_angle, write_bytes_atomic, write_json_atomic
from odolab.io.atomic import save_figure_atomic

#: Bins of the first frame's median depth, m.
BINS = ((0.0, 1.0), (1.0, 2.0), (2.0, 4.0), (4.0, np.inf))


def turn_pairs(split: str, seed: int, scenes: int, per_scene: int):
    """Yield (scene index, median depth m, action, prev frame, cur frame, true yaw rad) for random
    turns in the scenes of ``split``'s first ``scenes`` episodes."""
    from odolab.episodes import EpisodeSpec, start_environment
    from odolab.sim.agent import AgentState
    from odolab.types import Action

    for e in range(scenes):
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


def run_study(loaded: dict[str, Odometer], options: dict, split: str, seed: int, scenes: int, per_scene: int,
              quiet: bool = False) -> dict:
    """Every odometer (name -> loaded with ``options``) on the same turn pairs; returns {"config",
    "pairs": {name: [[median depth m, answered, |yaw error| deg or None]]}}."""
    from tqdm.auto import tqdm

    from odolab.episodes import EpisodeSpec

    intrinsics = EpisodeSpec().camera.intrinsics  # turn_pairs' episodes use the default camera
    pairs: dict[str, list] = {n: [] for n in loaded}
    scene = -1
    with tqdm(total=scenes * per_scene, desc="turn pairs", unit="pair", disable=quiet) as bar:
        for e, depth, action, prev, cur, true_yaw in turn_pairs(split, seed, scenes, per_scene):
            if e != scene:  # a new scene: a new sequence for every odometer
                for o in loaded.values():
                    o.reset(intrinsics)
                scene = e
            for n, o in loaded.items():
                pairs[n].append([depth, *_answer(o, prev, cur, action, true_yaw)])
            bar.update(1)
    return {"config": {"split": split, "seed": seed, "scenes": scenes, "per_scene": per_scene,
                       "options": options, "weights": {n: o.weights for n, o in loaded.items()}}, "pairs": pairs}


def _answer(odometer: Odometer, prev, cur, action, true_yaw: float) -> tuple[bool, float | None]:
    """(answered, |yaw error| deg or None) of one turn; frames guarded as the runner guards them
    (only oracles see the true poses), a raising odometer fails the pair."""
    from odolab.runner import failure_reason, guarded_frame
    from odolab.threads import odometer_threads

    oracle = bool(getattr(odometer, "oracle", False))
    try:
        with odometer_threads(odometer):
            est = odometer.step(guarded_frame(prev, oracle), guarded_frame(cur, oracle), action)
    except Exception:
        return False, None
    if failure_reason(est) is not None:
        return False, None
    return True, float(np.degrees(abs(wrap_angle(transform_to_planar(est.transform)[2] - true_yaw))))


def stats(rows: list, label: str) -> dict:
    """Pairs, failed share, RMS yaw error (deg) and share > 2 deg off of the answered, of ``rows``."""
    errs = np.array([r[2] for r in rows if r[1]], float)
    return {"bin": label, "pairs": len(rows), "failed": 1 - len(errs) / len(rows) if rows else float("nan"),
            "rms_deg": float(np.sqrt(np.mean(errs**2))) if errs.size else float("nan"),
            "over_2deg": float(np.mean(errs > 2.0)) if errs.size else float("nan")}


def bin_stats(rows: list) -> list[dict]:
    """:func:`stats` per depth bin of :data:`BINS`."""
    return [stats([r for r in rows if lo <= r[0] < hi], f"{lo:g}-{hi:g} m" if np.isfinite(hi) else f"> {lo:g} m")
            for lo, hi in BINS]


def table(doc: dict) -> str:
    lines = ["| odometer | median depth | pairs | failed | yaw RMS deg (answered) | > 2 deg off |", "|---|---|---|---|---|---|"]
    for n, rows in doc["pairs"].items():
        for s in bin_stats(rows) + [stats(rows, "all")]:
            failed, rms, off = (("n/a" if np.isnan(v) else f) for v, f in (
                (s["failed"], f"{100 * s['failed']:.1f} %"), (s["rms_deg"], f"{s['rms_deg']:.2f}"),
                (s["over_2deg"], f"{100 * s['over_2deg']:.1f} %")))
            lines.append(f"| {n} | {s['bin']} | {s['pairs']} | {failed} | {rms} | {off} |")
    return "\n".join(lines) + "\n"


def figure(doc: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    names = list(doc["pairs"])
    width = 0.8 / max(len(names), 1)
    for k, n in enumerate(names):
        per_bin = bin_stats(doc["pairs"][n])
        x = np.arange(len(per_bin)) + (k - (len(names) - 1) / 2) * width
        a.bar(x, [100 * s["failed"] for s in per_bin], width, label=n)
        b.bar(x, [s["rms_deg"] for s in per_bin], width, label=n)

    def count(k: int, word: str) -> str:
        return f"{k} {word}{'' if k == 1 else 's'}"

    labels = [f"{s['bin']}\n({count(s['pairs'], 'pair')})" for s in bin_stats(doc["pairs"][names[0]])]
    for ax, title in ((a, "failed turns (%)"), (b, "yaw error of answered turns, RMS (deg)")):
        ax.set_xticks(np.arange(len(labels)), labels, fontsize=8)
        ax.set_xlabel("median depth of the first frame (empty bins and bins with no answer: no bar)", fontsize=8)
        ax.set_title(title, fontsize=10)
        ax.set_ylim(bottom=0)
    rows = -(-len(names) // 4)  # at most four names per legend row
    fig.legend(*a.get_legend_handles_labels(), loc="lower center", ncol=min(len(names), 4), fontsize=8, frameon=False)
    cfg = doc["config"]
    given = "; ".join(f"{n} " + ", ".join(f"{k}={v}" for k, v in o.items()) for n, o in cfg.get("options", {}).items() if o)
    fig.suptitle(f"Turns from random poses: {count(cfg['scenes'], cfg['split'] + ' scene')} x "
                 f"{count(cfg['per_scene'], 'turn')}" + (f" (options: {given[:120]})" if given else ""), fontsize=10)
    fig.tight_layout(rect=(0, 0.05 + 0.04 * rows, 1, 1))
    save_figure_atomic(fig, path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    from odolab.cli import ArgumentParser, UsageError, check_report_dir, number, path_arg, seed
    from odolab.comparison import ComparisonError, load_odometers
    from odolab.odometer import parse_odometer_list
    from odolab.options import OptionError, parse_assignments

    ap = ArgumentParser(prog="python -m studies.turns_by_depth", description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=path_arg("--out"), default=Path("reports/turns-by-depth"),
                    help="results.json, table.md, turns.png (default reports/turns-by-depth)")
    ap.add_argument("--odometers", default="open3d-rgbd", help="comma-separated (default open3d-rgbd)")
    ap.add_argument("--odometer-option", action="append", default=[], metavar="NAME.key=value")
    ap.add_argument("--split", choices=("train", "val", "test"), default="val")
    ap.add_argument("--seed", type=seed(), default=7)
    ap.add_argument("--scenes", type=number("--scenes", int, 1, 1000), default=20)
    ap.add_argument("--per-scene", type=number("--per-scene", int, 1, 1000), default=20)
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    try:
        options = parse_assignments(args.odometer_option)
    except OptionError as exc:
        raise UsageError(str(exc)) from None
    try:  # bad names and option values fail here, before any pair
        loaded = load_odometers(parse_odometer_list(args.odometers), options)
    except (ValueError, KeyError, TypeError, ImportError, ComparisonError) as exc:
        raise UsageError(str(exc.args[0] if isinstance(exc, KeyError) and exc.args else exc)) from None
    check_report_dir(args.out, "--out", manifest="results.json")
    for name in ("results.json", "table.md", "turns.png"):  # found now, not after the whole run
        if (args.out / name).is_dir():
            raise UsageError(f"--out {args.out}: {name} is a folder; remove it or choose another --out")
    doc = run_study(loaded, options, args.split, args.seed, args.scenes, args.per_scene, quiet=args.quiet)
    write_json_atomic(args.out / "results.json", doc)
    text = table(doc)
    write_bytes_atomic(args.out / "table.md", text.encode())
    figure(doc, args.out / "turns.png")
    print(text)
    return 0


if __name__ == "__main__":
    from odolab.cli import run_cli

    raise SystemExit(run_cli(main, "python -m studies.turns_by_depth"))
