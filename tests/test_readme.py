"""The README's and docs' claims: code that runs as written, tables equal to the reports they quote,
commands that exist, links that resolve, and pages that read as a reference, not a history."""

import csv
import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from odolab import api

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
PAGES = [README, *sorted(DOCS.glob("*.md"))]


def table_rows(text: str, header_start: str) -> list[list[str]]:
    """The body rows of the first Markdown table whose header line starts with ``header_start``."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(header_start))
    rows = []
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        rows.append([cell.strip() for cell in line.strip().strip("|").split("|")])
    return rows


def number(cell: str) -> float:
    return float(re.sub(r"[*%]", "", cell).split()[0])


def test_add_an_odometer_snippet_runs():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.DOTALL)
    snippet = next(b for b in blocks if "register_odometer(" in b)
    exec(compile(snippet, "README.md", "exec"), {"__name__": "readme_snippet"})  # noqa: S102 - the README's own snippet
    odo = api.load_odometer("nominal")
    frame = api.Frame(np.zeros((2, 2, 3), np.uint8), np.zeros((2, 2), np.float32))
    assert odo.step(frame, frame, api.Action.MOVE_FORWARD).planar == pytest.approx([0.0, 0.25, 0.0])
    assert not odo.step(frame, frame, None).valid


def test_readme_names_the_two_commands():
    text = README.read_text()
    assert "pip install torch==2.13.0" in text and 'pip install -e ".[test]"' in text
    assert "python -m odolab.compare" in text and "\npytest\n" in text


def test_readme_headline_table_is_the_reports():
    """README's "What it found": the error columns are reports/compare-test-20x100/table.csv's,
    the success column reports/navigation/nav.csv's."""
    compare = {r["odometer"]: r for r in csv.DictReader((ROOT / "reports/compare-test-20x100/table.csv").open())}
    nav = {r["odometer"]: r for r in csv.DictReader((ROOT / "reports/navigation/nav.csv").open())}
    rows = table_rows(README.read_text(), "| odometer | dx | dz | dyaw | ATE m |")
    assert len(rows) >= 8
    for name_cell, dx, dz, dyaw, ate, failed, success in rows:
        name = name_cell.split(" (")[0]
        if dx != "-":
            row = compare[name]
            for cell, key in ((dx, "dx"), (dz, "dz"), (dyaw, "dyaw"), (ate, "ate_m")):
                assert number(cell) == pytest.approx(float(row[key]), abs=0.006), (name, key)
            assert number(failed) == pytest.approx(100 * float(row["failure_share"]), abs=0.5), name
        n = nav[name]
        low, high = re.findall(r"[\d.]+", success.split("[")[1])
        assert (number(success), float(low), float(high)) == pytest.approx(
            (float(n["success"]), float(n["success_low"]), float(n["success_high"])), abs=0.006
        ), name


def test_results_page_table_is_the_report():
    """docs/results.md's 20 x 100 table: every error column and the failed steps of table.csv."""
    compare = {r["odometer"]: r for r in csv.DictReader((ROOT / "reports/compare-test-20x100/table.csv").open())}
    rows = table_rows((DOCS / "results.md").read_text(), "| odometer | dx | dz | dyaw | ATE m | drift m |")
    assert len(rows) == len(compare)
    for name_cell, dx, dz, dyaw, ate, drift, failed in rows:
        row = compare[name_cell.split(" (")[0]]
        for cell, key, tol in (
            (dx, "dx", 0.006),
            (dz, "dz", 0.006),
            (dyaw, "dyaw", 0.006),
            (ate, "ate_m", 6e-4),
            (drift, "drift_m", 6e-4),
        ):
            assert number(cell) == pytest.approx(float(row[key]), abs=tol), (name_cell, key)
        assert int(failed.split()[0]) == int(row["failures"]), name_cell


