"""odolab/io/inputs.py: a path that is not a regular file is said to be what it is (a pipe, a device,
a folder, a link to one), in one line and without opening it; its users, the text-file reader
(odolab/io/textfiles.py), the TUM RGB-D folder reader (odolab/io/tum_rgbd.py) and evaluate, say so too."""

from __future__ import annotations

import os
import shutil
import signal
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from odolab.cli import run_cli
from odolab.io.errors import FileFormatError
from odolab.io.inputs import not_regular
from odolab.io.textfiles import read_lines
from odolab.io.tum_rgbd import load_tum_sequence

TUM = Path(__file__).parent / "data" / "tum_fr1_xyz_10"
FIRST_RGB = "rgb/1305031102.000000.png"  # on line 4 of rgb.txt


@contextmanager
def _no_hang(seconds: int = 5) -> Iterator[None]:
    """Fail instead of blocking for ever (opening a pipe for reading waits for a writer)."""

    def stop(signum, frame):
        raise TimeoutError("blocked: the pipe or device was opened")

    previous = signal.signal(signal.SIGALRM, stop)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


@pytest.fixture
def fifo(tmp_path: Path) -> Path:
    path = tmp_path / "pipe.png"
    os.mkfifo(path)
    return path


def test_what_is_not_a_regular_file_is_named(tmp_path: Path, fifo: Path):
    (tmp_path / "f.txt").write_text("x")
    (tmp_path / "zero.png").symlink_to("/dev/zero")
    (tmp_path / "gone.png").symlink_to(tmp_path / "nothing")
    assert not_regular(tmp_path / "f.txt") is None
    assert not_regular(fifo) == "is a named pipe (FIFO), not a regular file"
    assert not_regular("/dev/zero") == "is a character device, not a regular file"
    assert not_regular(tmp_path / "zero.png") == "is a link to /dev/zero, a character device, not a regular file"
    assert not_regular(tmp_path) == "is a folder, not a regular file"
    assert not_regular(tmp_path / "none.png") == "no such file"
    assert not_regular(tmp_path / "gone.png").startswith("is a link to nothing")


@pytest.mark.parametrize("kind", ["fifo", "/dev/zero"])
def test_a_text_file_that_is_a_pipe_or_device_is_refused_unopened(tmp_path: Path, fifo: Path, kind: str):
    path = fifo if kind == "fifo" else tmp_path / "gt.txt"
    if kind != "fifo":
        path.symlink_to("/dev/zero")
    with _no_hang(), pytest.raises(FileFormatError) as err:
        read_lines(path)
    words = "a named pipe (FIFO)" if kind == "fifo" else "a link to /dev/zero, a character device"
    assert str(err.value) == f"{path}: is {words}, not a regular file"


@pytest.fixture
def copy(tmp_path: Path) -> Path:
    """A writable copy of the 10-frame TUM sequence (its name says fr1)."""
    dst = tmp_path / "tum_fr1_copy"
    shutil.copytree(TUM, dst)
    return dst


@pytest.mark.parametrize(
    "kind,words",
    [
        ("/dev/zero", "is a link to /dev/zero, a character device, not a regular file"),
        ("fifo", "is a named pipe (FIFO), not a regular file"),
        ("folder", "is a folder, not a regular file"),
        ("missing", "no such file"),
    ],
)
def test_a_tum_image_that_is_no_regular_file_is_named_for_what_it_is(copy: Path, kind: str, words: str):
    image = copy / FIRST_RGB
    image.unlink()
    if kind == "/dev/zero":
        image.symlink_to("/dev/zero")
    elif kind == "fifo":
        os.mkfifo(image)
    elif kind == "folder":
        image.mkdir()
    with _no_hang(), pytest.raises(FileFormatError) as err:
        load_tum_sequence(copy)
    assert str(err.value) == f"{copy / 'rgb.txt'}, line 4: {FIRST_RGB}: {words}"


def test_a_tum_list_file_that_is_a_pipe_is_refused_unopened(copy: Path):
    (copy / "depth.txt").unlink()
    os.mkfifo(copy / "depth.txt")
    with _no_hang(), pytest.raises(FileFormatError, match=r"depth.txt: is a named pipe \(FIFO\), not a regular file"):
        load_tum_sequence(copy)


def test_a_link_to_nothing_is_named_as_one(tmp_path, capsys):
    from odolab.cli.evaluate import main as evaluate
    from odolab.io.inputs import check_regular_file

    dead = tmp_path / "est.txt"
    dead.symlink_to(tmp_path / "gone.txt")
    assert run_cli(evaluate, "python -m odolab.evaluate", [str(dead), str(dead)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith(f"{dead}: is a link to nothing ({tmp_path / 'gone.txt'} does not exist)"), err
    with pytest.raises(ValueError, match="is a link to nothing"):
        check_regular_file(dead)
    with pytest.raises(ValueError, match="no such file"):
        check_regular_file(tmp_path / "never.txt")
