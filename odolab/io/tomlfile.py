"""The one TOML file reader (:mod:`tomllib`: values only, nothing is evaluated): every way a file can
fail to read becomes one ``ValueError`` line naming the file."""
from __future__ import annotations

import os
import tomllib
from typing import Any


def read_toml(path: str | os.PathLike, what: str = "file") -> dict[str, Any]:
    """The document of TOML file ``path``; ``ValueError("<path>: ...")`` when it is missing
    ("no such <what>"), unreadable, not TOML, or holds an integer too long for Python to read."""
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise ValueError(f"{path}: no such {what}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not valid TOML ({exc})") from None
    except ValueError:  # Python refuses to read integers of over 4300 digits
        raise ValueError(f"{path}: holds a number too long to read (over 4300 digits)") from None
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror or exc})") from None
