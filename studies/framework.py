"""What every study shares: its definition (``studies/<name>.toml``, one table per scale), units of
work run as Ray tasks whose results are saved as each finishes and reused only when everything they
depend on is the same, and the report (``index.html``, ``table.csv``, ``table.md``, figures, the
command and the machine).

A study's command line is ``python -m studies.<name> [--scale ci|cpu|paper] [--out DIR]
[--ray-address ADDR] [--redraw]``. ``ci`` runs in seconds (the tests run it), ``cpu`` is the
committed report, ``paper`` the paper's size (documented, for a cluster). Results live in
``<out>/results/`` (one JSON file per unit, keyed by the unit's full description); the report files
are listed in ``<out>/manifest.txt`` and replaced by the next run, the results never.
"""

from __future__ import annotations

import csv
import hashlib
import html
import io
import json
import math
import os
import re
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomllib

from odolab.parallel import Execution, fan_out

SCALES = ("ci", "cpu", "paper")
HERE = Path(__file__).resolve().parent
#: The files a study's report consists of (what its manifest may list and a rerun replaces).
REPORT_NAMES = re.compile(r"(index\.html|table\.csv|table\.md|[A-Za-z0-9_.-]+\.png)")


@dataclass(frozen=True)
class StudyConfig:
    """A study's definition: ``name``, a one-line ``title`` and, per scale, its parameters (plain TOML
    values: numbers, strings, lists)."""

    name: str
    title: str
    scales: dict[str, dict[str, Any]]

    def at(self, scale: str) -> dict[str, Any]:
        """The parameters of ``scale`` (one of :data:`SCALES`)."""
        return self.scales[scale]


def load_study(name: str, folder: Path = HERE) -> StudyConfig:
    """``<folder>/<name>.toml``: ``title = "..."`` and a ``[scales.ci]``, ``[scales.cpu]`` and
    ``[scales.paper]`` table each holding the same keys. ``ValueError`` names the file and field."""
    path = folder / f"{name}.toml"
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not a readable study definition ({exc})") from None
    title = doc.get("title")
    if not isinstance(title, str) or not title:
        raise ValueError(f"{path}: title: expected a non-empty string, got {title!r}")
    scales = doc.get("scales")
    if not isinstance(scales, dict) or sorted(scales) != sorted(SCALES):
        got = sorted(scales) if isinstance(scales, dict) else type(scales).__name__
        raise ValueError(f"{path}: scales: expected the tables {', '.join(SCALES)}, got {got}")
    keys = set(scales["cpu"])
    for s in SCALES:
        if not isinstance(scales[s], dict) or set(scales[s]) != keys:
            raise ValueError(
                f"{path}: scales.{s}: expected the keys {', '.join(sorted(keys))}, got {sorted(scales[s])}"
            )
    stray = sorted(set(doc) - {"title", "scales"})
    if stray:
        raise ValueError(f"{path}: {stray[0]}: not a study field (expected title and scales)")
    return StudyConfig(name, title, {s: dict(scales[s]) for s in SCALES})


@dataclass(frozen=True)
class Unit:
    """One unit of work: ``key`` describes it fully (everything its result depends on, plain JSON
    data); ``label`` names it for people."""

    label: str
    key: dict[str, Any]

    @property
    def digest(self) -> str:
        return hashlib.sha256(json.dumps(self.key, sort_keys=True).encode()).hexdigest()[:16]


