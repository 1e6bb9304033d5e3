"""Shared command-line plumbing: user mistakes become one line on stderr and exit code 2."""
from __future__ import annotations

import argparse
import sys
from typing import Callable, Sequence


class UsageError(Exception):
    """A mistake in the user's input (bad argument, unreadable file...). The message names it."""


class ArgumentParser(argparse.ArgumentParser):
    """argparse whose mistakes raise :class:`UsageError` (so :func:`run_cli` prints one line)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise UsageError(message)


def number(name: str, kind: type = int, minimum: float | None = None) -> Callable[[str], float]:
    """An argparse ``type`` parsing ``kind`` (int or float) no smaller than ``minimum``; the error
    names the option: ``--episodes must be >= 1, got 0``. NaN is refused."""
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            noun = "an integer" if kind is int else "a number"
            raise argparse.ArgumentTypeError(f"{name} must be {noun}, got {text!r}") from None
        if value != value or (minimum is not None and value < minimum):
            raise argparse.ArgumentTypeError(f"{name} must be >= {minimum:g}, got {text}")
        return value
    return parse


def run_cli(main: Callable[[Sequence[str] | None], int | None], prog: str,
            argv: Sequence[str] | None = None) -> int:
    """Run ``main(argv)``; turn :class:`UsageError` and file errors into ``prog: error: ...`` + exit 2."""
    try:
        return int(main(argv) or 0)
    except (UsageError, FileNotFoundError, PermissionError, IsADirectoryError, NotADirectoryError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
