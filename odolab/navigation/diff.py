"""Two navigation runs of the same episodes, episode by episode: what a change won and lost.

    python -m odolab.navigation.diff reports/navigation runs/nav-new

reads each folder's ``episodes.csv`` (written by ``python -m odolab.navigate``), pairs the rows of
the same odometer, split, seed and episode, and prints per odometer: the paired episodes, success
before and after, the episodes won (failed before, succeeded after) and lost with McNemar's exact p
of that split, the mean SPL before and after with the paired change's 95 % interval (Student's t
over the episodes), and the mean collisions and steps before and after; notes on stderr say where the folders' policies (from
their ``config.json``) or episode settings differ. A policy or odometer change is judged on the same episodes,
so these counts, not two independent success rates, say what it did.
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from odolab.core.stats import MeanCI, mcnemar, mean_ci
from odolab.io.inputs import read_input_bytes, read_input_json
from odolab.navigation.report import markdown_cell

#: The columns of ``episodes.csv`` this reads: (kind, lowest, highest); ``bool``: 0 or 1.
COLUMNS: dict[str, tuple[type, float, float]] = {
    "odometer": (str, 0, 0),
    "split": (str, 0, 0),
    "seed": (int, 0, 2**32 - 1),
    "episode": (int, 0, 10**9),
    "success": (bool, 0, 1),
    "spl": (float, 0.0, 1.0),
    "collisions": (int, 0, 10**6),
    "steps": (int, 0, 10**6),
}


class EpisodesTableError(ValueError):
    """An ``episodes.csv`` that cannot be read as a navigation run's table; the message names the file
    (and the line and column)."""


_WHOLE = re.compile(r"-?[0-9]+")  # ASCII digits only: not "1_0", "1.0" or other scripts' digits


@dataclass(frozen=True)
class RowDiff:
    """One odometer's paired episodes in two runs (``before``, ``after``)."""

    odometer: str
    episodes: int
    success: tuple[int, int]  # successful episodes, before and after
    won: tuple[str, ...]  # episodes ("7", or "val/0/7" when the runs span splits or seeds) failed before, won after
    lost: tuple[str, ...]
    spl: tuple[float, float]  # means over the paired episodes
    collisions: tuple[float, float]
    steps: tuple[float, float]
    success_p: float  # McNemar's exact two-sided p of the won / lost split
    spl_change: MeanCI  # after - before, paired over the episodes (Student's t interval)


def _value(text: str, kind: type, low: float, high: float) -> str | int | float:
    """One cell as ``kind`` within [low, high] (``ValueError`` otherwise); ``bool``: 0 or 1, written
    as any number (``1.0000``), read as an int."""
    if kind is str:
        return text
    t = text.strip()
    if not t.isascii() or "_" in t or len(t) > 40:  # Python reads "1_0" and other scripts' digits too
        raise ValueError(text)
    if kind is int:
        if not _WHOLE.fullmatch(t):
            raise ValueError(text)
        value: float = int(t)
    else:
        value = float(t)
        if kind is bool:
            if value not in (0.0, 1.0):
                raise ValueError(text)
            return int(value)
    if not (math.isfinite(value) and low <= value <= high):
        raise ValueError(text)
    return value


