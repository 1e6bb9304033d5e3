"""Atomic file writes: readers never see a half-written file, and a failed write leaves the old one.

Files get the permissions an ordinary ``open(path, "w")`` would give (``0o666`` minus the
process umask), not the ``0o600`` of a bare temporary file.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import tempfile
from collections.abc import Iterator
from typing import IO, Any


def _umask() -> int:
    """The process umask, read without changing it where the OS allows (Linux ``/proc``)."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)  # elsewhere: read by setting, then restore at once
    os.umask(mask)
    return mask


@contextlib.contextmanager
def _temporary_beside(path: str, suffix: str) -> Iterator[str]:
    """A temporary file name in ``path``'s folder, moved onto ``path`` when the block succeeds
    (with umask-honouring permissions) and removed when it fails. A symbolic link is written
    through (its target is replaced, the link stays); a device, pipe or socket is refused
    (``ValueError``), never replaced by a regular file."""
    path = os.path.realpath(path)
    if os.path.exists(path) and not os.path.isfile(path) and not os.path.isdir(path):
        raise ValueError(f"{path}: not a regular file (a device, pipe or socket); refusing to replace it")
    directory = os.path.dirname(path)
    fd, tmp = tempfile.mkstemp(dir=directory, prefix="." + os.path.basename(path) + ".", suffix=suffix)
    os.close(fd)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "wb") -> Iterator[IO]:
    """``open`` for writing (``"w"`` text UTF-8 or ``"wb"``) whose content replaces ``path`` only
    when the block ends without an exception (flushed and fsynced first)."""
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_open: mode must be 'w' or 'wb', got {mode!r}")
    with (
        _temporary_beside(os.fspath(path), ".tmp") as tmp,
        open(tmp, mode, **({"encoding": "utf-8"} if mode == "w" else {})) as f,
    ):
        yield f
        f.flush()
        os.fsync(f.fileno())


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` to ``path`` via a temporary file in the same directory and ``os.replace``.

    Readers never see a half-written file; on failure the previous file (if any) is untouched.
    """
    with atomic_open(path, "w") as f:
        f.write(text)


def save_figure_atomic(fig, path: str | os.PathLike, dpi: int = 110) -> None:
    """``fig.savefig`` into a temporary file beside ``path``, then ``os.replace``."""
    path = os.fspath(path)
    with _temporary_beside(path, os.path.splitext(path)[1] or ".png") as tmp:
        fig.savefig(tmp, dpi=dpi, bbox_inches="tight")


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` like :func:`write_text_atomic` (replaced whole, or not at all)."""
    with atomic_open(path, "wb") as f:
        f.write(data)


def _json_safe(value: Any) -> Any:
    """``value`` with every non-finite float (Python or numpy) replaced by ``None``."""
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_json_atomic(path: str | os.PathLike, value: Any, indent: int = 1) -> None:
    """``value`` as JSON, written like :func:`write_text_atomic`. JSON has no NaN or infinity: such
    floats (a rate too fast to time, an error of an odometer with no valid step) are written as null,
    so that browsers, jq and strict parsers read the file; numpy scalars are written as numbers."""
    write_text_atomic(path, json.dumps(_json_safe(value), indent=indent, default=float, allow_nan=False))
