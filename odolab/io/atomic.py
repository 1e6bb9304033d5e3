"""Atomic file writes: readers never see a half-written file, and a failed write leaves the old one.

Files get the permissions an ordinary ``open(path, "w")`` would give (``0o666`` minus the
process umask), not the ``0o600`` of a bare temporary file.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import math
import os
import re
import stat
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
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


def _naming(exc: OSError, path: str) -> OSError:
    """``exc`` with ``path`` as its file name (a failed ``write`` or ``fsync`` names none, a failed
    ``mkstemp`` its temporary file's): the error then says which file could not be written, e.g.
    ``[Errno 28] No space left on device: 'runs/x/table.csv'``. Same errno, so the same subclass."""
    if exc.errno is None or exc.filename == path:
        return exc
    return OSError(exc.errno, exc.strerror, path)


def _lock_temporary(fd: int) -> None:
    """Hold ``fd``'s temporary file for its writer (``flock``), so that :func:`remove_stale_temporaries`
    tells a live writer's file from a dead one's; a file system without locks: not held."""
    with contextlib.suppress(OSError):
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)


@contextlib.contextmanager
def _temporary_beside(path: str, suffix: str, follow_links: bool = True) -> Iterator[str]:
    """A temporary file name in ``path``'s folder, moved onto ``path`` when the block succeeds
    (with umask-honouring permissions) and removed when it fails. A symbolic link is written
    through (its target is replaced, the link stays), or with ``follow_links`` False replaced
    itself by a regular file (nothing is written where it points); a device, pipe or socket is
    refused (``ValueError``), never replaced by a regular file. The temporary file is locked by
    its writer while it exists. An ``OSError`` (a full disk) names ``path`` and leaves it as it was."""
    given = path
    if follow_links:
        path = os.path.realpath(path)
    else:
        path = os.path.join(os.path.realpath(os.path.dirname(path) or "."), os.path.basename(path))
    replaced_link = not follow_links and os.path.islink(path)
    if not replaced_link and os.path.exists(path) and not os.path.isfile(path) and not os.path.isdir(path):
        raise ValueError(f"{path}: not a regular file (a device, pipe or socket); refusing to replace it")
    try:
        fd, tmp = tempfile.mkstemp(dir=os.path.dirname(path), prefix="." + os.path.basename(path) + ".", suffix=suffix)
    except OSError as exc:
        raise _naming(exc, given) from None
    try:
        _lock_temporary(fd)
        yield tmp
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        named = _naming(exc, given) if isinstance(exc, OSError) else exc
        if named is exc:
            raise
        raise named from exc
    finally:
        os.close(fd)


def remove_stale_temporaries(folder: str | os.PathLike, names: re.Pattern, min_age_s: float = 60.0) -> list[Path]:
    """Delete the temporary files that writers which died (killed, powered off) left in ``folder``:
    regular files whose name ``names`` matches in full, untouched for ``min_age_s`` seconds and locked
    by no live writer (:func:`_temporary_beside` holds its file while writing). Links, folders and
    a file that cannot be opened or locked are left alone; so is everything on a failure: cleaning
    never ends a run. Returns the paths removed."""
    removed: list[Path] = []
    try:
        entries = [e for e in os.scandir(folder) if names.fullmatch(e.name)]
    except OSError:
        return removed
    now = time.time()
    for entry in entries:
        try:
            st = entry.stat(follow_symlinks=False)
            if not stat.S_ISREG(st.st_mode) or now - st.st_mtime < min_age_s:
                continue
            fd = os.open(entry.path, os.O_RDWR | os.O_NOFOLLOW | os.O_NONBLOCK)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # a live writer holds it: BlockingIOError
            if os.fstat(fd).st_ino == os.lstat(entry.path).st_ino:  # still the file examined
                os.unlink(entry.path)
                removed.append(Path(entry.path))
        except OSError:
            pass
        finally:
            os.close(fd)
    return removed


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "wb", *, follow_links: bool = True) -> Iterator[IO]:
    """``open`` for writing (``"w"`` text UTF-8 or ``"wb"``) whose content replaces ``path`` only
    when the block ends without an exception (flushed and fsynced first). A symbolic link at
    ``path`` is written through, or with ``follow_links`` False replaced by the file. An ``OSError``
    (a full disk) names ``path``; nothing half-written is left."""
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_open: mode must be 'w' or 'wb', got {mode!r}")
    with (
        _temporary_beside(os.fspath(path), ".tmp", follow_links) as tmp,
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
