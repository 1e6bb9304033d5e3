"""Paths a run writes inside the folder it owns, never through a symbolic link out of it.

Every command that writes a folder (compare, simcard, navigate, the studies) asks
:func:`owned_path` for each file it writes and removes files with :func:`remove_owned`: the
relative path must be plain (no ``..``, not absolute), no component below the folder may be a
symbolic link, every folder on the way must be a folder (missing ones are created) and the file
itself must be a regular file or absent. The folder itself may be a link (the user named it);
nothing under it is followed.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path, PurePath

__all__ = ["UnsafeOutputError", "check_owned_folder", "check_owned_path", "owned_path", "remove_owned"]


class UnsafeOutputError(ValueError):
    """A path a run would write or remove that is not a plain file or folder inside its folder.

    ``str(err)`` names the path, what was expected there and what was found, e.g.
    ``"runs/x/trajectories/ep0: expected a folder, found a symbolic link to /elsewhere"``.
    """

    def __init__(self, path: str | os.PathLike, expected: str, found: str) -> None:
        self.path = os.fspath(path)
        self.expected = expected
        self.found = found
        super().__init__(self.path, expected, found)

    def __str__(self) -> str:
        return f"{self.path}: expected {self.expected}, found {self.found}"


def _parts(root: Path, relative: str | os.PathLike) -> tuple[str, ...]:
    """The components of ``relative``, refused unless it is a plain relative path below ``root``."""
    text = os.fspath(relative)
    parts = PurePath(text).parts
    if not text or PurePath(text).is_absolute() or not parts or any(p in ("..", ".") for p in parts) or "\x00" in text:
        raise UnsafeOutputError(
            root / text if text and not PurePath(text).is_absolute() else text,
            f"a plain path inside {root}",
            f"{text!r}",
        )
    return parts


def _kind(mode: int, path: Path) -> str:
    """What an lstat mode says ``path`` is, in words."""
    if stat.S_ISLNK(mode):
        try:
            target = os.readlink(path)
        except OSError:
            target = "?"
        return f"a symbolic link to {target}" if os.path.exists(path) else f"a link to nothing ({target})"
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISREG(mode):
        return "a file"
    return "a pipe, device or socket"


def _check(root: Path, relative: str | os.PathLike, create: bool, folder: bool) -> Path:
    """:func:`check_owned_path` (``folder`` False) or :func:`check_owned_folder` (True)."""
    root = Path(root)
    parts = _parts(root, relative)
    here = root
    missing = False
    for k, part in enumerate(parts):
        here = here / part
        last = k == len(parts) - 1
        wants_folder = folder or not last
        if missing:
            if create and wants_folder:
                os.mkdir(here)
            continue
        try:
            mode = os.lstat(here).st_mode
        except FileNotFoundError:
            if create and wants_folder:
                os.mkdir(here)
            else:
                missing = True
            continue
        except OSError as exc:  # a name too long, a folder on the way not searchable
            raise UnsafeOutputError(
                here,
                "a folder" if wants_folder else "a regular file or nothing",
                f"a path that cannot be read ({(exc.strerror or str(exc)).lower()})",
            ) from None
        if stat.S_ISDIR(mode) if wants_folder else stat.S_ISREG(mode):
            continue
        raise UnsafeOutputError(here, "a folder" if wants_folder else "a regular file or nothing", _kind(mode, here))
    real_root = os.path.realpath(root)
    real = os.path.realpath(here if folder else here.parent)
    if os.path.commonpath([real_root, real]) != real_root:  # belt and braces: no link was followed above
        raise UnsafeOutputError(here, f"a path inside {real_root}", f"one in {real}")
    return here


def check_owned_path(root: str | os.PathLike, relative: str | os.PathLike, *, create: bool = False) -> Path:
    """``root / relative`` if a run may write a regular file there without leaving ``root``; else
    :class:`UnsafeOutputError` naming the first component that is a symbolic link, a file where
    a folder belongs, or a folder, pipe or device where the file belongs. With ``create`` the
    missing folders on the way are made (each checked as it is made)."""
    return _check(Path(root), relative, create, folder=False)


def check_owned_folder(root: str | os.PathLike, relative: str | os.PathLike) -> Path:
    """``root / relative`` if it is a folder (or nothing yet) reached from ``root`` through folders
    only; else :class:`UnsafeOutputError` naming the first component that is not."""
    return _check(Path(root), relative, False, folder=True)


def owned_path(root: str | os.PathLike, relative: str | os.PathLike) -> Path:
    """:func:`check_owned_path` with ``create``: the path to write, its folders made."""
    Path(root).mkdir(parents=True, exist_ok=True)
    return check_owned_path(root, relative, create=True)


def remove_owned(root: str | os.PathLike, relative: str | os.PathLike) -> bool:
    """Delete file ``root / relative`` and the folders its removal empties (up to ``root``), when
    :func:`check_owned_path` accepts it; True when a file was removed. A path through a link, a
    folder, a pipe or a path that cannot be removed is left alone (False): cleaning up never
    follows a link and never fails a run."""
    root = Path(root)
    try:
        path = check_owned_path(root, relative)
        if not path.is_file():
            return False
        path.unlink()
    except (OSError, UnsafeOutputError):
        return False
    for parent in path.parents:
        if parent == root:
            break
        try:
            if stat.S_ISLNK(os.lstat(parent).st_mode) or any(os.scandir(parent)):
                break
            os.rmdir(parent)
        except OSError:
            break
    return True
