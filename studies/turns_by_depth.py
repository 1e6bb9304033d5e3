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
``turns.png``. Serial: a few minutes in one process. Resumable: ``results.json`` is saved after
each scene, and an odometer's pairs are reused when its options and weights (the digest of its
model file or settings) are the saved ones; the split, seed, ``--scenes`` and ``--per-scene`` of a
folder are fixed (another value is refused). ``--redraw`` rebuilds the table and figure from
``results.json`` alone, computing nothing.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

from odolab.api import Odometer, invert, transform_to_planar, wrap_angle, write_bytes_atomic, write_json_atomic
from odolab.io.atomic import save_figure_atomic

#: Bins of the first frame's median depth, m.
BINS = ((0.0, 1.0), (1.0, 2.0), (2.0, 4.0), (4.0, np.inf))
#: The settings every odometer's pairs in one results file share.
SHARED = ("split", "seed", "scenes", "per_scene")
#: What the study writes under --out.
FILES = ("results.json", "table.md", "turns.png")


class ResultsError(ValueError):
    """A results file this study cannot use (not its own, or made with other shared settings)."""


def turn_pairs(split: str, seed: int, scenes: int, per_scene: int, first: int = 0):
    """Yield (scene index, median depth m, action, prev frame, cur frame, true yaw rad) for random
    turns in the scenes of ``split``'s first ``scenes`` episodes, from scene ``first`` on (each
    scene's turns are the same whichever scene the run starts from)."""
    from odolab.episodes import EpisodeSpec, start_environment
    from odolab.sim.agent import AgentState
    from odolab.types import Action

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


def _row_ok(row: object) -> bool:
    """A saved pair: [median depth m, answered, |yaw error| deg or None when not answered]."""

    def number(v: object) -> bool:
        try:  # an integer of hundreds of digits is no float: not a number here
            return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
        except OverflowError:
            return False

    return (
        isinstance(row, list)
        and len(row) == 3
        and number(row[0])
        and row[0] >= 0
        and isinstance(row[1], bool)
        and ((row[1] and number(row[2]) and 0 <= row[2] <= 180) or (not row[1] and row[2] is None))
    )


def read_results(path: Path) -> dict | None:
    """The study's saved ``results.json`` (None when there is none); :class:`ResultsError` naming
    the file when it is not one of this study's."""
    from odolab.io.inputs import read_input_json

    if not path.exists():
        return None
    try:
        doc = read_input_json(path, "turns study results file")
    except ValueError as exc:
        raise ResultsError(f"{exc}; delete it or choose another --out") from None
    cfg = doc.get("config") if isinstance(doc, dict) else None
    if not (
        isinstance(cfg, dict)
        and isinstance(doc.get("pairs"), dict)
        and isinstance(cfg.get("split"), str)
        and all(type(cfg.get(k)) is int for k in SHARED[1:])
        and isinstance(cfg.get("options", {}), dict)
        and isinstance(cfg.get("weights", {}), dict)
    ):
        raise ResultsError(
            f"{path}: not a results file of this study (expected config with {', '.join(SHARED)} and "
            "pairs per odometer); delete it or choose another --out"
        )
    return doc


def _settings(cfg: dict) -> str:
    """Shared settings as the options that set them: "--split val --seed 7 --scenes 20 --per-scene 20"."""
    return " ".join(f"--{k.replace('_', '-')} {cfg.get(k)}" for k in SHARED)


def check_shared(doc: dict, path: Path, split: str, seed: int, scenes: int, per_scene: int) -> None:
    """:class:`ResultsError` unless ``doc`` was made with these shared settings."""
    want = {"split": split, "seed": seed, "scenes": scenes, "per_scene": per_scene}
    if any(doc["config"].get(k) != v for k, v in want.items()):
        raise ResultsError(
            f"{path} was made with {_settings(doc['config'])}, not {_settings(want)}; choose another --out"
        )


def reusable(
    doc: dict, name: str, options: dict, weights: str | None, per_scene: int, total: int
) -> tuple[list, str | None]:
    """The saved pairs of ``name`` that a run with ``options`` and ``weights`` may keep (whole scenes,
    at most ``total``), and why none are kept (None when kept, or when there were none)."""
    rows = doc["pairs"].get(name)
    if rows is None:
        return [], None
    cfg = doc["config"]
    if cfg.get("options", {}).get(name, {}) != options:
        return [], "saved with other options"
    if cfg.get("weights", {}).get(name) != weights:
        return [], "saved with another model file or settings"
    if not isinstance(rows, list) or len(rows) % per_scene or len(rows) > total or not all(map(_row_ok, rows)):
        return [], "damaged saved pairs"
    return rows, None


