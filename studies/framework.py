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
import importlib.metadata
import io
import json
import math
import os
import re
import sys
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import tomllib

from odolab.core.parallel import Execution, fan_out
from odolab.io.lock import FolderLock
from studies.reports_index import DEFAULT_REPORTS

T = TypeVar("T")

SCALES = ("ci", "cpu", "paper")
HERE = Path(__file__).resolve().parent
#: The name of a unit's saved result (:class:`ResultStore`): its digest.
RESULT_NAME = re.compile(r"[0-9a-f]{16}\.json")
#: The files a study's report consists of (what its manifest may list and a rerun replaces).
REPORT_NAMES = re.compile(r"(index\.html|table\.md|[A-Za-z0-9_.-]+\.csv|[A-Za-z0-9_.-]+\.png)")


@dataclass(frozen=True)
class StudyConfig:
    """A study's definition: ``name``, a one-line ``title`` and, per scale, its parameters (plain TOML
    values: numbers, strings, lists); ``path``, the file it was read from (named in errors)."""

    name: str
    title: str
    scales: dict[str, dict[str, Any]]
    path: Path | None = None

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
    return StudyConfig(name, title, {s: dict(scales[s]) for s in SCALES}, path)


def identities(
    config: StudyConfig, scale: str, odometers: Sequence[str], options: dict[str, dict[str, Any]] | None = None
) -> dict[str, str | None]:
    """Name -> ``Odometer.identity_digest`` (its model file's or settings' digest, None for neither) of
    each odometer loaded with its ``options``: what a unit's key holds so that a retrained model's or
    changed setting's results are computed again. ``ValueError`` naming the file and field for a name
    or an option the odometer refuses."""
    from odolab.api import load_odometer

    out = {}
    for name in odometers:
        try:
            out[name] = load_odometer(name, **(options or {}).get(name, {})).identity_digest
        except (ValueError, KeyError, TypeError, ImportError) as exc:
            said = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
            field = "options" if (options or {}).get(name) else "odometers"
            raise ValueError(f"{config.path or config.name}: scales.{scale}.{field}: {name}: {said}") from None
    return out


def default_out(config: StudyConfig) -> Path:
    """The report folder of a study run without ``--out``: ``reports/<name with dashes>`` (relative
    to the working folder, as every odolab command's default output)."""
    return DEFAULT_REPORTS / config.name.replace("_", "-")


@dataclass(frozen=True)
class Unit:
    """One unit of work: ``key`` describes it fully (everything its result depends on, plain JSON
    data); ``label`` names it for people; ``inputs``: what its task needs besides but its result does
    not depend on (where mesh files lie: the key holds their digests), handed to it with the key and
    neither hashed nor saved."""

    label: str
    key: dict[str, Any]
    inputs: dict[str, Any] = field(default_factory=dict)

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
        from odolab.io.inputs import read_input_json

        path = self.folder / f"{unit.digest}.json"
        if not path.is_file() or path.is_symlink():
            return None
        try:  # a regular file of a sane size and nesting: else not saved, whatever it holds
            doc = read_input_json(path, "study result")
        except ValueError:
            return None
        if not isinstance(doc, dict) or doc.get("key") != json.loads(json.dumps(unit.key)):
            return None
        return doc.get("result")

    def put(self, unit: Unit, result: Any) -> None:
        """Save ``result`` of ``unit`` at once (atomically)."""
        from odolab.io.atomic import write_text_atomic

        doc = {"label": unit.label, "key": unit.key, "result": result}
        write_text_atomic(self._path(unit), json.dumps(doc, indent=1, allow_nan=True) + "\n")

    def check_writable(self, units: Sequence[Unit]) -> None:
        """Before computing ``units``: ``UsageError`` with one line when a result could not be saved
        (the folder not writable, or a unit's file place taken by a folder or a link), so that no
        unit's work is lost when it finishes."""
        import tempfile

        from odolab.cli import UsageError
        from odolab.io.owned import UnsafeOutputError

        for unit in units:
            try:
                path = self._path(unit)  # makes the folder
            except (UnsafeOutputError, OSError) as exc:
                raise UsageError(f"{exc}; remove it to save the unit's result there") from None
            if path.exists() and not path.is_file():
                raise UsageError(f"{path}: expected a result file or nothing, found a folder; remove it")
        try:
            with tempfile.NamedTemporaryFile(dir=self.folder, prefix=".write-check-"):
                pass
        except OSError as exc:
            raise UsageError(f"{self.folder}: results cannot be saved there ({exc.strerror or exc})") from None


