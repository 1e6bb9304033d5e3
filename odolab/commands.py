"""The ``odolab`` console script (``odolab.commands:console`` in pyproject.toml): it lives in
:mod:`odolab.cli.commands`."""

from odolab.cli.args import exit_process
from odolab.cli.commands import COMMANDS, main, usage

__all__ = ["COMMANDS", "console", "main", "usage"]


def console() -> None:
    """The console script: :func:`main`, its code the process's (:func:`exit_process`)."""
    exit_process(main())


if __name__ == "__main__":
    console()