def run_study(
    loaded: dict[str, Odometer],
    options: dict,
    split: str,
    seed: int,
    scenes: int,
    per_scene: int,
    quiet: bool = False,
    saved: dict | None = None,
    save=None,
) -> dict:
    """Every odometer (name -> loaded with ``options``) on the same turn pairs; returns {"config",
    "pairs": {name: [[median depth m, answered, |yaw error| deg or None]]}}.

    ``saved`` (a :func:`read_results` document of the same shared settings): each odometer's
    pairs in it are kept when its options and weights are the same, and only its missing scenes
    run; other odometers' pairs stay in the document. ``save(doc)`` is called after each scene."""
    from tqdm.auto import tqdm

    from odolab.episodes import EpisodeSpec

    intrinsics = EpisodeSpec().camera.intrinsics  # turn_pairs' episodes use the default camera
    total = scenes * per_scene
    doc = (
        saved
        if saved is not None
        else {
            "config": {
                "split": split,
                "seed": seed,
                "scenes": scenes,
                "per_scene": per_scene,
                "options": {},
                "weights": {},
            },
            "pairs": {},
        }
    )
    cfg = doc["config"]
    cfg["options"], cfg["weights"] = dict(cfg.get("options", {})), dict(cfg.get("weights", {}))
    done: dict[str, int] = {}  # name -> scenes already saved
    for n, o in loaded.items():
        rows, why = reusable(doc, n, options.get(n, {}), o.identity_digest, per_scene, total)
        if why:  # said even when quiet: results are replaced
            print(f"note: {n}: {why}; running its {total} pairs again", file=sys.stderr, flush=True)
        doc["pairs"][n], cfg["options"][n], cfg["weights"][n] = rows, options.get(n, {}), o.identity_digest
        done[n] = len(rows) // per_scene
    first = min(done.values(), default=scenes)
    todo = sum(scenes - d for d in done.values()) * per_scene
    scene = -1
    with tqdm(total=todo, desc="turn pairs", unit="pair", disable=quiet or not todo) as bar:
        for e, depth, action, prev, cur, true_yaw in turn_pairs(split, seed, scenes, per_scene, first):
            if e != scene:  # a new scene: a new sequence for every odometer still to see it
                if scene >= 0 and save is not None:
                    save(doc)
                for n, o in loaded.items():
                    if done[n] <= e:
                        o.reset(intrinsics)
                scene = e
            for n, o in loaded.items():
                if done[n] <= e:
                    doc["pairs"][n].append([depth, *_answer(o, prev, cur, action, true_yaw)])
                    bar.update(1)
    if save is not None:
        save(doc)
    return doc


def selected(doc: dict, names: list[str]) -> dict:
    """``doc`` with the pairs, options and weights of ``names`` only (in that order)."""
    cfg = doc["config"]
    return {
        "config": {
            **cfg,
            "options": {n: cfg.get("options", {}).get(n, {}) for n in names},
            "weights": {n: cfg.get("weights", {}).get(n) for n in names},
        },
        "pairs": {n: doc["pairs"][n] for n in names},
    }


def _answer(odometer: Odometer, prev, cur, action, true_yaw: float) -> tuple[bool, float | None]:
    """(answered, |yaw error| deg or None) of one turn; frames guarded as the runner guards them
    (only oracles see the true poses), a raising odometer fails the pair."""
    from odolab.runner import failure_reason, guarded_frame
    from odolab.threads import odometer_threads

    oracle = bool(getattr(odometer, "oracle", False))
    try:
        with odometer_threads(odometer):
            est = odometer.step(guarded_frame(prev, oracle), guarded_frame(cur, oracle), action)
    except Exception:  # noqa: BLE001 - a failing odometer is a failed step
        return False, None
    if failure_reason(est) is not None:
        return False, None
    return True, float(np.degrees(abs(wrap_angle(transform_to_planar(est.transform)[2] - true_yaw))))


def stats(rows: list, label: str) -> dict:
    """Pairs, failed share, RMS yaw error (deg) and share > 2 deg off of the answered, of ``rows``."""
    errs = np.array([r[2] for r in rows if r[1]], float)
    return {
        "bin": label,
        "pairs": len(rows),
        "failed": 1 - len(errs) / len(rows) if rows else float("nan"),
        "rms_deg": float(np.sqrt(np.mean(errs**2))) if errs.size else float("nan"),
        "over_2deg": float(np.mean(errs > 2.0)) if errs.size else float("nan"),
    }


def bin_stats(rows: list) -> list[dict]:
    """:func:`stats` per depth bin of :data:`BINS`."""
    return [
        stats([r for r in rows if lo <= r[0] < hi], f"{lo:g}-{hi:g} m" if np.isfinite(hi) else f"> {lo:g} m")
        for lo, hi in BINS
    ]