@dataclass
class Outcome:
    """The results of a study's units (label -> result), which were computed now, and which are
    missing (only with ``redraw``: never computed); ``seconds`` of computing, summed over units;
    ``machines``: how many of the units ran on each machine (:func:`machine`; "" not recorded)."""

    results: dict[str, Any] = field(default_factory=dict)
    computed: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)
    seconds: float = 0.0
    machines: Counter[str] = field(default_factory=Counter)

    def count(self, where: Any) -> None:
        """Count one more unit run on ``where`` (a saved machine line, made one printable line of at most
        200 characters; anything else, or blank: not recorded)."""
        if not isinstance(where, str):
            where = ""
        self.machines[" ".join("".join(c if c.isprintable() else " " for c in where).split())[:200]] += 1


def _accepts(valid: Callable[[Any], bool], value: Any) -> bool:
    try:
        return bool(valid(value))
    except (TypeError, ValueError, KeyError, AttributeError, IndexError, OverflowError):
        return False


def _seconds(value: Any) -> float:
    """A saved computing time in seconds, 0 when it is not a finite number >= 0 (edited by hand)."""
    try:
        seconds = float(value)
    except (TypeError, ValueError, OverflowError):
        return 0.0
    return seconds if math.isfinite(seconds) and seconds >= 0 else 0.0


def _timed(job: tuple[Callable[[dict], Any], dict]) -> tuple[Any, float, str]:
    """``fn(key)``, its seconds and the machine it ran on (a Ray task's own node)."""
    fn, key = job
    t0 = time.perf_counter()
    result = fn(key)
    return result, time.perf_counter() - t0, machine()


def _saved(store: ResultStore, unit: Unit, valid: Callable[[Any], bool] | None) -> dict[str, Any] | None:
    """``unit``'s saved ``{"value", "seconds"}`` when ``valid`` accepts its value, else None."""
    saved = store.get(unit)
    if isinstance(saved, dict) and "value" in saved and (valid is None or _accepts(valid, saved["value"])):
        return saved
    return None


def unsaved(units: Sequence[Unit], store: ResultStore, valid: Callable[[Any], bool] | None = None) -> list[Unit]:
    """The units :func:`run_units` would compute: those without a saved result ``valid`` accepts."""
    return [u for u in units if _saved(store, u, valid) is None]


@dataclass(frozen=True)
class Phase:
    """One kind of a study's units: ``fn(unit.key | unit.inputs)`` computes one; ``units(before)`` lists
    the phase's units that the outcomes of the phases before it (``before``, so far) make possible;
    ``valid`` accepts a saved value (:func:`run_units`); ``gpus``: what each of its Ray tasks asks for;
    ``saved(unit, value)`` is called in the driver once a unit computed now has its result saved."""

    fn: Callable[[dict[str, Any]], Any]
    units: Callable[[Sequence[Outcome]], Sequence[Unit]]
    valid: Callable[[Any], bool] | None = None
    gpus: float = 0.0
    saved: Callable[[Unit, Any], None] | None = None