def read_episodes(folder: Path) -> dict[tuple[str, str, int, int], dict]:
    """``episodes.csv`` of a navigation folder keyed by (odometer, split, seed, episode); ``EpisodesTableError``
    naming the file, line and column for a missing or unreadable file, a missing column, a short or
    long row or a value out of its range (:data:`COLUMNS`)."""
    path = Path(folder) / "episodes.csv"
    try:
        text = read_input_bytes(path, "episodes table").decode("utf-8-sig")
    except UnicodeDecodeError as exc:  # a ValueError too: before the next clause
        raise EpisodesTableError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except ValueError as exc:  # it names the file
        raise EpisodesTableError(f"{exc} (expected the episodes.csv of python -m odolab.navigate)") from None
    reader = csv.reader(io.StringIO(text), strict=True)
    rows: dict[tuple[str, str, int, int], dict] = {}
    try:
        header = next(reader, None)
        if header is None:
            raise EpisodesTableError(f"{path}: empty; expected the episodes.csv of python -m odolab.navigate")
        twice = sorted({h for h in header if header.count(h) > 1})
        missing = [c for c in COLUMNS if c not in header]
        if twice or missing:
            raise EpisodesTableError(
                f"{path}: "
                + (f"column {', '.join(twice)} appears twice" if twice else f"no column {', '.join(missing)}")
                + " (expected the episodes.csv of python -m odolab.navigate)"
            )
        where = {c: header.index(c) for c in COLUMNS}
        for raw in reader:
            line = reader.line_num
            if not raw:
                continue
            if len(raw) != len(header):
                raise EpisodesTableError(f"{path}, line {line}: {len(raw)} fields, the header has {len(header)}")
            row = {}
            for name, (kind, low, high) in COLUMNS.items():
                try:
                    row[name] = _value(raw[where[name]], kind, low, high)
                except ValueError:
                    what = (
                        "0 or 1"
                        if name == "success"
                        else f"a whole number in [{low}, {high}]"
                        if kind is int
                        else f"a number in [{low:g}, {high:g}]"
                    )
                    raise EpisodesTableError(
                        f"{path}, line {line}: {name} must be {what}, got {raw[where[name]][:40]!r}"
                    ) from None
            key = (row["odometer"], row["split"], row["seed"], row["episode"])
            if key in rows:
                raise EpisodesTableError(
                    f"{path}, line {line}: episode {row['episode']} of {row['odometer'][:60]!r} "
                    f"({row['split']}, seed {row['seed']}) appears twice"
                )
            rows[key] = row
    except csv.Error as exc:  # an unclosed quote, a field over the csv module's limit
        raise EpisodesTableError(f"{path}, line {reader.line_num}: not CSV ({exc})") from None
    if not rows:
        raise EpisodesTableError(f"{path}: holds no episodes")
    return rows


def diff_runs(before: dict, after: dict) -> list[RowDiff]:
    """Per odometer (in ``after``'s order), the episodes both runs hold, compared."""
    by_name: dict[str, list[tuple]] = {}
    for k in after:
        if k in before:
            by_name.setdefault(k[0], []).append(k)
    labelled = len({(k[1], k[2]) for k in (*before, *after)}) > 1  # several splits or seeds: say which

    def label(k: tuple) -> str:
        return f"{k[1]}/{k[2]}/{k[3]}" if labelled else str(k[3])

    def mean(rows: list[dict], m: str) -> float:
        return sum(float(r[m]) for r in rows) / len(rows)

    out = []
    for name, keys in by_name.items():
        keys.sort(key=lambda k: (k[1], k[2], k[3]))
        b, a = [before[k] for k in keys], [after[k] for k in keys]
        out.append(
            RowDiff(
                odometer=name,
                episodes=len(keys),
                success=(sum(r["success"] for r in b), sum(r["success"] for r in a)),
                won=tuple(label(k) for k, x, y in zip(keys, b, a) if y["success"] > x["success"]),
                lost=tuple(label(k) for k, x, y in zip(keys, b, a) if y["success"] < x["success"]),
                spl=(mean(b, "spl"), mean(a, "spl")),
                collisions=(mean(b, "collisions"), mean(a, "collisions")),
                steps=(mean(b, "steps"), mean(a, "steps")),
                success_p=mcnemar(np.array([r["success"] for r in a]), np.array([r["success"] for r in b]))[2],
                spl_change=mean_ci(np.array([float(y["spl"]) - float(x["spl"]) for x, y in zip(b, a)])),
            )
        )
    return out


def unpaired(before: dict, after: dict) -> list[str]:
    """Notes on what only one run holds: odometers, and episodes of odometers both hold."""
    names_b, names_a = {k[0] for k in before}, {k[0] for k in after}
    notes = []
    for names, where in ((names_b - names_a, "BEFORE"), (names_a - names_b, "AFTER")):
        if names:
            shown = ", ".join(markdown_cell(n)[:60] for n in sorted(names)[:5]) + (" ..." if len(names) > 5 else "")
            notes.append(f"{len(names)} odometer(s) only in {where}: {shown}")
    both = names_b & names_a
    only_b = sum(1 for k in before if k[0] in both and k not in after)
    only_a = sum(1 for k in after if k[0] in both and k not in before)
    if only_b or only_a:
        notes.append(f"episodes of the shared odometers left out: {only_b} only in BEFORE, {only_a} only in AFTER")
    return notes


def _configs(before: Path, after: Path) -> tuple[list[dict], list[str]]:
    """The two folders' ``config.json`` documents, or none and the note that one could not be read."""
    docs = []
    for folder in (before, after):
        try:
            doc = read_input_json(Path(folder) / "config.json", "navigation config")
        except ValueError:
            return [], [f"no readable config.json in {folder}: the runs' settings were not compared"]
        if (
            not isinstance(doc, dict)
            or not isinstance(doc.get("policy"), dict)
            or not isinstance(doc.get("episodes"), list)
            or not doc["episodes"]
            or not isinstance(doc["episodes"][0], dict)
        ):
            return [], [f"{folder}/config.json is not a navigation config: the runs' settings were not compared"]
        docs.append(doc)
    return docs, []


