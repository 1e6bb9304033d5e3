"""Every HTML report, opened in a real headless browser: no console or resource errors, every
image loads, every table has rows; and the report's content is what a reader needs."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from browser_check import CHROMIUM, inspect_page

from odolab.cli import run_cli
from odolab.compare import main

ROOT = Path(__file__).resolve().parents[1]
# Skipped only off CI, where a developer may lack chromium; in CI (.ci/run installs it) a missing browser fails.
needs_browser = pytest.mark.skipif(
    CHROMIUM is None and not os.environ.get("CI"), reason="chromium is not installed (README set-up)"
)


def assert_readable(page: Path) -> dict:
    found = inspect_page(page)
    assert found["errors"] == [], found["errors"]
    assert found["images"], "no image on the page"
    broken = [i["src"] for i in found["images"] if not i["done"] or i["width"] == 0]
    assert broken == [], f"images that did not load: {broken}"
    assert found["tables"] and all(n > 0 for n in found["tables"]), f"rows per table: {found['tables']}"
    return found


@pytest.fixture(scope="module")
def sim_report(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sim") / "run"
    args = [
        "--odometers",
        "examples.nominal_motion:NominalMotion,ground-truth,action-prior",
        "--episodes",
        "5",
        "--max-steps",
        "8",
        "--serial",
        "--quiet",
        "--no-cache",
        "--out",
        str(out),
    ]
    assert run_cli(main, "odolab.compare", args) == 0
    return out


@pytest.fixture(scope="module")
def tum_report(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("tum") / "run"
    args = [
        "--tum",
        str(ROOT / "tests" / "data" / "tum_fr1_xyz_10"),
        "--odometers",
        "action-prior,ground-truth",
        "--quiet",
        "--out",
        str(out),
    ]
    assert run_cli(main, "odolab.compare", args) == 0
    return out


@pytest.mark.slow
@needs_browser
def test_simulator_report_loads_in_a_browser(sim_report):
    found = assert_readable(sim_report / "report.html")
    gallery = [i["src"] for i in found["images"] if i["src"].endswith("top-down.png")]
    assert len(gallery) == 5  # every sequence's trajectories are reachable, not only the first 4


@needs_browser
def test_tum_report_loads_in_a_browser(tum_report):
    found = assert_readable(tum_report / "report.html")
    assert len(found["tables"]) == 1  # no empty per-action table on real data


@pytest.mark.slow
@needs_browser
@pytest.mark.parametrize("page", sorted((ROOT / "reports").glob("*/report.html")), ids=lambda p: p.parent.name)
def test_committed_reports_load_in_a_browser(page):
    assert_readable(page)


def test_a_broken_page_is_caught(tmp_path):
    if CHROMIUM is None and not os.environ.get("CI"):
        pytest.skip("chromium is not installed")
    (tmp_path / "report.html").write_text(
        '<html><head></head><body><img src="missing.png"><table>'
        "<thead><tr><th>a</th></tr></thead><tbody></tbody></table></body></html>"
    )
    found = inspect_page(tmp_path / "report.html")
    assert found["images"][0]["width"] == 0 and found["tables"] == [0]
    assert any("missing.png" in e for e in found["errors"])


def test_report_reads_well(sim_report, tum_report):
    page = (sim_report / "report.html").read_text()
    assert "``" not in page and ":mod:" not in page and "<code>dx, dz, dyaw</code>" in page  # rendered reST
    assert "ATE, m, RMSE, no alignment" in page and "&plusmn;" in page  # units, alignment, mean +- std
    table = page[page.index("<h2>Summary") :]  # the rows, after the notes that quote the command
    assert table.index("ground-truth (oracle)") < table.index("action-prior (reference)") < table.index("Nominal")
    import csv

    rows = list(csv.DictReader((sim_report / "table.csv").read_text().splitlines()))
    # reference rows first, each group in the given order
    assert [r["odometer"] for r in rows] == ["ground-truth", "action-prior", "examples.nominal_motion:NominalMotion"]
    assert [r["fps"] == "nan" for r in rows] == [True, True, False]  # reference rows are not timed: "-"
    tum = (tum_report / "report.html").read_text()
    assert "Per action" not in tum and "translation error, mm" in tum
    seq = next((sim_report / "trajectories").iterdir())
    names = {p.name for p in seq.iterdir()}
    assert "groundtruth.tum" in names and "ground-truth.tum" not in names  # one name for the truth


@pytest.mark.slow
def test_rerun_removes_what_the_previous_run_owned(tmp_path):
    out = tmp_path / "run"
    base = ["--odometers", "action-prior", "--max-steps", "6", "--serial", "--quiet", "--no-cache", "--out", str(out)]
    assert run_cli(main, "odolab.compare", [*base, "--episodes", "3"]) == 0
    (out / "mine.txt").write_text("the user's own file")
    assert len(list((out / "trajectories").iterdir())) == 3
    assert run_cli(main, "odolab.compare", [*base, "--episodes", "1"]) == 0
    assert len(list((out / "trajectories").iterdir())) == 1  # the older run's episodes are gone
    assert (out / "mine.txt").exists()  # what no run wrote stays
    listed = {line for line in (out / "manifest.txt").read_text().splitlines() if not line.startswith("#")}
    on_disk = {str(p.relative_to(out)) for p in out.rglob("*") if p.is_file()} - {"manifest.txt", "mine.txt"}
    assert listed == on_disk


def test_a_failing_figure_costs_nothing_else(tmp_path, monkeypatch, capsys):
    import odolab.reporting.report

    def broken(*args, **kwargs):
        raise RuntimeError("no room on the canvas")

    monkeypatch.setattr(odolab.reporting.report, "plot_errors", broken)
    out = tmp_path / "run"
    args = [
        "--odometers",
        "action-prior",
        "--episodes",
        "1",
        "--max-steps",
        "6",
        "--serial",
        "--quiet",
        "--no-cache",
        "--out",
        str(out),
    ]
    assert run_cli(main, "odolab.compare", args) == 0
    assert (out / "table.csv").exists() and not (out / "errors.png").exists()
    assert "no room on the canvas" in (out / "report.html").read_text()
    captured = capsys.readouterr()
    assert "action-prior" in captured.out and "errors.png could not be drawn" in captured.err
