"""odolab.io.atomic against hostile disks (issue 56): a full disk names the file and leaves nothing
half-written, a link can be replaced instead of written through, dead writers' temporary files go;
outputs honour the umask, JSON holds no NaN, and a device or a pipe is never replaced."""

from __future__ import annotations

import errno
import fcntl
import os
import re
import stat

import numpy as np
import pytest

from odolab.io import atomic
from tests.helpers import one_line_error

TEMPORARY = re.compile(r"\.[a-z]+\.txt\.[A-Za-z0-9_]+\.tmp")


@pytest.mark.parametrize("where", ["write", "fsync", "replace"])
def test_a_full_disk_names_the_file_and_keeps_the_old_one(tmp_path, monkeypatch, where):
    path = tmp_path / "table.csv"
    path.write_text("old")

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    if where != "write":
        monkeypatch.setattr(atomic.os, where, full)
    with pytest.raises(OSError) as exc, atomic.atomic_open(path, "w") as f:
        if where == "write":
            full()
        f.write("new")
    assert exc.value.errno == errno.ENOSPC and exc.value.filename == str(path)
    assert str(path) in str(exc.value)
    monkeypatch.undo()
    assert path.read_text() == "old" and os.listdir(tmp_path) == ["table.csv"]


def test_an_unwritable_folder_names_the_file_not_a_temporary_one(tmp_path, monkeypatch):
    def denied(*args, **kwargs):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(tmp_path / ".x.tmp"))

    monkeypatch.setattr(atomic.tempfile, "mkstemp", denied)
    with pytest.raises(PermissionError) as exc:  # the same subclass, so callers catch it as before
        atomic.write_text_atomic(tmp_path / "report.html", "x")
    assert exc.value.filename == str(tmp_path / "report.html")


def test_a_link_is_written_through_or_with_follow_links_false_replaced(tmp_path):
    target, link = tmp_path / "elsewhere" / "t.npz", tmp_path / "link.npz"
    target.parent.mkdir()
    link.symlink_to(target)  # a link to nothing
    with atomic.atomic_open(link, "wb", follow_links=False) as f:
        f.write(b"data")
    assert not os.path.lexists(target) and not link.is_symlink() and link.read_bytes() == b"data"
    other = tmp_path / "other.txt"
    other.symlink_to(target)
    atomic.write_text_atomic(other, "through")  # the default: through the link, which stays
    assert other.is_symlink() and target.read_text() == "through"


def _old(path):
    path.write_text("half")
    os.utime(path, (0, 0))
    return path


def test_only_unheld_old_temporary_files_of_the_pattern_are_removed(tmp_path):
    dead = _old(tmp_path / ".table.txt.abc123.tmp")
    held = _old(tmp_path / ".other.txt.def456.tmp")
    young = tmp_path / ".young.txt.ghi789.tmp"
    young.write_text("being written")
    mine = _old(tmp_path / "notes.txt")
    link = tmp_path / ".link.txt.jkl012.tmp"
    link.symlink_to(mine)
    os.utime(link, (0, 0), follow_symlinks=False)
    with open(held, "rb") as writer:
        fcntl.flock(writer, fcntl.LOCK_EX)
        assert atomic.remove_stale_temporaries(tmp_path, TEMPORARY) == [dead]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in (held, young, mine, link))
    assert atomic.remove_stale_temporaries(tmp_path / "missing", TEMPORARY) == []


def test_outputs_honour_the_umask(tmp_path):
    from odolab.io.atomic import atomic_open, write_text_atomic

    old = os.umask(0o027)
    try:
        write_text_atomic(tmp_path / "a.txt", "x")
        with atomic_open(tmp_path / "b.bin") as f:
            f.write(b"y")
    finally:
        os.umask(old)
    for name in ("a.txt", "b.bin"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o640


def test_json_reports_have_no_nan(tmp_path):
    """JSON has no NaN: a rate too fast to time (bench) or a missing own error (noise study) becomes
    null, so browsers and jq can read the file."""
    import json

    from odolab.io.atomic import write_json_atomic

    report = {
        "odometers": [
            {"odometer": "action-prior", "steps_per_s": float("nan")},
            {"odometer": "icp", "steps_per_s": 18.5, "fails": np.float64("inf")},
        ]
    }
    write_json_atomic(tmp_path / "r.json", report)
    text = (tmp_path / "r.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text)["odometers"][0]["steps_per_s"] is None
    assert json.loads(text)["odometers"][1] == {"odometer": "icp", "steps_per_s": 18.5, "fails": None}


def test_atomic_writes_go_through_links_and_never_replace_devices_or_pipes(tmp_path):
    import os

    from odolab.io.atomic import write_text_atomic

    target = tmp_path / "target.json"
    target.write_text("{}")
    link = tmp_path / "link.json"
    link.symlink_to(target)
    write_text_atomic(link, "new")
    assert link.is_symlink() and target.read_text() == "new"
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match="not a regular file"):
        write_text_atomic(fifo, "x")
    assert not fifo.is_file() and fifo.exists()
    one_line_error("odolab.bench", "--only", "evaluate", "--json", fifo, words="is not a regular file")
    one_line_error("odolab.bench", "--only", "evaluate", "--json", "/dev/null", words="is not a regular file")
