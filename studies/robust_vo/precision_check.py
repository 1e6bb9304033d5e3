"""Does bf16 autocast cost accuracy? The same short recipe trained in fp32 and in bf16, each with two
seeds, on the same data; validation errors side by side, with the seed-to-seed spread as the noise.

    python -m studies.robust_vo.precision_check [--out reports/robust-vo/precision] [--seeds 0 1]

The recipe is the shipped one (170 x 96, row 18 + warp + mirror_turns) cut short: 100 train episodes
(about 7,000 pairs), 16 val episodes, 3 forward epochs and 2 turn epochs (DataAug), about 24,000
samples per run. Every run is saved under
``runs/robust-vo/precision/`` and resumes; the tables go to ``--out``: ``runs.csv`` (one row per
precision, seed, action and component) and ``comparison.md``.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import platform
from pathlib import Path

import numpy as np
import torch

from odolab.config import SEED_RANGE, check, setting
from odolab.io.atomic import write_text_atomic
from odolab.learned.robust_vo import train as trainer
from odolab.learned.robust_vo.config import StageConfig, TrainConfig, load_train_config
from odolab.learned.training import ComputeConfig

ROOT = Path(__file__).resolve().parents[2]
PRECISIONS = ("fp32", "bf16")


@dataclasses.dataclass(frozen=True)
class CheckSettings:
    """The check's training ``seeds``: at least two different ones (their spread is the noise)."""

    seeds: tuple[int, ...] = setting((0, 1), range=SEED_RANGE, min_items=2, distinct=True, doc="training seeds")

    def __post_init__(self) -> None:
        check(self)


def short_recipe(seed: int, precision: str) -> TrainConfig:
    """The shipped recipe cut short (module docstring), at ``seed`` in ``precision``."""
    base = load_train_config(str(ROOT / "studies" / "robust_vo" / "shipped.toml"))
    stages = (
        StageConfig("forward", ("move_forward",), 3, lr=5e-4, batch=32),
        StageConfig("turns", ("turn_left", "turn_right"), 2, lr=5e-4, batch=32, data_aug=True),
    )
    return dataclasses.replace(
        base,
        stages=stages,
        seed=seed,
        val_pairs=1000,
        train_data=dataclasses.replace(base.train_data, episodes=100),
        val_data=dataclasses.replace(base.val_data, episodes=16),
        compute=ComputeConfig(precision=precision, loader_workers=1),
    )


def last_val_rows(reports: Path) -> list[dict]:
    """The last epoch's validation rows of each stage (``curves.csv``)."""
    with open(reports / "curves.csv", encoding="utf-8") as f:
        rows = [r for r in csv.DictReader(f) if r["split"] == "val"]
    last: dict[str, int] = {}
    for r in rows:
        last[r["stage"]] = max(last.get(r["stage"], 0), int(r["epoch"]))
    return [r for r in rows if int(r["epoch"]) == last[r["stage"]]]


def run(args) -> int:
    """The study as its command line (:mod:`odolab.cli.study`) asks."""
    from odolab.cli import UsageError, check_report_dir
    from odolab.cli.args import check_folder_path

    try:
        CheckSettings(tuple(args.seeds))  # at least two, none twice: their spread is the noise
    except ValueError as exc:
        raise UsageError(f"--{exc}") from None
    check_folder_path(args.work, "--work")  # both found fit before hours of training, not after
    check_report_dir(args.out, "--out", manifest="runs.csv")
    table: list[dict] = []
    speed: list[str] = []
    for precision in PRECISIONS:
        for seed in args.seeds:
            cfg = short_recipe(seed, precision)
            run = args.work / f"{precision}-seed{seed}"
            trainer.run(
                cfg,
                work=run / "work",
                reports=run / "reports",
                export=run / "model.pt",
                device=torch.device("cpu"),
                hours=None,
                command=f"precision_check {precision} seed {seed}",
            )
            stages = json.loads((run / "reports" / "training.json").read_text(encoding="utf-8"))["stages"].values()
            pairs, hours = sum(st["pairs_seen"] for st in stages), sum(st["hours"] for st in stages)
            speed.append(f"| {precision} | {seed} | {pairs:,} | {hours:.3f} | {pairs / max(hours * 3600, 1e-9):.0f} |")
            for r in last_val_rows(run / "reports"):
                table.append(
                    {
                        "precision": precision,
                        "seed": seed,
                        "action": r["action"],
                        "component": r["component"],
                        "mae": float(r["mae"]),
                        "prior_mae": float(r["prior_mae"]),
                    }
                )
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(table[0]), lineterminator="\n")
    w.writeheader()
    w.writerows(table)
    write_text_atomic(args.out / "runs.csv", buf.getvalue())
    text = comparison(table, args.seeds) + "\n".join(
        [
            "| precision | seed | samples seen | hours (training and validation) | samples/s |",
            "|---|---|---|---|---|",
            *speed,
            "",
        ]
    )
    write_text_atomic(args.out / "comparison.md", text)
    print(text)
    return 0


def comparison(table: list[dict], seeds: list[int]) -> str:
    """Markdown: per action and component, each precision's mean MAE over seeds (x 1e-2), the
    precision gap and the seed spread (largest minus smallest over seeds, within a precision)."""
    keys = list(dict.fromkeys((r["action"], r["component"]) for r in table))
    lines = [
        (
            f"Validation MAE (x 1e-2) after the short recipe of `studies/robust_vo/precision_check.py`, "
            f"seeds {', '.join(map(str, seeds))}; machine: {platform.machine()}, {torch.get_num_threads()} torch threads, "
            f"torch {torch.__version__}, Python {platform.python_version()}."
        ),
        "",
        "| action | component | action prior | fp32 (mean) | bf16 (mean) | bf16 - fp32 | seed spread fp32 | seed spread bf16 |",
        "|---|---|---|---|---|---|---|---|",
    ]
    gaps, spreads, worst = [], [], []
    for action, comp in keys:
        by = {
            p: [r["mae"] * 100 for r in table if (r["action"], r["component"], r["precision"]) == (action, comp, p)]
            for p in PRECISIONS
        }
        prior = next(r["prior_mae"] for r in table if (r["action"], r["component"]) == (action, comp)) * 100
        gap = np.mean(by["bf16"]) - np.mean(by["fp32"])
        spread = {p: max(v) - min(v) for p, v in by.items()}
        gaps.append(abs(gap))
        spreads += list(spread.values())
        worst.append(max(spread.values()))
        lines.append(
            f"| {action} | {comp} | {prior:.2f} | {np.mean(by['fp32']):.2f} | {np.mean(by['bf16']):.2f} | "
            f"{gap:+.2f} | {spread['fp32']:.2f} | {spread['bf16']:.2f} |"
        )
    within = sum(g <= s for g, s in zip(gaps, worst))
    lines += [
        "",
        (
            f"Largest |bf16 - fp32| gap: {max(gaps):.2f}; largest seed spread: {max(spreads):.2f} (x 1e-2). "
            f"In {within} of {len(gaps)} components the gap is at most the larger of the two precisions' seed "
            "spreads (with two seeds a spread is a rough measure of the noise)."
        ),
        "",
    ]
    return "\n".join(lines)


if __name__ == "__main__":  # python -m studies.robust_vo.precision_check: the command line is odolab.cli.study's
    import importlib

    study = importlib.import_module("odolab.cli.study")
    study.exit_process(study.command("precision-check"))
