"""The ``odolab`` console script (``odolab.commands:main`` in pyproject.toml): it lives in
:mod:`odolab.cli.commands`."""

import sys

from odolab.cli.commands import COMMANDS, main, usage

__all__ = ["COMMANDS", "main", "usage"]

if __name__ == "__main__":
    sys.exit(main())
