"""Helpers shared by the text-table trajectory formats: strict reading and number formatting."""

from __future__ import annotations

import math
import os

import numpy as np

from odolab.io.errors import FileFormatError
from odolab.io.inputs import missing, special_kind


def read_lines(path: str | os.PathLike) -> list[str]:
    """All lines of a UTF-8 text file (a byte-order mark at its start is dropped); OS and decoding
    problems become :class:`FileFormatError`, as does a pipe or a device (e.g. a link to
    ``/dev/zero``), which is never opened: reading it would block or never end."""
    _refuse_special(path)
    try:
        with open(path, encoding="utf-8-sig") as f:
            return f.read().splitlines()
    except FileNotFoundError:
        raise FileFormatError(path, None, missing(path)) from None
    except IsADirectoryError:
        raise FileFormatError(path, None, "is a directory, not a file") from None
    except UnicodeDecodeError as exc:
        raise FileFormatError(path, None, f"not a text file ({exc.reason})") from None
    except OSError as exc:
        raise FileFormatError(path, None, (exc.strerror or str(exc)).lower()) from None


def _refuse_special(path: str | os.PathLike) -> None:
    """:class:`FileFormatError` when ``path`` is (a link to) a pipe, device or socket (found by
    ``stat``, without opening it); a missing path or a folder is left to ``open`` to report."""
    try:
        kind = special_kind(os.stat(path).st_mode)
    except OSError:
        return
    if kind is not None:
        link = f"a link to {os.readlink(path)}, " if os.path.islink(path) else ""
        raise FileFormatError(path, None, f"is {link}{kind}, not a regular file")


def read_numeric_rows(path: str | os.PathLike, n_cols: int, layout: str) -> tuple[np.ndarray, np.ndarray]:
    """Rows of exactly ``n_cols`` finite numbers, skipping blank lines and ``#`` comments.

    Returns ``(values (N, n_cols) float64, line_numbers (N,) int, 1-based)``. ``layout`` names the
    expected columns in error messages (e.g. ``"t tx ty tz qx qy qz qw"``).
    """
    rows: list[list[float]] = []
    line_nos: list[int] = []
    for no, line in enumerate(read_lines(path), start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        fields = text.split()
        if len(fields) != n_cols:
            raise FileFormatError(path, no, f"expected {n_cols} columns, got {len(fields)} (layout: {layout})")
        try:
            values = [float(v) for v in fields]
        except ValueError:
            bad = next(i for i, v in enumerate(fields) if not _is_number(v))
            raise FileFormatError(path, no, f"column {bad + 1}: {fields[bad]!r} is not a number") from None
        for i, v in enumerate(values):
            if not math.isfinite(v):
                raise FileFormatError(path, no, f"column {i + 1}: value {fields[i]!r} is not finite")
        rows.append(values)
        line_nos.append(no)
    if not rows:
        raise FileFormatError(path, None, "no poses (the file is empty or only has comments)")
    return np.array(rows, dtype=np.float64), np.array(line_nos, dtype=np.int64)


#: Columns of a pose line, per format: TUM ``t tx ty tz qx qy qz qw``, KITTI a row-major 3x4 matrix.
FORMAT_COLUMNS = {"tum": 8, "kitti": 12}


def infer_format(path: str | os.PathLike) -> str:
    """``"tum"`` or ``"kitti"``, from the column count of the first pose line of trajectory file
    ``path`` (8 or 12; blank lines and ``#`` comments skipped). :class:`FileFormatError` naming the
    file when it holds no pose line, or its first one has another count, or its extension names
    the other format (``.tum``, ``.kitti``)."""
    for no, line in enumerate(read_lines(path), start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        count = len(text.split())
        fmt = next((f for f, n in FORMAT_COLUMNS.items() if n == count), None)
        if fmt is None:
            raise FileFormatError(
                path, no, f"cannot tell the trajectory format: expected 8 columns (TUM) or 12 (KITTI), got {count}"
            )
        named = os.path.splitext(os.fspath(path))[1].lower().lstrip(".")
        if named in FORMAT_COLUMNS and named != fmt:
            raise FileFormatError(
                path, no, f"named .{named} but its lines have {count} columns, as {fmt.upper()} files do"
            )
        return fmt
    raise FileFormatError(path, None, "no poses (the file is empty or only has comments)")


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def format_rows(values: np.ndarray) -> str:
    """Space-separated rows with the shortest exact (round-trip) decimal form of each number."""
    return "".join(" ".join(repr(float(v)) for v in row) + "\n" for row in values)
