"""odolab.cli.args against hostile disks and names (issue 56): a name over 255 bytes, a full disk
while a command writes, a read-only cache: one line and exit 2, never a traceback."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from odolab.cli import run_cli
from odolab.cli.args import NAME_MAX, UsageError, check_cache_dir, disk_error
from odolab.io import atomic

TUM = Path(__file__).parent / "data" / "tum_fr1_xyz_10"


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize("option", ["--out", "--cache"])
def test_a_folder_name_over_255_bytes_is_one_line(tmp_path, capsys, option):
    from odolab.cli.compare import main

    long = tmp_path / ("é" * 130)  # 260 bytes in UTF-8, 130 characters
    assert run_cli(main, "python -m odolab.compare", [option, str(long / "x"), "--quiet"]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith(f"python -m odolab.compare: error: {option}: expected folder and file names of at most")
    assert f"{NAME_MAX} bytes, got one of 260 bytes" in line and len(line) < 300
    assert os.listdir(tmp_path) == []


def test_a_path_over_the_systems_limit_is_one_line(capsys):
    from odolab.cli.compare import main

    deep = "/".join(["d" * 200] * 21)  # every name fits, the whole does not
    assert run_cli(main, "python -m odolab.compare", ["--out", deep]) == 2
    assert "expected a path of at most 4095 bytes" in _one_line(capsys.readouterr().err)


def test_a_disk_error_is_one_line_naming_the_file_and_others_still_raise(capsys):
    def full(argv):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), "runs/x/table.csv")

    assert run_cli(full, "prog", []) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith("prog: error: runs/x/table.csv: no space left on device; nothing half-written")

    def broken(argv):
        raise OSError(errno.EIO, "input/output error")

    with pytest.raises(OSError):  # not a disk's refusal of a write: a bug to see whole
        run_cli(broken, "prog", [])
    assert disk_error(OSError(errno.EDQUOT, "Disk quota exceeded")).startswith("disk quota exceeded; ")


def test_a_full_disk_while_compare_writes_out_is_one_line_and_leaves_nothing_half_written(
    tmp_path, monkeypatch, capsys
):
    from odolab.cli.compare import main

    real, calls = os.fsync, []

    def full(fd: int) -> None:  # the disk fills once the manifest is written
        calls.append(fd)
        if len(calls) > 1:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real(fd)

    out = tmp_path / "out"
    monkeypatch.setattr(atomic.os, "fsync", full)
    argv = ["--tum", str(TUM), "--odometers", "ground-truth", "--out", str(out), "--quiet"]
    assert run_cli(main, "python -m odolab.compare", argv) == 2
    line = _one_line(capsys.readouterr().err)
    assert f"{out / 'table.csv'}: no space left on device; nothing half-written was left" in line
    assert not [p for p in out.rglob("*") if p.name.endswith(".tmp")] and not (out / "table.csv").exists()


def test_a_read_only_cache_is_accepted_and_a_file_is_not(tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    cache.mkdir()
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: False if mode & os.W_OK else real(p, mode))
    check_cache_dir(cache, "--cache")  # read, not refused (root writes anywhere: the check is faked)
    (tmp_path / "file").write_text("x")
    with pytest.raises(UsageError, match="is a file, not a folder"):
        check_cache_dir(tmp_path / "file", "--cache")
    monkeypatch.setattr(os, "access", real)
    check_cache_dir(tmp_path / "new", "--cache")  # made
    assert (tmp_path / "new").is_dir()