def test_navigation_page_table_is_the_report():
    """docs/navigation.md quotes reports/navigation/nav.md's table line for line."""
    page = (DOCS / "navigation.md").read_text().splitlines()
    for line in (ROOT / "reports/navigation/nav.md").read_text().splitlines():
        if line.startswith("| ") and not line.startswith("|---"):
            assert line in page, line


@pytest.mark.slow
def test_readme_defaults_are_compares():
    """The defaults README's "Run" states: episodes, --max-steps and the odometers."""
    text = README.read_text()
    run = text[text.index("## Run") : text.index("## Test")]
    helptext = " ".join(
        subprocess.run(
            [sys.executable, "-m", "odolab.compare", "--help"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.split()
    )
    episodes = re.search(r"`--episodes (\d+)`", run).group(1)
    max_steps = re.search(r"`--max-steps (\d+)`", run).group(1)
    assert f"number of episodes, [1, 1000] (default {episodes})" in helptext
    assert f"(default {max_steps})" in helptext.split("--max-steps MAX_STEPS", 2)[-1][:80]
    named = re.search(r"every registered odometer: (.*?)\n\(choose", run, flags=re.DOTALL).group(1)
    listed = re.findall(r"`([a-z0-9-]+)`", named)
    default = re.search(r"\(default: all of (.*?)\)", helptext).group(1).replace("- ", "-")
    assert listed == [n.strip() for n in default.split(",")]


def test_every_readme_command_exists():
    """Each `python -m MODULE` in README's command table is a module that can be run, and each
    `odolab NAME` beside it is the subcommand `odolab --help` pairs with that module."""
    rows = table_rows(README.read_text(), "| command | or | what it does | reference |")
    modules = [m for row in rows for m in re.findall(r"`python -m ([\w.]+)`", row[0])]
    assert len(modules) >= 15
    for module in modules:
        assert importlib.util.find_spec(module) is not None, module
    odolab = Path(sys.executable).with_name("odolab")  # the console script the package installs
    listing = subprocess.run([str(odolab), "--help"], capture_output=True, text=True, check=True).stdout
    pairs = dict(re.findall(r"^  (\S+) .*\(python -m ([\w.]+)\)$", listing, flags=re.MULTILINE))
    studies = subprocess.run([str(odolab), "study", "--help"], capture_output=True, text=True, check=True).stdout
    pairs |= {
        f"study {n}": m for n, m in re.findall(r"^  (\S+) .*\(python -m ([\w.]+)\)$", studies, flags=re.MULTILINE)
    }
    named = {
        re.search(r"`odolab ([\w -]+)`", row[1]).group(1): re.search(r"`python -m ([\w.]+)`", row[0]).group(1)
        for row in rows
        if row[1]
    }
    assert named == {n: m for n, m in pairs.items() if n != "study"}  # each study by its name


def slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_links_resolve(page):
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.DOTALL)
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if re.match(r"[a-z]+://", target):
            continue
        path, _, anchor = target.partition("#")
        file = (page.parent / path).resolve() if path else page
        if file == DOCS / "training.md" and not file.exists():
            continue  # the training page is written apart from this one
        assert file.exists(), f"{page.name}: {target}"
        if anchor and file.suffix == ".md":
            headings = re.findall(r"^#+ (.*)$", file.read_text(), flags=re.MULTILINE)
            assert anchor in {slug(h) for h in headings}, f"{page.name}: {target}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_pages_are_a_reference_not_a_history(page):
    text = page.read_text()
    prose = re.sub(r"`[^`]+`", "", re.sub(r"```.*?```", "", text, flags=re.DOTALL))
    for words in ("former", "earlier session", "earlier run", "not committed", "previous session"):
        assert words not in prose.lower(), f"{page.name}: {words!r}"
    hashes = [h for h in re.findall(r"\b[0-9a-f]{7,40}\b", text) if re.search(r"[a-f]", h) and re.search(r"\d", h)]
    assert not hashes, f"{page.name}: commit-like {hashes}"