class ResultStore:
    """Results of units, one JSON file each under ``folder`` (``<digest>.json`` holding the unit's
    key and result); a result is reused only when its stored key equals the unit's key."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)

    def _path(self, unit: Unit) -> Path:
        from odolab.io.owned import owned_path

        return owned_path(self.folder, f"{unit.digest}.json")

    def get(self, unit: Unit) -> Any | None:
        """The saved result of ``unit``, or None (none saved, unreadable, or saved for another key)."""
        path = self.folder / f"{unit.digest}.json"
        if not path.is_file() or path.is_symlink():
            return None
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        if not isinstance(doc, dict) or doc.get("key") != json.loads(json.dumps(unit.key)):
            return None
        return doc.get("result")

    def put(self, unit: Unit, result: Any) -> None:
        """Save ``result`` of ``unit`` at once (atomically)."""
        from odolab.io.atomic import write_text_atomic

        doc = {"label": unit.label, "key": unit.key, "result": result}
        write_text_atomic(self._path(unit), json.dumps(doc, indent=1, allow_nan=True) + "\n")


@dataclass
class Outcome:
    """The results of a study's units (label -> result), which were computed now, and which are
    missing (only with ``redraw``: never computed); ``seconds`` of computing, summed over units."""

    results: dict[str, Any] = field(default_factory=dict)
    computed: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)
    seconds: float = 0.0


def _accepts(valid: Callable[[Any], bool], value: Any) -> bool:
    try:
        return bool(valid(value))
    except (TypeError, ValueError, KeyError, AttributeError, IndexError):
        return False


def _timed(job: tuple[Callable[[dict], Any], dict]) -> tuple[Any, float]:
    fn, key = job
    t0 = time.perf_counter()
    result = fn(key)
    return result, time.perf_counter() - t0


def run_units(
    fn: Callable[[dict[str, Any]], Any],
    units: Sequence[Unit],
    store: ResultStore,
    *,
    redraw: bool = False,
    execution: Execution = Execution(),
    valid: Callable[[Any], bool] | None = None,
) -> Outcome:
    """``fn(unit.key)`` for every unit without a saved result, as Ray tasks (a local instance, or the
    cluster at ``execution.ray_address``), each result saved as it finishes; with ``redraw`` nothing is computed.
    Results must be plain JSON data. Computing seconds are saved beside each result. A saved result
    that ``valid`` refuses (a file edited or damaged by hand) counts as not saved: computed again,
    or missing with ``redraw``."""

    out = Outcome()
    todo = []
    for u in units:
        saved = store.get(u)
        if isinstance(saved, dict) and "value" in saved and (valid is None or _accepts(valid, saved["value"])):
            out.results[u.label] = saved["value"]
            out.seconds += float(saved.get("seconds", 0.0))
        elif redraw:
            out.missing.append(u.label)
        else:
            todo.append(u)

    def done(k: int, value: tuple[Any, float]) -> None:
        result, seconds = value
        store.put(todo[k], {"value": result, "seconds": seconds})
        out.results[todo[k].label] = result
        out.computed.append(todo[k].label)
        out.seconds += seconds

    fan_out(
        _timed,
        [(fn, u.key) for u in todo],
        on_result=done,
        execution=execution,
        desc="study units",
    )
    return out


def machine() -> str:
    """The machine a report ran on, in one line (CPU model, cores, Python, torch), from
    :func:`odolab.bench.machine`, as the benchmarks record it."""
    from odolab.bench import machine as measured

    m = measured()
    try:
        import torch

        torch_version = f", torch {torch.__version__}"
    except ImportError:
        torch_version = ""
    cpu = m["processor"] if m["cpu_model"] == "unknown" else m["cpu_model"]
    return f"{cpu}, {m['cpus']} cores, Python {m['python']}{torch_version}"


def _cell(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.3g}" if math.isfinite(v) else "-"
    return str(v)


def table_md(columns: list[str], rows: list[dict[str, Any]]) -> str:
    """A Markdown table of ``rows`` (dicts) in ``columns`` order."""
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(_cell(r.get(c, "")) for c in columns) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def table_csv(columns: list[str], rows: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, columns, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


@dataclass(frozen=True)
class Report:
    """What a study reports: ``title``; ``intro`` (paragraphs, plain text); the table (``columns``,
    ``rows``); ``figures`` (file name -> caption; :meth:`write` calls ``draw(path)`` for each);
    ``findings`` (one plain-text line each: where ours agrees with the paper and where not); the
    ``command`` that made it, the ``machine`` and the ``cpu_hours`` of its units."""

    title: str
    intro: list[str]
    columns: list[str]
    rows: list[dict[str, Any]]
    figures: dict[str, tuple[str, Callable[[Path], None]]]
    findings: list[str]
    command: str
    machine: str
    cpu_hours: float


def write_report(report: Report, out: Path, owner: str) -> list[str]:
    """Write ``report`` into ``out`` (``index.html``, ``table.csv``, ``table.md``, the figures),
    replacing the previous run's report files (never its results); returns the files written."""
    from odolab.io.atomic import write_text_atomic
    from odolab.report import OutputFolder

    folder = OutputFolder(out, owner=owner, names=REPORT_NAMES)
    write_text_atomic(folder.path("table.csv"), table_csv(report.columns, report.rows))
    md = [f"# {report.title}", "", *report.intro, "", table_md(report.columns, report.rows)]
    md += [f"- {f}" for f in report.findings]
    md += ["", f"Command: `{report.command}`", "", f"Machine: {report.machine}; {report.cpu_hours:.2f} CPU-hours."]
    write_text_atomic(folder.path("table.md"), "\n".join(md) + "\n")
    figures = []
    for name, (caption, draw) in report.figures.items():
        draw(folder.path(name))
        figures.append(
            f'<figure><img src="{html.escape(name)}" alt="{html.escape(caption)}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>"
        )
    head = "".join(f"<th>{html.escape(c)}</th>" for c in report.columns)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(_cell(r.get(c, '')))}</td>" for c in report.columns) + "</tr>"
        for r in report.rows
    )
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(report.title)}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em}}
table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:3px 8px;text-align:right}}
th{{background:#f2f2f2}}td:first-child,th:first-child{{text-align:left}}img{{max-width:100%}}
figure{{margin:1.5em 0}}</style></head><body>
<h1>{html.escape(report.title)}</h1>
{"".join(f"<p>{html.escape(p)}</p>" for p in report.intro)}
<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>
<h2>Against the paper</h2><ul>{"".join(f"<li>{html.escape(f)}</li>" for f in report.findings)}</ul>
{"".join(figures)}
<p>Command: <code>{html.escape(report.command)}</code><br>Machine: {html.escape(report.machine)};
{report.cpu_hours:.2f} CPU-hours of units.</p>
</body></html>
"""
    write_text_atomic(folder.path("index.html"), page)
    folder.finish()
    return folder.written


def command_line(prog: str, argv: Sequence[str] | None) -> str:
    """The command as typed: ``prog`` and its arguments."""
    import shlex

    return " ".join([prog, *map(shlex.quote, sys.argv[1:] if argv is None else argv)])


def study_arguments(prog: str, config: StudyConfig):
    """The argument parser every study shares: ``--scale``, ``--out``, ``--ray-address``, ``--redraw``."""
    from odolab.cli import ArgumentParser, path_arg

    ap = ArgumentParser(prog=prog, description=config.title)
    ap.add_argument(
        "--scale",
        choices=SCALES,
        default="cpu",
        help="ci: seconds; cpu: the committed report (default); paper: the paper's size, for a cluster",
    )
    ap.add_argument(
        "--out",
        type=path_arg("--out"),
        default=None,
        help=f"report folder (default reports/{config.name.replace('_', '-')})",
    )
    ap.add_argument("--ray-address", default=None, help="Ray cluster for the units (default: a local instance)")
    ap.add_argument("--serial", action="store_true", help="run the units one after another in this process")
    ap.add_argument("--redraw", action="store_true", help="rebuild the report from saved results only")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    return ap


def check_out(out: Path, config: StudyConfig) -> None:
    """Refuse an ``--out`` folder a study cannot own (a user's files, another command's report, links)."""
    from odolab.cli import UsageError, check_report_dir
    from odolab.io.owned import UnsafeOutputError
    from odolab.report import ManifestError, OutputFolder

    owner = f"study {config.name}"
    if _interrupted_first_run(out):  # results saved, killed before its report: the study's own folder
        _claim(out, owner)
    check_report_dir(out, "--out")
    try:
        OutputFolder.check(out, folders=("results",), owner=owner, names=REPORT_NAMES)
    except (UnsafeOutputError, ManifestError) as exc:
        said = str(exc).removeprefix(f"{out}: ")  # the path once
        raise UsageError(f"--out {out}: {said}") from None
    if not (out / "manifest.txt").exists():
        _claim(out, owner)  # before any unit's result is saved: an interrupted run is resumed, not refused


def _claim(out: Path, owner: str) -> None:
    """Mark ``out`` as ``owner``'s with a manifest naming no report file yet."""
    from odolab.io.atomic import write_text_atomic
    from odolab.io.owned import owned_path

    write_text_atomic(owned_path(out, "manifest.txt"), f"# odolab {owner}\n")


def _interrupted_first_run(out: Path) -> bool:
    """Whether ``out`` holds only a ``results`` folder of result files and no manifest: what a
    study's first run left when it was stopped before its report (before manifests were written first)."""
    try:
        if not out.is_dir() or out.is_symlink() or (out / "manifest.txt").exists() or os.listdir(out) != ["results"]:
            return False
        results = out / "results"
        entries = list(results.iterdir()) if results.is_dir() and not results.is_symlink() else []
    except OSError:
        return False
    return bool(entries) and all(e.suffix == ".json" and e.is_file() and not e.is_symlink() for e in entries)


def check_options(args, out: Path, config: StudyConfig) -> None:
    """Everything a study's command line can get wrong, found before any work and before ``out`` is
    made: ``--ray-address`` (malformed, unreachable, or with ``--serial``), ``--redraw`` with no saved
    results to draw from, and the ``--out`` folder (:func:`check_out`)."""
    from odolab.cli import UsageError, check_ray_option

    check_ray_option(args.ray_address, args.serial)
    if args.redraw:
        if args.ray_address is not None:
            raise UsageError("--redraw computes nothing; --ray-address is for computing units: drop one")
        if out.is_dir():  # another command's or a user's folder is said as such first
            check_out(out, config)
        results = out / "results"
        if not results.is_dir() or not any(results.glob("*.json")):
            raise UsageError(f"--redraw: no saved results in {results}; run without --redraw first")
    check_out(out, config)


def write_reports_index(reports: Path) -> Path:
    """``reports/index.html``: a link to every report page under ``reports`` (``*/index.html`` and
    ``*/report.html``), with its title."""
    from odolab.io.atomic import write_text_atomic

    items = []
    for page in sorted([*reports.glob("*/index.html"), *reports.glob("*/report.html")]):
        if page.is_symlink():
            continue
        text = page.read_text(encoding="utf-8", errors="replace")
        m = re.search(r"<title>(.*?)</title>", text, flags=re.DOTALL)
        title = html.unescape(m.group(1).strip()) if m else page.parent.name
        rel = page.relative_to(reports).as_posix()
        items.append(f'<li><a href="{html.escape(rel)}">{html.escape(page.parent.name)}</a>: {html.escape(title)}</li>')
    page = (
        '<!doctype html>\n<html lang="en"><head><meta charset="utf-8"><title>odolab reports</title>'
        "<style>body{font-family:sans-serif;max-width:900px;margin:2em auto}</style></head><body>"
        "<h1>odolab reports</h1><ul>" + "".join(items) + "</ul></body></html>\n"
    )
    write_text_atomic(reports / "index.html", page)
    return reports / "index.html"