def run_phases(
    phases: Sequence[Phase],
    store: ResultStore,
    *,
    redraw: bool = False,
    execution: Execution = Execution(),
    only: Callable[[Unit], bool] | None = None,
) -> list[Outcome]:
    """:func:`run_units` for phases whose units come from the results of the phases before (each
    trained model's evaluations), one :class:`Outcome` per phase. Pipelined: once a unit's result is
    saved, the later units it makes possible are queued at once, behind the units already queued, so
    they run on the cores that a phase's last, longest units leave idle. Saved results are read and
    ``redraw`` and ``only`` apply as in :func:`run_units`."""
    outcomes = [Outcome() for _ in phases]
    seen: list[set[str]] = [set() for _ in phases]
    listed = [-1] * len(phases)  # results of the phases before, when a phase's units were last listed
    queued: list[tuple[int, Unit]] = []

    def newly_possible() -> list[tuple[Callable[[dict[str, Any]], Any], dict[str, Any]]]:
        """Read or queue each phase's units not met before; the queued ones as ``_timed`` items."""
        fresh = []
        for p, phase in enumerate(phases):
            before = sum(len(o.results) for o in outcomes[:p])
            if before == listed[p]:
                continue
            listed[p] = before
            for u in phase.units(outcomes[:p]):
                if u.digest in seen[p]:
                    continue
                seen[p].add(u.digest)
                saved = _saved(store, u, phase.valid)
                if saved is not None:
                    outcomes[p].results[u.label] = saved["value"]
                    outcomes[p].seconds += _seconds(saved.get("seconds", 0.0))
                    outcomes[p].count(saved.get("machine"))
                elif redraw or (only is not None and not only(u)):
                    outcomes[p].missing.append(u.label)
                else:
                    fresh.append((p, u))
        if fresh:
            store.check_writable([u for _, u in fresh])
        queued.extend(fresh)
        return [(phases[p].fn, {**u.key, **u.inputs}) for p, u in fresh]

    def done(k: int, value: tuple[Any, float, str]) -> None:
        result, seconds, where = value
        p, unit = queued[k]
        store.put(unit, {"value": result, "seconds": seconds, "machine": where})
        out = outcomes[p]
        out.results[unit.label] = result
        out.computed.append(unit.label)
        out.seconds += seconds
        out.count(where)
        if phases[p].saved is not None:
            phases[p].saved(unit, result)

    first = newly_possible()
    fan_out(
        _timed,
        first,
        on_result=done,
        then=(lambda _k, _value: newly_possible()) if len(phases) > 1 else None,
        execution=execution,
        desc="study units",
        gpus=lambda k: phases[queued[k][0]].gpus,
    )
    return outcomes


def run_units(
    fn: Callable[[dict[str, Any]], Any],
    units: Sequence[Unit],
    store: ResultStore,
    *,
    redraw: bool = False,
    execution: Execution = Execution(),
    valid: Callable[[Any], bool] | None = None,
    gpus: float = 0.0,
    only: Callable[[Unit], bool] | None = None,
) -> Outcome:
    """``fn(unit.key | unit.inputs)`` for every unit without a saved result, as Ray tasks (a local instance, or the
    cluster at ``execution.ray_address``), each result saved as it finishes; with ``redraw`` nothing is
    computed, and with ``only`` nothing but the units it accepts (the others are read as with ``redraw``).
    Results must be plain JSON data. Computing seconds and the machine are saved beside each result. A saved result
    that ``valid`` refuses (a file edited or damaged by hand) counts as not saved: computed again,
    or missing with ``redraw``. ``gpus``: GPUs each unit's Ray task asks for (:func:`fan_out`)."""
    return run_phases(
        [Phase(fn, lambda _before: units, valid, gpus)], store, redraw=redraw, execution=execution, only=only
    )[0]


def machine() -> str:
    """The machine a report ran on, in one line (CPU model, cores, Python, torch), from
    :func:`odolab.core.machine.machine`, as the benchmarks record it."""
    from odolab.core.machine import machine as measured

    m = measured()
    try:  # the installed version, read without importing torch (a Ray worker may never need it)
        torch_version = f", torch {importlib.metadata.version('torch')}"
    except importlib.metadata.PackageNotFoundError:
        torch_version = ""
    cpu = m["processor"] if m["cpu_model"] == "unknown" else m["cpu_model"]
    return f"{cpu}, {m['cpus']} cores, Python {m['python']}{torch_version}"


