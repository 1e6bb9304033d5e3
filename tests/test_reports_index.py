"""studies/reports_index.py: ``reports/index.html`` links only, relatively, to folders and pages that
exist, each name percent-encoded and HTML-escaped."""

from __future__ import annotations

import html
import os
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest

from studies import reports_index


class _Links(HTMLParser):
    """Every ``href`` of a page, unescaped as a browser reads it."""

    def __init__(self) -> None:
        super().__init__()
        self.hrefs: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.hrefs += [v for k, v in attrs if tag == "a" and k == "href" and v is not None]


def _hrefs(page: str) -> list[str]:
    parser = _Links()
    parser.feed(page)
    return parser.hrefs


def _page(path: Path, title: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"<!doctype html><html><head><title>{title}</title></head><body></body></html>")


@pytest.mark.parametrize("name", ["javascript:alert(1)", 'a"<>&b', "data:text,x", "x y#?%"])
def test_a_folder_name_is_a_relative_link_to_that_folder(tmp_path: Path, name: str):
    reports = tmp_path / "reports"
    _page(reports / name / "report.html", "a page")
    (reports / f"{name}-notes").mkdir()
    (reports / f"{name}-notes" / "n.md").write_text("# notes")
    page = reports_index.write_reports_index(reports).read_text()
    hrefs = _hrefs(page)
    assert len(hrefs) == 3
    for href in hrefs:
        parts = urlsplit(href)
        assert (parts.scheme, parts.netloc, parts.query, parts.fragment) == ("", "", "", ""), href
        assert (reports / unquote(parts.path)).exists(), href  # relative, to what is there
    assert f">{html.escape(name)}</a>" in page  # the text escaped too
    if set(name) & set('<>"&'):
        assert name not in page


def test_names_that_are_not_plain_are_left_out(tmp_path: Path):
    reports = tmp_path / "reports"
    _page(reports / "ok" / "index.html", "fine")
    _page(reports / "two\nlines" / "index.html", "a line break")
    _page(reports / "back\\slash" / "index.html", "a backslash")
    (reports / os.fsdecode(b"not-utf8-\xff")).mkdir()
    (reports / os.fsdecode(b"not-utf8-\xff") / "n.md").write_text("# x")
    page = reports_index.write_reports_index(reports).read_text()
    assert _hrefs(page) == ["ok/index.html"]
    assert "a line break" not in page and "a backslash" not in page and "not-utf8" not in page


def test_plain_names_keep_their_links_as_before(tmp_path: Path):
    reports = tmp_path / "reports"
    _page(reports / "e-table" / "index.html", "Errors &amp; seeds")
    (reports / "simcard").mkdir()
    (reports / "simcard" / "card.md").write_text("# card")
    page = reports_index.write_reports_index(reports).read_text()
    assert '<a href="e-table/index.html">e-table</a>: Errors &amp; seeds' in page
    assert '<li><a href="simcard/">simcard</a>: <a href="simcard/card.md">card.md</a></li>' in page


def test_link_encodes_and_escapes():
    assert reports_index.link(Path("javascript:alert(1)/index.html")) == "javascript%3Aalert%281%29/index.html"
    assert reports_index.link(Path('"<>&'), folder=True) == "%22%3C%3E%26/"
    assert reports_index.link(Path("/etc/passwd")) is None and reports_index.link(Path("a/../b")) is None


def test_a_folder_of_the_users_files_or_a_link_is_refused(tmp_path: Path, capsys):
    """The index is written only into a folder of reports, never into a user's own folder or through a link."""
    from odolab.cli.study import command

    own = tmp_path / "own"
    own.mkdir()
    (own / "mine.md").write_text("mine")
    (tmp_path / "link").symlink_to(own)
    for folder, words in ((own, "holds no report page"), (tmp_path / "link", "is a link")):
        assert command("reports-index", ["--reports", str(folder)]) == 2
        assert words in capsys.readouterr().err
    assert sorted(p.name for p in own.iterdir()) == ["mine.md"]
