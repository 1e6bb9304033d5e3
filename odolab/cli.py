"""Shared command-line plumbing: user mistakes become one line on stderr and exit code 2."""
from __future__ import annotations

import sys
from typing import Callable, Sequence


class UsageError(Exception):
    """A mistake in the user's input (bad argument, unreadable file...). The message names it."""


def run_cli(main: Callable[[Sequence[str] | None], int | None], argv: Sequence[str] | None = None) -> int:
    """Run ``main(argv)``; turn :class:`UsageError` (and file errors) into ``error: ...`` + exit 2."""
    prog = getattr(main, "__module__", "odolab")
    try:
        return int(main(argv) or 0)
    except UsageError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except (FileNotFoundError, PermissionError, IsADirectoryError, NotADirectoryError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