#: Episode settings that may differ between two runs of the same episodes (said in a note).
_SETTINGS = ("max_steps", "noise", "camera")


def _first_episodes(docs: list[dict]) -> list[dict]:
    """Each config's first episode record (:func:`_configs` checked that there is one)."""
    return [d["episodes"][0] for d in docs]


def _same(a: object, b: object) -> bool:
    """Whether two JSON values are the same record (NaN equal to NaN, as JSON writes both)."""
    return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def _shown(value: object, limit: int) -> str:
    """A JSON value on one line, cut to ``limit`` characters."""
    return " ".join(str(value).split())[:limit]


def episode_difference(before: Path, after: Path) -> str | None:
    """What makes the two runs' episodes other episodes (their scene family or mesh files, their
    goals' distances, ...: every field of the episode records but the index and :data:`_SETTINGS`),
    as ``key A -> B`` (the first two such fields); None where they are the same episodes or a config
    cannot be read (:func:`setting_notes` says so)."""
    docs, _ = _configs(before, after)
    if not docs:
        return None
    first = _first_episodes(docs)
    keys = sorted((set(first[0]) | set(first[1])) - set(_SETTINGS) - {"index"})
    changed = [
        f"{_shown(k, 80)} {_shown(first[0].get(k, '-'), 80)} -> {_shown(first[1].get(k, '-'), 80)}"
        for k in keys
        if not _same(first[0].get(k), first[1].get(k))
    ]
    return ", ".join(changed[:2]) if changed else None


def setting_notes(before: Path, after: Path) -> list[str]:
    """Notes on how the two folders' ``config.json`` settings differ: policy parameters (each record
    completed with the defaults it leaves out, :meth:`PolicyConfig.completed`; one only one folder
    records shows as ``-`` in the other) and the episodes' step limit, noise and camera; or that a
    config could not be read, so settings were not compared."""
    from odolab.navigation.agent import PolicyConfig

    docs, unread = _configs(before, after)
    if not docs:
        return unread
    policies = [PolicyConfig.completed(d["policy"]) for d in docs]

    def shown(policy: dict, key: str) -> str:
        return repr(policy[key]) if key in policy else "-"

    changed = [
        f"{k} {shown(policies[0], k)} -> {shown(policies[1], k)}"
        for k in sorted(set(policies[0]) | set(policies[1]))
        if (k in policies[0], policies[0].get(k)) != (k in policies[1], policies[1].get(k))
    ]
    notes = [f"the policies differ: {', '.join(changed)[:300]}"] if changed else []
    first = _first_episodes(docs)
    for key in _SETTINGS:
        if not _same(first[0].get(key), first[1].get(key)):
            notes.append(
                f"the episodes' {key} differ: {_shown(first[0].get(key), 100)} -> {_shown(first[1].get(key), 100)}"
            )
    return notes


def markdown(diffs: list[RowDiff]) -> str:
    """The comparison as a Markdown table (before -> after)."""

    def ids(v: tuple[str, ...]) -> str:
        return ", ".join(v[:12]) + (f" ... ({len(v)})" if len(v) > 12 else "") if v else "-"

    def change(ci: MeanCI) -> str:
        interval = f" [{ci.low:+.3f}, {ci.high:+.3f}]" if np.isfinite(ci.low) and np.isfinite(ci.high) else ""
        return f"{ci.mean:+.3f}{interval}"

    lines = [
        (
            "| odometer | episodes | successes | episodes won | episodes lost | McNemar p | SPL | SPL change [95 %] "
            "| collisions per episode | steps |"
        ),
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for d in diffs:
        lines.append(
            f"| {markdown_cell(d.odometer)} | {d.episodes} | {d.success[0]} -> {d.success[1]} | "
            f"{ids(d.won)} | {ids(d.lost)} | {d.success_p:.2g} | {d.spl[0]:.2f} -> {d.spl[1]:.2f} | "
            f"{change(d.spl_change)} | {d.collisions[0]:.1f} -> {d.collisions[1]:.1f} | "
            f"{d.steps[0]:.0f} -> {d.steps[1]:.0f} |"
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":  # python -m odolab.navigation.diff: the command line is odolab.cli.navigation_diff's
    import runpy

    runpy.run_module("odolab.cli.navigation_diff", run_name="__main__", alter_sys=True)
