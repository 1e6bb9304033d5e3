"""Open an HTML report in headless Chromium (Debian's ``chromium``) and report what a reader
would meet: images that did not load, tables without rows, console and resource errors."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")

# Injected first in <head>: records errors from the start, then, once everything has loaded,
# writes what it found into the DOM that --dump-dom prints.
_PROBE = """<script>
window.__found = {errors: []};
console.error = (...a) => window.__found.errors.push('console: ' + a.join(' '));
window.addEventListener('error', e => window.__found.errors.push(
  e.target && e.target !== window ? 'resource: ' + (e.target.src || e.target.href) : 'script: ' + e.message), true);
window.addEventListener('load', () => {
  const f = window.__found;
  f.images = [...document.images].map(i => ({src: i.getAttribute('src'), width: i.naturalWidth, done: i.complete}));
  f.tables = [...document.querySelectorAll('table')].map(t => [...t.rows].filter(r => r.querySelector('td')).length);
  const pre = document.createElement('pre'); pre.id = '__found';
  pre.textContent = JSON.stringify(f); document.body.appendChild(pre);
});
</script>"""


def inspect_page(page: Path, timeout: float = 60.0) -> dict:
    """``{"errors": [...], "images": [{"src", "width", "done"}], "tables": [rows per table]}`` of
    ``page`` as loaded by headless Chromium (lazy images made eager so every one is fetched)."""
    page = Path(page).resolve()
    probe = page.with_name(f".browser-check-{page.name}")  # beside it: relative image paths resolve
    text = page.read_text(encoding="utf-8").replace(' loading="lazy"', "")
    probe.write_text(re.sub(r"<head>", "<head>" + _PROBE.replace("\\", "\\\\"), text, count=1), encoding="utf-8")
    try:
        with tempfile.TemporaryDirectory() as profile:
            proc = subprocess.run(
                [
                    CHROMIUM,
                    "--headless",
                    "--no-sandbox",
                    "--disable-gpu",
                    "--disable-background-networking",
                    "--disable-component-update",
                    "--disable-sync",
                    "--no-first-run",
                    f"--user-data-dir={profile}",
                    "--allow-file-access-from-files",
                    "--virtual-time-budget=10000",
                    "--dump-dom",
                    probe.as_uri(),
                ],
                capture_output=True,
                text=True,
                timeout=timeout,
                check=False,
            )
    finally:
        probe.unlink(missing_ok=True)
    match = re.search(r'<pre id="__found">(.*?)</pre>', proc.stdout, re.DOTALL)
    if match is None:
        raise AssertionError(f"the page never finished loading in chromium: {proc.stderr[-2000:]}")
    import html

    return json.loads(html.unescape(match.group(1)))
