"""Reading a user's input file whole: only regular files (a pipe or a device would block or never
end) of a sane size, JSON without repeated keys, every failure one ``ValueError`` line naming the file."""

from __future__ import annotations

import json
import os
import stat
from typing import Any

#: Largest input file read whole (options, recipes, calibrations are a few kB).
MAX_INPUT_BYTES = 16 * 2**20


def missing(path: str | os.PathLike, what: str = "file") -> str:
    """Why ``path`` cannot be opened though named: ``no such <what>``, or, for a symbolic link whose
    target does not exist, ``is a link to nothing (<target> does not exist)``."""
    if os.path.islink(path):
        return f"is a link to nothing ({os.readlink(path)} does not exist)"
    return f"no such {what}"


def special_kind(mode: int) -> str | None:
    """What an ``os.stat`` mode that is neither a regular file nor a folder is, in words ("a named
    pipe (FIFO)", "a character device"...); None for a regular file or a folder."""
    for test, words in (
        (stat.S_ISFIFO, "a named pipe (FIFO)"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
    ):
        if test(mode):
            return words
    return None if stat.S_ISREG(mode) or stat.S_ISDIR(mode) else "not a regular file"


def not_regular(path: str | os.PathLike, what: str = "file") -> str | None:
    """Why ``path`` is not (a link to) a regular file, in words after its name, e.g. ``no such file``,
    ``is a folder, not a regular file``, ``is a named pipe (FIFO), not a regular file``, ``is a link
    to /dev/zero, a character device, not a regular file``; None for a regular file. Only looked
    at (``stat``), never opened: reading a pipe would block, a device may never end."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return missing(path, what)
    except OSError as exc:  # a link loop, a name too long, no permission on a folder on the way
        return f"cannot be read ({(exc.strerror or str(exc)).lower()})"
    if stat.S_ISREG(mode):
        return None
    kind = "a folder" if stat.S_ISDIR(mode) else special_kind(mode)
    if os.path.islink(path):
        return f"is a link to {os.readlink(path)}, {kind}, not a regular file"
    return f"is {kind}, not a regular file"


def check_regular_file(path: str | os.PathLike, what: str = "file") -> None:
    """Raise ``ValueError("<path>: ...")`` unless ``path`` is (a link to) a regular file: missing
    ("no such <what>"), a folder, a pipe, a device or a socket."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise ValueError(f"{path}: {missing(path, what)}") from None
    except OSError as exc:  # a link loop, a name too long, no permission on a folder on the way
        raise ValueError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if stat.S_ISDIR(mode):
        raise ValueError(f"{path}: is a folder; the {what} must be a regular file")
    if not stat.S_ISREG(mode):
        raise ValueError(f"{path}: is a pipe, device or socket; the {what} must be a regular file")


def read_input_bytes(path: str | os.PathLike, what: str = "file", limit: int = MAX_INPUT_BYTES) -> bytes:
    """The bytes of regular file ``path`` (see :func:`check_regular_file`); refused when larger than
    ``limit`` bytes (a huge options file or calibration is a mistake, not something to read whole)."""
    check_regular_file(path, what)
    try:
        with open(path, "rb") as f:
            data = f.read(limit + 1)
    except FileNotFoundError:  # removed since the check
        raise ValueError(f"{path}: no such {what}") from None
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if len(data) > limit:
        raise ValueError(f"{path}: larger than {limit // 2**20} MiB, too large to be read as the {what}")
    return data


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    seen: dict[str, Any] = {}
    for key, value in pairs:
        if key in seen:  # json would keep the last silently: which one the user meant is unknown
            raise ValueError(f"key {key!r} appears twice in one object")
        seen[key] = value
    return seen


def parse_input_json(data: bytes, path: str | os.PathLike, what: str = "file") -> Any:
    """The JSON document in ``data``, read from ``path``; ``ValueError`` naming the file and the
    ``what`` for bad UTF-8, bad JSON, nesting too deep or a key repeated in one object."""
    try:
        return json.loads(data.decode("utf-8"), object_pairs_hook=_unique_keys)
    except (ValueError, RecursionError) as exc:  # ValueError: bad JSON or UTF-8, numbers too long, a repeated key
        raise ValueError(f"{path}: not a valid {what} ({exc})") from None


def read_input_json(path: str | os.PathLike, what: str = "file") -> Any:
    """The JSON document in regular file ``path`` (:func:`read_input_bytes`, :func:`parse_input_json`)."""
    return parse_input_json(read_input_bytes(path, what), path, what)
