"""Two navigation runs of the same episodes, episode by episode: what a change won and lost.

    python -m odolab.navigation.diff reports/navigation runs/nav-new

reads each folder's ``episodes.csv`` (written by ``python -m odolab.navigate``), pairs the rows of
the same odometer, split, seed and episode, and prints per odometer: the paired episodes, success
before and after, the episodes won (failed before, succeeded after) and lost, and the mean SPL,
collisions and steps before and after. A policy or odometer change is judged on the same episodes,
so these counts, not two independent success rates, say what it did.
"""
from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from odolab.cli import ArgumentParser, UsageError, path_arg, run_cli
from odolab.io.inputs import read_input_bytes

#: The columns of ``episodes.csv`` this reads, and their kinds.
COLUMNS = {"odometer": str, "episode": int, "split": str, "seed": int, "success": float, "spl": float,
           "collisions": int, "steps": int}


@dataclass(frozen=True)
class RowDiff:
    """One odometer's paired episodes in two runs (``before``, ``after``)."""

    odometer: str
    episodes: int
    success: tuple[int, int]  # successful episodes, before and after
    won: tuple[int, ...]  # episode indices that failed before and succeeded after
    lost: tuple[int, ...]
    spl: tuple[float, float]  # means over the paired episodes
    collisions: tuple[float, float]
    steps: tuple[float, float]


def read_episodes(folder: Path) -> dict[tuple[str, str, int, int], dict]:
    """``episodes.csv`` of a navigation folder keyed by (odometer, split, seed, episode); ``UsageError``
    naming the file, line and column for a missing file, a missing column or a bad value."""
    path = Path(folder) / "episodes.csv"
    if not path.exists():
        raise UsageError(f"{path}: no such file (is {folder} a folder written by python -m odolab.navigate?)")
    try:
        text = read_input_bytes(path, "episodes table").decode("utf-8")
    except (ValueError, UnicodeDecodeError) as exc:
        raise UsageError(f"{path}: {exc}") from None
    reader = csv.DictReader(io.StringIO(text))
    missing = [c for c in COLUMNS if c not in (reader.fieldnames or [])]
    if missing:
        raise UsageError(f"{path}: no column {', '.join(missing)} (expected the episodes.csv of python -m odolab.navigate)")
    rows: dict[tuple[str, str, int, int], dict] = {}
    for line, raw in enumerate(reader, start=2):
        row = {}
        for name, kind in COLUMNS.items():
            try:
                row[name] = kind(raw[name])
            except (TypeError, ValueError):
                raise UsageError(f"{path}, line {line}: {name} must be {'a whole number' if kind is int else 'a number' if kind is float else 'text'}, "
                                 f"got {raw[name]!r}") from None
            if kind is float and not math.isfinite(row[name]):
                raise UsageError(f"{path}, line {line}: {name} must be finite, got {raw[name]!r}")
        key = (row["odometer"], row["split"], row["seed"], row["episode"])
        if key in rows:
            raise UsageError(f"{path}, line {line}: episode {row['episode']} of {row['odometer']} appears twice")
        rows[key] = row
    return rows


def diff_runs(before: dict, after: dict) -> list[RowDiff]:
    """Per odometer (in ``after``'s order), the episodes both runs hold, compared."""
    out = []
    for name in dict.fromkeys(k[0] for k in after):
        keys = sorted((k for k in after if k[0] == name and k in before), key=lambda k: (k[1], k[2], k[3]))
        if not keys:
            continue
        b, a = [before[k] for k in keys], [after[k] for k in keys]

        def mean(rows: list[dict], m: str) -> float:
            return sum(r[m] for r in rows) / len(rows)

        out.append(RowDiff(
            odometer=name, episodes=len(keys),
            success=(sum(r["success"] > 0.5 for r in b), sum(r["success"] > 0.5 for r in a)),
            won=tuple(k[3] for k, x, y in zip(keys, b, a) if x["success"] < 0.5 < y["success"]),
            lost=tuple(k[3] for k, x, y in zip(keys, b, a) if y["success"] < 0.5 < x["success"]),
            spl=(mean(b, "spl"), mean(a, "spl")), collisions=(mean(b, "collisions"), mean(a, "collisions")),
            steps=(mean(b, "steps"), mean(a, "steps"))))
    return out


def markdown(diffs: list[RowDiff]) -> str:
    """The comparison as a Markdown table (before -> after)."""
    def ids(v: tuple[int, ...]) -> str:
        return ", ".join(map(str, v[:12])) + (f" ... ({len(v)})" if len(v) > 12 else "") if v else "-"
    lines = ["| odometer | episodes | successes | won | lost | SPL | collisions per episode | steps |",
             "|---|---|---|---|---|---|---|---|"]
    for d in diffs:
        lines.append(f"| {d.odometer.replace('|', chr(92) + '|')} | {d.episodes} | {d.success[0]} -> {d.success[1]} | "
                     f"{ids(d.won)} | {ids(d.lost)} | {d.spl[0]:.2f} -> {d.spl[1]:.2f} | "
                     f"{d.collisions[0]:.1f} -> {d.collisions[1]:.1f} | {d.steps[0]:.0f} -> {d.steps[1]:.0f} |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    ap = ArgumentParser(prog="python -m odolab.navigation.diff", description=__doc__.splitlines()[0])
    ap.add_argument("before", type=path_arg("before"), help="a navigation folder (python -m odolab.navigate --out)")
    ap.add_argument("after", type=path_arg("after"), help="another one, of the same episodes")
    args = ap.parse_args(argv)
    diffs = diff_runs(read_episodes(args.before), read_episodes(args.after))
    if not diffs:
        raise UsageError(f"{args.before} and {args.after} share no episode of any odometer (same --split, --seed "
                         "and odometer names are needed)")
    print(markdown(diffs), end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(run_cli(main, "python -m odolab.navigation.diff"))
