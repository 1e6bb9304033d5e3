"""The one TOML file reader (:mod:`tomllib`: values only, nothing is evaluated): every way a file can
fail to read becomes one ``ValueError`` line naming the file."""

from __future__ import annotations

import os
from typing import Any

import tomllib

from odolab.io.inputs import read_input_bytes


def read_toml(path: str | os.PathLike, what: str = "file") -> dict[str, Any]:
    """The document of TOML file ``path``; ``ValueError("<path>: ...")`` when it is missing
    ("no such <what>"), not a regular file, unreadable, not TOML, or holds an integer too long for
    Python to read."""
    data = read_input_bytes(path, what)
    try:
        return tomllib.loads(data.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not valid TOML ({exc})") from None
    except ValueError:  # Python refuses to read integers of over 4300 digits
        raise ValueError(f"{path}: holds a number too long to read (over 4300 digits)") from None
    except RecursionError:  # [[[[...]]]] thousands deep
        raise ValueError(f"{path}: holds a value nested too deeply") from None