def table(doc: dict) -> str:
    lines = [
        "| odometer | median depth | pairs | failed | yaw RMS deg (answered) | > 2 deg off |",
        "|---|---|---|---|---|---|",
    ]
    for n, rows in doc["pairs"].items():
        for s in bin_stats(rows) + [stats(rows, "all")]:
            failed, rms, off = (
                ("n/a" if np.isnan(v) else f)
                for v, f in (
                    (s["failed"], f"{100 * s['failed']:.1f} %"),
                    (s["rms_deg"], f"{s['rms_deg']:.2f}"),
                    (s["over_2deg"], f"{100 * s['over_2deg']:.1f} %"),
                )
            )
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
    given = "; ".join(
        f"{n} " + ", ".join(f"{k}={v}" for k, v in o.items()) for n, o in cfg.get("options", {}).items() if o
    )
    fig.suptitle(
        f"Turns from random poses: {count(cfg['scenes'], cfg['split'] + ' scene')} x "
        f"{count(cfg['per_scene'], 'turn')}" + (f" (options: {given[:120]})" if given else ""),
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0.05 + 0.04 * rows, 1, 1))
    save_figure_atomic(fig, path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    from odolab.cli import ArgumentParser, UsageError, check_report_dir, number, path_arg, seed
    from odolab.comparison import ComparisonError, load_odometers
    from odolab.io.owned import UnsafeOutputError, check_owned_path, owned_path
    from odolab.odometer import parse_odometer_list
    from odolab.options import OptionError, parse_assignments

    ap = ArgumentParser(prog="python -m studies.turns_by_depth", description=__doc__.split("\n")[0])
    ap.add_argument(
        "--out",
        type=path_arg("--out"),
        default=Path("reports/turns-by-depth"),
        help="results.json, table.md, turns.png (default reports/turns-by-depth)",
    )
    ap.add_argument("--odometers", default="open3d-rgbd", help="comma-separated (default open3d-rgbd)")
    ap.add_argument("--odometer-option", action="append", default=[], metavar="NAME.key=value")
    ap.add_argument("--split", choices=("train", "val", "test"), default="val")
    ap.add_argument("--seed", type=seed(), default=7)
    ap.add_argument("--scenes", type=number("--scenes", int, 1, 1000), default=20)
    ap.add_argument("--per-scene", type=number("--per-scene", int, 1, 1000), default=20)
    ap.add_argument(
        "--redraw",
        action="store_true",
        help="rebuild table.md and turns.png from --out's results.json of the same settings, computing nothing",
    )
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    try:
        options = parse_assignments(args.odometer_option)
        names = parse_odometer_list(args.odometers)
    except (OptionError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    results = args.out / "results.json"
    if args.redraw and not results.is_file():
        raise UsageError(f"--redraw: {results}: no such results file; run the study first")
    loaded = None
    if not args.redraw:
        try:  # bad names and option values fail here, before any pair
            loaded = load_odometers(names, options)
        except (ValueError, KeyError, TypeError, ImportError, ComparisonError) as exc:
            raise UsageError(str(exc.args[0] if isinstance(exc, KeyError) and exc.args else exc)) from None
    check_report_dir(args.out, "--out", manifest="results.json")
    try:
        for name in FILES:  # found now, not after the whole run
            check_owned_path(args.out, name)
        saved = read_results(results)
        if saved is not None:
            check_shared(saved, results, args.split, args.seed, args.scenes, args.per_scene)
    except UnsafeOutputError as exc:
        raise UsageError(f"--out: {exc}; remove it or choose another --out") from None
    except ResultsError as exc:
        raise UsageError(str(exc)) from None
    if args.redraw:
        total = args.scenes * args.per_scene
        for n in names:
            rows = saved["pairs"].get(n)
            if saved["config"].get("options", {}).get(n, {}) != options.get(n, {}):
                raise UsageError(
                    f"--redraw: {results}: {n}'s pairs were computed with other options "
                    f"({saved['config'].get('options', {}).get(n, {})!r}, not {options.get(n, {})!r}); "
                    "give those, or run without --redraw to compute them"
                )
            if not (isinstance(rows, list) and len(rows) == total and all(map(_row_ok, rows))):
                have = sum(map(_row_ok, rows)) if isinstance(rows, list) else 0
                raise UsageError(
                    f"--redraw: {results}: {n} has {have} of {total} pairs; run without --redraw to compute them"
                )
        doc = saved
    else:
        doc = run_study(
            loaded,
            options,
            args.split,
            args.seed,
            args.scenes,
            args.per_scene,
            quiet=args.quiet,
            saved=saved,
            save=lambda d: write_json_atomic(owned_path(args.out, "results.json"), d),
        )
    view = selected(doc, names)
    text = table(view)
    write_bytes_atomic(owned_path(args.out, "table.md"), text.encode())
    figure(view, owned_path(args.out, "turns.png"))
    print(text)
    return 0


if __name__ == "__main__":
    from odolab.cli import run_cli

    raise SystemExit(run_cli(main, "python -m studies.turns_by_depth"))
