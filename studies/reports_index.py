"""``reports/index.html``: a link to every report page under the reports folder, with its title.

    python -m studies.reports_index [--reports reports]

Every study refreshes it when it writes a report there; this command refreshes it after any other
command's report (compare, navigate) was written or removed. A page there that odolab did not write
(another title) is left alone.

Links are relative, to files and folders found under the reports folder (never through a link),
each name percent-encoded (a folder named ``javascript:x`` is a path, not a scheme) and
HTML-escaped; a path with a name that is not a plain folder or file name (control characters, a
backslash, bytes that are not UTF-8) is left out.
"""

from __future__ import annotations

import html
import os
import re
from pathlib import Path
from urllib.parse import quote

#: The reports folder of every odolab command run without --out (relative to the working folder).
DEFAULT_REPORTS = Path("reports")

#: The title of the reports index: a page with another is a user's, never written over.
INDEX_TITLE = "<title>odolab reports</title>"
#: Files named so are report pages; what a report folder holds besides them is listed when it has none.
PAGE_NAMES = ("index.html", "report.html")


def plain_name(name: str) -> bool:
    """Whether ``name`` is a plain file or folder name to link: printable (no control characters
    or line breaks), valid UTF-8, no backslash, not ``.`` or ``..``."""
    if name in ("", ".", "..") or "\\" in name or not name.isprintable():
        return False
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:  # bytes that are not UTF-8, kept by the file system as surrogates
        return False
    return True


def link(relative: Path, folder: bool = False) -> str | None:
    """The ``href`` value, HTML-escaped, of a file (or with ``folder``, a folder) at ``relative``
    below the index: relative, each name percent-encoded (``:`` included, so that no name reads as
    a URL scheme); None when a name on the way is not :func:`plain_name`."""
    if relative.is_absolute() or not relative.parts or not all(plain_name(p) for p in relative.parts):
        return None
    return html.escape(quote(relative.as_posix(), safe="/") + ("/" if folder else ""))


def _report_files(reports: Path) -> list[Path]:
    """Every regular file under ``reports`` (relative), reached through folders only (no links)."""
    found = []
    for root, dirs, files in os.walk(reports):
        dirs[:] = sorted(d for d in dirs if not (Path(root) / d).is_symlink())
        found += [(Path(root) / f).relative_to(reports) for f in sorted(files) if (Path(root) / f).is_file()]
    return [f for f in found if not (Path(reports) / f).is_symlink()]


def _page_title(page: Path) -> str:
    """The ``<title>`` of an HTML page (the folder's name when it has none or cannot be read)."""
    try:
        text = page.read_text(encoding="utf-8", errors="replace")[:100_000]
    except OSError:
        return page.parent.name
    m = re.search(r"<title>(.*?)</title>", text, flags=re.DOTALL | re.IGNORECASE)
    return " ".join(html.unescape(m.group(1)).split()) if m and m.group(1).strip() else page.parent.name


def index_page(reports: Path) -> str:
    """The HTML of ``reports/index.html``: a link to every report page under ``reports`` at any
    depth (``index.html`` or ``report.html``) with its title; then each top-level folder with no
    page, linking its Markdown files (links: :func:`link`)."""
    reports = Path(reports)
    files = [f for f in _report_files(reports) if link(f) is not None]
    pages = [f for f in files if f.name in PAGE_NAMES and f != Path("index.html")]
    items = [
        f'<li><a href="{link(f)}">{html.escape(f.parent.as_posix())}</a>: {html.escape(_page_title(reports / f))}</li>'
        for f in pages
    ]
    with_page = {f.parts[0] for f in pages}
    bare = sorted({f.parts[0] for f in files if len(f.parts) > 1} - with_page)
    others = []
    for top in bare:
        notes = [f for f in files if f.parts[0] == top and f.suffix == ".md"]
        links = ", ".join(f'<a href="{link(f)}">{html.escape(f.relative_to(top).as_posix())}</a>' for f in notes)
        others.append(
            f'<li><a href="{link(Path(top), folder=True)}">{html.escape(top)}</a>{": " + links if links else ""}</li>'
        )
    return (
        f'<!doctype html>\n<html lang="en"><head><meta charset="utf-8">{INDEX_TITLE}'
        "<style>body{font-family:sans-serif;max-width:900px;margin:2em auto;padding:0 1em}li{margin:.3em 0}</style>"
        "</head><body><h1>odolab reports</h1><h2>Report pages</h2><ul>"
        + "".join(items)
        + "</ul>"
        + (f"<h2>Folders without a page</h2><ul>{''.join(others)}</ul>" if others else "")
        + "</body></html>\n"
    )


def write_reports_index(reports: Path) -> Path:
    """Write :func:`index_page` to ``reports/index.html`` (atomically, inside ``reports``); a page
    there that odolab did not write is left alone (:class:`~odolab.io.owned.UnsafeOutputError`)."""
    from odolab.io.atomic import write_text_atomic
    from odolab.io.owned import UnsafeOutputError, owned_path

    page = index_page(Path(reports))
    path = owned_path(reports, "index.html")
    if path.exists() and not is_reports_index(path):
        raise UnsafeOutputError(path, "odolab's reports index", "another page, which is left alone")
    write_text_atomic(path, page)
    return path


def is_reports_index(path: Path) -> bool:
    """Whether ``path`` is a page :func:`write_reports_index` wrote (its title), not a user's own."""
    try:
        return INDEX_TITLE in path.read_text(encoding="utf-8", errors="replace")[:2000]
    except OSError:
        return False


def run(args) -> int:
    """The study as its command line (:mod:`odolab.cli.study`) asks."""
    from odolab.cli import UsageError
    from odolab.io.owned import UnsafeOutputError

    if args.reports.is_symlink():
        raise UsageError(
            f"--reports {args.reports}: is a link; give the folder itself (nothing is written through a link)"
        )
    if not args.reports.is_dir():
        raise UsageError(f"--reports {args.reports}: not a folder")
    pages = [f for f in _report_files(args.reports) if f.name in PAGE_NAMES and len(f.parts) > 1]
    if not pages and not (args.reports / "index.html").is_file():
        raise UsageError(
            f"--reports {args.reports}: holds no report page (no <folder>/index.html or report.html); "
            "expected the folder an odolab command wrote its reports into"
        )
    try:
        path = write_reports_index(args.reports)
    except UnsafeOutputError as exc:
        raise UsageError(f"--reports {args.reports}: {exc}") from None
    print(path)
    return 0


if __name__ == "__main__":  # python -m studies.reports_index: the command line is odolab.cli.study's
    import importlib

    study = importlib.import_module("odolab.cli.study")
    study.exit_process(study.command("reports-index"))
