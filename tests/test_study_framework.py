"""studies.framework (definitions, saved results keyed by what they depend on, reports) and the
e_table study at its ci scale; the command-line checks every study shares (--out, --redraw,
--ray-address, a stopped run resumed), with e_table standing for them."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from odolab.cli import UsageError
from odolab.cli.study import command, study
from odolab.core.parallel import SERIAL
from studies import e_table, framework, reports_index
from tests.helpers import refused


def test_a_result_is_reused_only_for_the_same_key(tmp_path: Path):
    store = framework.ResultStore(tmp_path / "results")
    unit = framework.Unit("a", {"odometer": "icp", "seed": 0})
    assert store.get(unit) is None
    store.put(unit, {"value": 1.5})
    assert store.get(unit) == {"value": 1.5}
    other = framework.Unit("a", {"odometer": "icp", "seed": 1})
    assert store.get(other) is None
    path = tmp_path / "results" / f"{unit.digest}.json"
    doc = json.loads(path.read_text())
    doc["key"]["seed"] = 7  # a file whose key does not match its name: not this unit's result
    path.write_text(json.dumps(doc))
    assert store.get(unit) is None
    path.write_text("{not json")
    assert store.get(unit) is None


def test_units_run_once_and_redraw_computes_nothing(tmp_path: Path):
    store = framework.ResultStore(tmp_path)
    units = [framework.Unit(f"u{k}", {"k": k}) for k in range(3)]
    first = framework.run_units(_square, units, store, execution=SERIAL)
    assert first.results == {"u0": 0, "u1": 1, "u2": 4} and sorted(first.computed) == ["u0", "u1", "u2"]
    again = framework.run_units(_square, [*units, framework.Unit("u3", {"k": 3})], store, execution=SERIAL, redraw=True)
    assert again.computed == [] and again.missing == ["u3"] and again.results["u2"] == 4


def test_run_phases_computes_each_result_s_followers_and_reads_saved_ones(tmp_path: Path):
    store = framework.ResultStore(tmp_path)
    first = [framework.Unit(f"a{k}", {"k": k}) for k in (1, 2, 3)]
    saved = []

    def later(before):  # a follower of each result of the first phase: its value's negative
        return [framework.Unit(f"b{label}", {"k": -v}) for label, v in before[0].results.items()]

    phases = [
        framework.Phase(_square, lambda _before: first, saved=lambda u, v: saved.append((u.label, v))),
        framework.Phase(_square, later),
    ]
    only_small = lambda u: u.key["k"] < 3
    a, b = framework.run_phases(phases, store, execution=SERIAL, only=only_small)
    assert a.results == {"a1": 1, "a2": 4} and a.missing == ["a3"] and saved == [("a1", 1), ("a2", 4)]
    assert b.results == {"ba1": 1, "ba2": 16} and b.computed == ["ba1", "ba2"]
    a, b = framework.run_phases(phases, store, execution=SERIAL)  # a3 now, and its follower; the rest read
    assert a.computed == ["a3"] and b.computed == ["ba3"] and b.results["ba3"] == 81 and len(saved) == 3
    a, b = framework.run_phases(phases, store, execution=SERIAL, redraw=True)
    assert a.computed == b.computed == [] and len(b.results) == 3


def test_a_report_names_the_machines_its_units_ran_on_not_the_one_that_redraws(tmp_path: Path):
    store = framework.ResultStore(tmp_path)
    units = [framework.Unit(f"u{k}", {"k": k}) for k in range(3)]
    first = framework.run_units(_square, units, store, execution=SERIAL)
    here = framework.machine()
    assert first.machines == {here: 3}
    assert framework.machines([first]) == f"{here} (all 3 units)"
    for k, where in ((0, "Another  CPU,\n64 cores "), (1, None)):  # one ran elsewhere (odd spaces); one never said
        path = tmp_path / f"{units[k].digest}.json"
        doc = json.loads(path.read_text())
        doc["result"].pop("machine")
        if where:
            doc["result"]["machine"] = where
        path.write_text(json.dumps(doc))
    again = framework.run_units(_square, units, store, execution=SERIAL, redraw=True)
    first_two = sorted(["Another CPU, 64 cores", here])  # one unit each: by name
    assert framework.machines([again]) == (
        f"{first_two[0]} (1 of 3 units); {first_two[1]} (1 of 3 units); machine not recorded (1 of 3 units)"
    )
    assert framework.machines([framework.Outcome()]) == here
    assert framework.machines([framework.Outcome(machines={"": 2})]) == "not recorded (all 2 units)"


def _square(key: dict) -> int:
    return key["k"] ** 2


def test_study_definitions_are_checked(tmp_path: Path):
    (tmp_path / "s.toml").write_text('title = "t"\n[scales.ci]\na = 1\n[scales.cpu]\na = 2\n')
    with pytest.raises(ValueError, match=r"s.toml: scales: expected the tables ci, cpu, paper"):
        framework.load_study("s", tmp_path)
    (tmp_path / "s.toml").write_text('title = "t"\n[scales.ci]\na = 1\n[scales.cpu]\na = 2\n[scales.paper]\nb = 3\n')
    with pytest.raises(ValueError, match=r"scales.paper: expected the keys a"):
        framework.load_study("s", tmp_path)
    assert framework.load_study("e_table").at("ci")["seeds"] == [0, 1]


@pytest.mark.slow
def test_e_table_at_ci_scale_reports_and_resumes(tmp_path: Path, capsys):
    out = tmp_path / "e"
    args = ["--scale", "ci", "--out", str(out), "--serial", "--quiet"]
    assert study("e-table", args) == 0
    assert {"index.html", "table.csv", "table.md", "errors.png", "manifest.txt", "results"} <= {
        p.name for p in out.iterdir()
    }
    rows = (out / "table.csv").read_text().splitlines()
    assert rows[0].startswith("family,odometer,action,seeds,steps,dx,dx_sd") and len(rows) > 3
    assert {r.split(",")[0] for r in rows[1:]} == {"boxes", "free"}
    said = capsys.readouterr().out
    assert "16 units computed" in said and f"open {out.resolve() / 'index.html'}" in said  # the page to open, named
    assert study("e-table", args) == 0  # everything saved: nothing computed again
    assert "0 units computed" in capsys.readouterr().out
    html = (out / "index.html").read_text()
    assert "E1 (15.9, 21.3, 8.51)" in html and "Against the paper" in html
    md = (out / "table.md").read_text()
    as_used = [line for line in md.splitlines() if "boxes: " in line and ", as used: ours" in line]
    assert len(as_used) == 3 and all("the paper's order E2 < E1" in line for line in as_used), md  # E2 lower in each
    assert len([line for line in md.splitlines() if ", the paper's protocol: ours" in line]) == 6
    assert len([line for line in md.splitlines() if ", boxes -> free (x 1e-2, as used): dx " in line]) == 4


def test_a_folder_of_the_users_own_files_is_refused(tmp_path: Path):
    (tmp_path / "thesis.docx").write_text("mine")
    with pytest.raises(UsageError, match="holds files odolab did not write"):
        study("e-table", ["--scale", "ci", "--out", str(tmp_path), "--serial", "--quiet"])
    assert (tmp_path / "thesis.docx").read_text() == "mine"


def _page(path: Path, title: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"<!doctype html><html><head><title>{title}</title></head><body></body></html>")


def test_the_reports_index_lists_every_page_at_any_depth(tmp_path: Path):
    reports = tmp_path / "reports"
    _page(reports / "e-table" / "index.html", "Errors &amp; seeds")
    _page(reports / "navigation" / "report.html", "odolab navigation")
    _page(reports / "fusion" / "classical" / "report.html", "odolab compare")
    (reports / "simcard").mkdir()
    (reports / "simcard" / "card.md").write_text("# card")
    _page(tmp_path / "elsewhere" / "index.html", "not a report here")
    (reports / "linked").symlink_to(tmp_path / "elsewhere")
    page = framework.write_reports_index(reports).read_text()
    assert '<a href="e-table/index.html">e-table</a>: Errors &amp; seeds' in page
    assert '<a href="navigation/report.html">navigation</a>: odolab navigation' in page
    assert '<a href="fusion/classical/report.html">fusion/classical</a>: odolab compare' in page
    assert '<a href="simcard/card.md">card.md</a>' in page and "Folders without a page" in page
    assert "not a report here" not in page and 'href="index.html"' not in page  # no link, not itself
    assert framework.write_reports_index(reports).read_text() == page  # its own index is no report


def test_a_report_among_the_default_reports_refreshes_their_index(tmp_path: Path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    report = framework.Report("A study", [], ["a"], [{"a": 1.5}], {}, [], "cmd", "machine", 0.0)
    framework.write_report(report, tmp_path / "elsewhere" / "s", owner="study s")
    assert not (tmp_path / "elsewhere" / "index.html").exists()  # nothing outside --out
    framework.write_report(report, framework.DEFAULT_REPORTS / "s", owner="study s")
    assert '<a href="s/index.html">s</a>: A study' in (tmp_path / "reports" / "index.html").read_text()


def test_the_reports_index_command(tmp_path: Path, capsys):

    _page(tmp_path / "n" / "report.html", "odolab navigation")
    assert command("reports-index", ["--reports", str(tmp_path)]) == 0
    assert "odolab navigation" in (tmp_path / "index.html").read_text()
    assert command("reports-index", ["--reports", str(tmp_path / "none")]) == 2
    assert "not a folder" in capsys.readouterr().err


def test_the_committed_index_links_every_committed_report_page():
    reports = framework.HERE.parent / "reports"
    index = (reports / "index.html").read_text()
    pages = [p for name in reports_index.PAGE_NAMES for p in reports.rglob(name) if p != reports / "index.html"]
    assert pages and (reports / "navigation" / "report.html") in pages
    for p in pages:
        assert f'href="{p.relative_to(reports).as_posix()}"' in index, f"run python -m studies.reports_index: {p}"


def test_e_table_scale_fields_are_checked():
    base = framework.load_study("e_table")
    for field, bad, words in [
        ("seeds", [0, 0], "scales.ci: seeds must hold no value twice, got [0, 0]"),
        ("seeds", [0, -1], "scales.ci: seeds[1] must be a whole number in [0, 4294967295], got -1"),
        ("episodes", 0, "scales.ci: episodes must be in [1, 1000], got 0"),
        ("odometers", [], "scales.ci: odometers must hold at least 1 item, got []"),
    ]:
        config = framework.StudyConfig(
            base.name, base.title, {**base.scales, "ci": {**base.at("ci"), field: bad}}, base.path
        )
        with pytest.raises(ValueError) as exc:
            framework.scale_params(config, "ci", e_table.Scale)
        assert str(exc.value) == f"{base.path}: {words}"
    assert framework.scale_params(base, "cpu", e_table.Scale).seeds == (0, 1, 2)


def test_missing_units_are_named_as_ranges():
    """A study stopped early leaves thousands of units; the note names runs of them as ranges."""
    from studies.framework import unit_ranges

    labels = [f"navigate row {r} seed 0 episode {e}" for r in (0, 3) for e in range(50)]
    assert unit_ranges(["train row 4", "train row 5", "train row 7", *labels, "u"]) == (
        "104 units: train row 4-5, train row 7, navigate row 0 seed 0 episode 0-49, "
        "navigate row 3 seed 0 episode 0-49, u"
    )
    assert unit_ranges(["u3"]) == "u3" and unit_ranges(["e 2", "e 1"]) == "2 units: e 2, e 1"


def test_a_study_checks_ray_address_and_redraw_before_making_its_folder(tmp_path, capsys):
    """A dead --ray-address was a traceback after --out was made; with --serial it was ignored; --redraw
    on a new folder made it, empty."""
    out = tmp_path / "e"
    for argv, words in [
        (["--ray-address", "127.0.0.1:1"], "--ray-address 127.0.0.1:1: no Ray cluster there"),
        (["--ray-address", "127.0.0.1:1", "--serial"], "exclude each other"),
        (["--redraw"], "--redraw: no saved results in"),
    ]:
        assert command("e-table", ["--scale", "ci", "--out", str(out), *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and words in err, err
        assert not out.exists()


def test_a_study_names_another_commands_folder_once(tmp_path, capsys):
    (tmp_path / "manifest.txt").write_text("# odolab compare\ntable.csv\n")
    (tmp_path / "table.csv").write_text("x")
    assert command("e-table", ["--scale", "ci", "--out", str(tmp_path), "--redraw"]) == 2
    err = capsys.readouterr().err.strip()
    assert "holds the results of odolab compare" in err and err.count(str(tmp_path)) == 1, err


def test_a_saved_study_result_of_the_wrong_shape_is_computed_again(tmp_path):
    from studies import e_table, framework

    store = framework.ResultStore(tmp_path)
    unit = framework.Unit("u", {"k": 2})
    store.put(unit, {"value": {"all": "oops"}, "seconds": 1.0})  # a results file edited by hand
    calls = []

    def fn(key):
        calls.append(key)
        return {"all": {c: 1.0 for c in ("dx", "dz", "dyaw", "dx_own", "dz_own", "dyaw_own", "failure_share")}}

    def shaped(value):
        return e_table.valid_result({"all": {**value["all"], "steps": 3}})

    redrawn = framework.run_units(fn, [unit], store, redraw=True, execution=SERIAL, valid=shaped)
    assert redrawn.missing == ["u"] and not calls
    again = framework.run_units(fn, [unit], store, execution=SERIAL, valid=shaped)
    assert again.computed == ["u"] and calls == [{"k": 2}]
    assert not e_table.valid_result({"all": {"dx": 1.0}}) and not e_table.valid_result([1])


def test_a_study_stopped_before_its_report_resumes_instead_of_refusing_its_folder(tmp_path, monkeypatch, capsys):
    """Killed after some units, before its report: the rerun read 'holds files odolab did not
    write (no manifest.txt)' and could neither resume nor redraw."""
    from studies import framework

    out = tmp_path / "e"
    config = framework.load_study("e_table")

    def stopped(fn, units, store, **kw):
        store.put(units[0], {"value": {"all": {}}, "seconds": 0.0})  # one unit saved, then Ctrl-C
        raise KeyboardInterrupt

    monkeypatch.setattr(framework, "run_units", stopped)
    argv = ["--scale", "ci", "--out", str(out), "--serial", "--quiet"]
    assert command("e-table", argv) == 130
    assert (out / "manifest.txt").read_text() == "# odolab study e_table\n"
    framework.check_out(out, config)  # the rerun may use its folder
    (out / "manifest.txt").unlink()  # a folder left by a run from before the manifest came first
    framework.check_out(out, config)
    assert (out / "manifest.txt").is_file() and len(list((out / "results").iterdir())) == 1