def machines(outcomes: Sequence[Outcome]) -> str:
    """Where the units of ``outcomes`` ran, in one line: each machine with its number of units, most
    first (not recorded last); this machine (:func:`machine`) when there are no units."""
    counts: Counter[str] = Counter()
    for o in outcomes:
        counts.update(o.machines)
    if not counts:
        return machine()
    total = sum(counts.values())
    if len(counts) == 1:
        return f"{next(iter(counts)) or 'not recorded'} (all {total} units)"
    parts = sorted(counts.items(), key=lambda kv: (kv[0] == "", -kv[1], kv[0]))
    return "; ".join(f"{where or 'machine not recorded'} ({n} of {total} units)" for where, n in parts)


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
    ``command`` that made it, the ``machine`` and the ``cpu_hours`` of its units; ``tables``: more
    tables after the findings (each written as ``<name>.csv`` too)."""

    title: str
    intro: list[str]
    columns: list[str]
    rows: list[dict[str, Any]]
    figures: dict[str, tuple[str, Callable[[Path], None]]]
    findings: list[str]
    command: str
    machine: str
    cpu_hours: float
    tables: list[Table] = field(default_factory=list)


@dataclass(frozen=True)
class Table:
    """A further table of a report: its file ``name`` (``<name>.csv``), a ``heading``, paragraphs of
    ``intro`` (plain text) and its ``columns`` and ``rows``."""

    name: str
    heading: str
    intro: list[str]
    columns: list[str]
    rows: list[dict[str, Any]]


def write_report(report: Report, out: Path, owner: str) -> list[str]:
    """Write ``report`` into ``out`` (``index.html``, ``table.csv``, ``table.md``, the figures),
    replacing the previous run's report files (never its results); returns the files written."""
    from odolab.io.atomic import write_text_atomic
    from odolab.io.owned import UnsafeOutputError
    from odolab.reporting.report import OutputFolder

    folder = OutputFolder(out, owner=owner, names=REPORT_NAMES)
    write_text_atomic(folder.path("table.csv"), table_csv(report.columns, report.rows))
    md = [f"# {report.title}", "", *report.intro, "", table_md(report.columns, report.rows)]
    md += [f"- {f}" for f in report.findings]
    for extra in report.tables:
        write_text_atomic(folder.path(f"{extra.name}.csv"), table_csv(extra.columns, extra.rows))
        md += ["", f"## {extra.heading}", "", *extra.intro, "", table_md(extra.columns, extra.rows)]
    md += ["", f"Command: `{report.command}`", "", f"Machine: {report.machine}; {report.cpu_hours:.2f} CPU-hours."]
    write_text_atomic(folder.path("table.md"), "\n".join(md) + "\n")
    figures = []
    for name, (caption, draw) in report.figures.items():
        draw(folder.path(name))
        figures.append(
            f'<figure><img src="{html.escape(name)}" alt="{html.escape(caption)}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>"
        )
    extras = "".join(
        f"<h2>{html.escape(t.heading)}</h2>{''.join(f'<p>{html.escape(p)}</p>' for p in t.intro)}{_html_table(t.columns, t.rows)}"
        for t in report.tables
    )
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(report.title)}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em}}
table{{border-collapse:collapse;font-size:.64em}}td,th{{border:1px solid #ccc;padding:2px 1px;text-align:right}}
th{{background:#f2f2f2}}td:first-child,th:first-child{{text-align:left}}
img{{max-width:100%}}figure{{margin:1.5em 0}}
.wide{{overflow-x:auto;width:calc(100vw - 2em);position:relative;left:50%;transform:translateX(-50%)}}
.wide table{{margin:0 auto}}</style></head><body>
<h1>{html.escape(report.title)}</h1>
{"".join(f"<p>{html.escape(p)}</p>" for p in report.intro)}
{_html_table(report.columns, report.rows)}
<h2>Against the paper</h2><ul>{"".join(f"<li>{html.escape(f)}</li>" for f in report.findings)}</ul>
{extras}
{"".join(figures)}
<p>Command: <code>{html.escape(report.command)}</code><br>Machine: {html.escape(report.machine)};
{report.cpu_hours:.2f} CPU-hours of units.</p>
</body></html>
"""
    write_text_atomic(folder.path("index.html"), page)
    folder.finish()
    reports = DEFAULT_REPORTS.resolve()
    if reports in Path(out).resolve().parents:  # a report among the default ones: the index lists it
        try:
            write_reports_index(reports)
        except (UnsafeOutputError, OSError) as exc:  # the report is written; a user's page stays
            print(f"note: {reports / 'index.html'} not refreshed: {exc}", file=sys.stderr)
    return folder.written


def _html_table(columns: list[str], rows: list[dict[str, Any]]) -> str:
    """A table as the study pages show it: as wide as the window, headers that wrap at ``_``."""
    head = "".join(f"<th>{html.escape(c).replace('_', '_<wbr>')}</th>" for c in columns)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(_cell(r.get(c, '')))}</td>" for c in columns) + "</tr>" for r in rows
    )
    return f'<div class="wide"><table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>'


def unit_ranges(labels: Sequence[str]) -> str:
    """``labels`` for people, in their order: a run of labels that differ only in a last number
    counting up by one becomes one range ("navigate row 3 episode 0-49"), led by the count of units
    when there are several ("3 units: row 4, errors row 0 seed 0-1")."""
    groups: list[list[Any]] = []  # [prefix, first, last] or [label, None, None]
    for label in labels:
        m = re.fullmatch(r"(.*?)(\d+)", label)
        prefix, number = (m.group(1), int(m.group(2))) if m else (label, None)
        last = groups[-1] if groups else None
        if number is not None and last and last[0] == prefix and last[2] is not None and number == last[2] + 1:
            last[2] = number
        else:
            groups.append([prefix, number, number])
    parts = [p if a is None else f"{p}{a}" if a == b else f"{p}{a}-{b}" for p, a, b in groups]
    return f"{len(labels)} units: {', '.join(parts)}" if len(labels) > 1 else ", ".join(parts)


def missing_note(labels: Sequence[str]) -> str:
    """For a report's intro: the units ``labels`` left out because no result was saved ("" when none)."""
    return f" Missing (not computed): {unit_ranges(labels)}." if labels else ""


def outcome_note(outcome: Outcome) -> str:
    """:func:`missing_note` of ``outcome``'s missing units."""
    return missing_note(outcome.missing)


def say_missing(labels: Sequence[str]) -> None:
    """Name on stderr the units ``labels`` that have no saved result, so no number comes from them (nothing when none)."""
    if labels:
        print(f"note: no saved result (no number in the table comes from them): {unit_ranges(labels)}", file=sys.stderr)


def require_results(outcome: Outcome, out: Path, scale: str) -> None:
    """``UsageError`` when there is nothing to report: ``--redraw`` found no saved result of ``scale``."""
    from odolab.cli import UsageError

    if not outcome.results:
        raise UsageError(
            f"--redraw: no saved results in {out / 'results'} for --scale {scale}"
            + (
                " (its results were saved with other settings: another --scale, or --scenes for those of mesh files)"
                if any((out / "results").glob("*.json"))
                else ""
            )
            + "; run without --redraw"
        )


def say_done(outcome: Outcome, rows: int, out: Path) -> None:
    """Print how many units were computed and rows written; name the missing units on stderr."""
    from odolab.reporting.report import counted

    print(
        f"{counted(len(outcome.computed), 'unit')} computed, {counted(rows, 'row')} -> {out}; open {out / 'index.html'}"
    )
    say_missing(outcome.missing)


def check_out(out: Path, config: StudyConfig, claim: bool = True) -> None:
    """Refuse an ``--out`` folder a study cannot own (a user's files, another command's report,
    links); then, when ``claim`` (the run will go on), make it and mark it as the study's. With
    ``claim`` False only checked: a run that may still be refused writes nothing."""
    from odolab.cli import UsageError, check_not_nested, check_report_dir
    from odolab.io.owned import UnsafeOutputError
    from odolab.reporting.report import ManifestError, OutputFolder

    owner = f"study {config.name}"
    check_not_nested(out, "--out")  # before a stopped first run's folder is claimed
    if _interrupted_first_run(out):  # results saved, killed before its report: the study's own folder
        if not claim:
            return
        _claim(out, owner)
    check_report_dir(out, "--out")
    try:
        OutputFolder.check(out, folders=("results",), owner=owner, names=REPORT_NAMES)
    except (UnsafeOutputError, ManifestError) as exc:
        said = str(exc).removeprefix(f"{out}: ")  # the path once
        raise UsageError(f"--out {out}: {said}") from None
    if claim and not (out / "manifest.txt").exists():
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
    return bool(entries) and all(_is_result_file(e) for e in entries)


def _is_result_file(path: Path) -> bool:
    """Whether ``path`` is a file :meth:`ResultStore.put` wrote: named by a unit's digest, a JSON
    object holding a ``key`` and a ``result`` (a user's own JSON files are not)."""
    if not (RESULT_NAME.fullmatch(path.name) and path.is_file() and not path.is_symlink()):
        return False
    try:
        doc = json.loads(path.read_text(encoding="utf-8")[:10_000_000])
    except (OSError, ValueError):
        return False
    return isinstance(doc, dict) and {"key", "result"} <= set(doc)


def check_options(args, out: Path, config: StudyConfig) -> FolderLock:
    """Everything a study's command line can get wrong, found before any work and before ``out`` is
    made: ``--ray-address`` (malformed, unreachable, or with ``--serial``) and the ``RAY_ADDRESS``
    variable (unless nothing is computed), ``--redraw`` with no saved results to draw from, and the
    ``--out`` folder (:func:`check_out`), claimed only once every check has passed (with ``--redraw``,
    by the report it draws). Returns this run's hold on ``out`` (:func:`hold_out`): keep it while
    the study computes and writes."""
    from odolab.cli import UsageError, check_ray_option

    if args.redraw and args.ray_address is not None:
        raise UsageError("--redraw computes nothing; --ray-address is for computing units: drop one")
    check_ray_option(args.ray_address, args.serial, starts_ray=not args.redraw)
    if args.redraw:
        if out.exists() or out.is_symlink():  # a file, a link, another command's or a user's folder first
            check_out(out, config, claim=False)
        results = out / "results"
        if not results.is_dir() or not any(results.glob("*.json")):
            raise UsageError(f"--redraw: no saved results in {results}; run without --redraw first")
        return hold_out(out)  # the report, once drawn, claims the folder: a redraw refused later writes nothing
    check_out(out, config)
    return hold_out(out)


def hold_out(out: Path) -> FolderLock:
    """This run's hold on its ``--out`` folder (:func:`odolab.io.lock.lock_folder`): ``UsageError``
    at once when another odolab run holds it (two runs of a study into one folder would overwrite
    each other's results and report). Released when the returned object is released or dropped, or
    the process ends."""
    from odolab.cli import UsageError
    from odolab.io.lock import FolderInUseError, lock_folder

    try:
        return lock_folder(out)
    except FolderInUseError as exc:
        raise UsageError(exc.named("--out")) from None


@dataclass(frozen=True)
class StudyRun:
    """One run of a study as asked: its definition, the parsed command line (``args``), the checked
    parameters of the asked scale (``scale``), the report folder ``out`` and each odometer's
    identity digest (``identity``, :func:`identities`)."""

    config: StudyConfig
    args: Any
    scale: Any
    out: Path
    identity: dict[str, str | None]
    held: FolderLock | None = None  # this run's hold on out (check_options), released once published

    def run(self, fn: Callable[[dict[str, Any]], Any], units: Sequence[Unit], valid: Callable[[Any], bool]) -> Outcome:
        """:func:`run_units` into ``out/results`` as the command line asks (``--redraw``, where the
        units run); ``UsageError`` when ``--redraw`` finds nothing saved for this scale."""
        from odolab.cli import execution_of

        store = ResultStore(self.out / "results")
        cache = cache_inputs(self.args)
        units = [Unit(u.label, u.key, {**u.inputs, **cache}) for u in units] if cache else units
        outcome = run_units(fn, units, store, redraw=self.args.redraw, execution=execution_of(self.args), valid=valid)
        require_results(outcome, self.out, self.args.scale)
        return outcome

    def publish(
        self,
        outcome: Outcome,
        intro: list[str],
        columns: list[str],
        rows: list[dict[str, Any]],
        figures: dict[str, tuple[str, Callable[[Path], None]]],
        findings: list[str],
    ) -> None:
        """Write the report (:func:`write_report`; the missing units named in its intro), then print
        its table and what was computed."""
        report = Report(
            title=self.config.title,
            intro=[*intro[:-1], intro[-1] + outcome_note(outcome)] if intro else [outcome_note(outcome)],
            columns=columns,
            rows=rows,
            figures=figures,
            findings=findings,
            command=self.args.command,
            machine=machines([outcome]),
            cpu_hours=outcome.seconds / 3600,
        )
        write_report(report, self.out, owner=f"study {self.config.name}")
        if self.held is not None:
            self.held.release()
        print(table_md(columns, rows))
        say_done(outcome, len(rows), self.out)


def scale_params(config: StudyConfig, scale: str, cls: type[T]) -> T:
    """The asked scale's parameters: its table of ``<name>.toml`` built into ``cls``, a dataclass of
    :func:`odolab.config.setting` fields (their types, ranges and the class's own checks);
    :class:`odolab.config.ConfigError` (a ``ValueError``) names the file and field, a key that is
    none of the fields included."""
    from odolab.config import build

    return build(cls, config.at(scale), f"{config.path or config.name}: scales.{scale}")


def begin(name: str, args: Any, scale_class: type) -> StudyRun:
    """Everything a study checks before any work, given its parsed command line ``args``
    (:mod:`odolab.cli.study`): ``<name>.toml``, the asked scale's parameters (:func:`scale_params`
    into ``scale_class``, which has ``odometers`` and may have ``options``), the odometers (loaded for their
    identity digests) and the ``--out`` folder. Bad input is one ``UsageError`` line naming the file
    and field or the option."""
    from odolab.cli import UsageError

    try:
        config = load_study(name)
        scale = scale_params(config, args.scale, scale_class)
        identity = identities(config, args.scale, scale.odometers, getattr(scale, "options", None))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    out = args.out or default_out(config)
    check_cache(args)
    held = check_options(args, out, config)
    return StudyRun(config, args, scale, out, identity, held)


def check_cache(args: Any) -> None:
    """The study's ``--cache``, where it has one, checked as a cache a run reads and adds to
    (:func:`odolab.cli.args.check_cache_dir`; ``UsageError`` in one line)."""
    if getattr(args, "cache", None) is not None:
        from odolab.cli.args import check_cache_dir

        check_cache_dir(args.cache, "--cache")


def cache_inputs(args: Any) -> dict[str, Any]:
    """The episode cache the command line names (``--cache``), for the units' inputs ({} where the
    study has no such option): where its episodes are kept, not what its results depend on."""
    cache = getattr(args, "cache", None)
    return {} if cache is None else {"cache": str(cache)}


def episode_cache(key: dict[str, Any]) -> Path:
    """The episode cache a unit's key and inputs (:func:`cache_inputs`) name; the comparison's
    default cache where they name none."""
    from odolab.reporting.pipeline import DEFAULT_CACHE

    return Path(key["cache"]) if "cache" in key else DEFAULT_CACHE


def mesh_scenes(args: Any, default_out: str):
    """The test split of the mesh files the study's ``--scenes`` names (every file read first;
    :class:`odolab.sim.mesh_scenes.SceneFiles`), or None without it; such a report needs its own
    ``--out`` (not ``default_out``). ``UsageError`` in one line."""
    from odolab.cli import UsageError
    from odolab.cli.args import scenes_of

    if getattr(args, "scenes", None) is not None and args.out is None:
        raise UsageError(f"--scenes: the report of episodes in mesh files needs its own --out (not {default_out})")
    return scenes_of(args, getattr(args, "argv", None))


def scene_key(scenes) -> dict[str, Any]:
    """What a unit's result depends on of mesh ``scenes`` (their digests and reading settings; {}
    for none), for its key."""
    return {} if scenes is None else {"scenes": scenes.identity()}


def scene_inputs(scenes) -> dict[str, Any]:
    """Where mesh ``scenes`` lie, for a unit's inputs ({} for none)."""
    return {} if scenes is None else {"scene_files": list(scenes.files)}


def scenes_of_key(key: dict[str, Any]):
    """The mesh scenes a unit's key and inputs (:func:`scene_key`, :func:`scene_inputs`) name, or None."""
    from odolab.sim.mesh_scenes import SceneFiles

    recorded = key.get("scenes")
    return None if recorded is None else SceneFiles(tuple(key["scene_files"]), **recorded)


def write_reports_index(reports: Path) -> Path:
    """``reports/index.html`` (:func:`studies.reports_index.write_reports_index`: relative,
    percent-encoded links to the report pages found there)."""
    from studies.reports_index import write_reports_index as write

    return write(reports)