def test_a_study_refusing_redraw_writes_nothing_in_an_empty_folder(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    err = refused(capsys, "e_table", ["--scale", "ci", "--out", str(empty), "--redraw"])
    assert "--redraw: no saved results" in err and list(empty.iterdir()) == []


PROG = "python -m studies.e_table"


CI = ["--scale", "ci", "--serial", "--quiet"]


@pytest.fixture(scope="module")
def ci_run(tmp_path_factory) -> Path:
    """One finished ci run of studies.e_table (copied by the tests that change it)."""
    out = tmp_path_factory.mktemp("e") / "run"
    assert study("e-table", [*CI, "--out", str(out)]) == 0
    return out


def _run(argv: list[str], capsys) -> tuple[int, str]:
    rc = command("e-table", argv)
    return rc, capsys.readouterr().err.strip()


def test_ray_address_auto_without_a_cluster_is_one_line_before_any_folder(tmp_path, monkeypatch, capsys):
    from ray._private import services

    def none_found(addr, temp_dir):
        raise ConnectionError("Could not find any running Ray instance.")

    monkeypatch.setattr(services, "get_ray_address_from_environment", none_found)
    out = tmp_path / "e"
    rc, err = _run(["--scale", "ci", "--quiet", "--ray-address", "auto", "--out", str(out)], capsys)
    assert rc == 2 and err.splitlines() == [
        f"{PROG}: error: --ray-address auto: no running Ray cluster found on this machine; start one (ray start --head) or give host:port"
    ]
    assert not out.exists()


@pytest.mark.slow
def test_a_users_own_reports_index_is_left_alone(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    page = tmp_path / "reports" / "index.html"
    page.parent.mkdir()
    page.write_text("<html>MY OWN PAGE</html>")
    rc, err = _run([*CI, "--out", "reports/e"], capsys)
    assert rc == 0 and page.read_text() == "<html>MY OWN PAGE</html>"
    assert "reports/index.html not refreshed" in err and (tmp_path / "reports" / "e" / "index.html").is_file()


def test_a_users_folder_of_json_files_is_not_taken_for_a_stopped_study(tmp_path, capsys):
    out = tmp_path / "mine"
    (out / "results").mkdir(parents=True)
    (out / "results" / "exp1.json").write_text('{"my": "experiment"}')
    rc, err = _run([*CI, "--out", str(out)], capsys)
    assert rc == 2 and "holds files odolab did not write" in err
    assert sorted(p.name for p in out.rglob("*")) == ["exp1.json", "results"]


@pytest.mark.slow
def test_a_refused_redraw_writes_nothing(ci_run, tmp_path, capsys):
    out = tmp_path / "e"
    shutil.copytree(ci_run / "results", out / "results")  # a run stopped before its report
    rc, err = _run(["--scale", "cpu", "--redraw", "--quiet", "--out", str(out)], capsys)
    assert rc == 2 and "--redraw: no saved results" in err
    assert sorted(p.name for p in out.iterdir()) == ["results"]
    rc, err = _run(["--scale", "ci", "--redraw", "--quiet", "--out", str(out)], capsys)
    assert rc == 0 and (out / "manifest.txt").read_text().startswith("# odolab study e_table")


@pytest.mark.slow
def test_a_result_that_could_not_be_saved_is_refused_before_any_work(ci_run, tmp_path, capsys):
    out = tmp_path / "e"
    shutil.copytree(ci_run, out)
    victim = min((out / "results").iterdir())
    victim.unlink()
    victim.mkdir()
    rc, err = _run([*CI, "--out", str(out)], capsys)
    assert rc == 2 and len(err.splitlines()) == 1
    assert f"{victim}: expected a regular file or nothing, found a folder" in err and "remove it" in err


def test_a_scale_key_that_is_no_field_is_refused():
    from studies import e_table, framework

    base = framework.load_study("e_table")
    config = framework.StudyConfig(
        base.name, base.title, {**base.scales, "ci": {**base.at("ci"), "seed": 3}}, base.path
    )
    with pytest.raises(ValueError) as exc:
        framework.scale_params(config, "ci", e_table.Scale)
    assert str(exc.value).startswith(f"{base.path}: scales.ci: unknown field(s) seed; expected some of episodes")
    assert json.dumps(framework.scale_params(base, "ci", e_table.Scale).seeds) == "[0, 1]"


@pytest.mark.slow
def test_an_out_folder_inside_another_runs_folder_is_refused(ci_run, capsys):
    inner = ci_run / "results" / "mine"
    rc, err = _run([*CI, "--out", str(inner)], capsys)
    assert rc == 2 and err.endswith(
        f"--out {inner}: lies inside the report folder of study e_table (python -m studies.e_table), "
        f"{ci_run}; choose a folder outside it"
    )
    assert not inner.exists()


@pytest.mark.slow
def test_nesting_is_found_through_links_and_before_a_stopped_run_is_claimed(ci_run, tmp_path, capsys):
    link = tmp_path / "link"
    link.symlink_to(ci_run / "results")
    rc, err = _run([*CI, "--out", str(link / "x")], capsys)
    assert (
        rc == 2 and "lies inside the report folder of study e_table" in err and not (ci_run / "results" / "x").exists()
    )
    stopped = ci_run / "copy"  # what a stopped first run leaves, inside another run's folder
    shutil.copytree(ci_run / "results", stopped / "results")
    try:
        rc, err = _run([*CI, "--out", str(stopped)], capsys)
        assert rc == 2 and "lies inside" in err and not (stopped / "manifest.txt").exists()
    finally:
        shutil.rmtree(stopped)
