"""``python -m odolab.compare``: the command line lives in :mod:`odolab.cli.compare`."""

from odolab.cli.compare import main

__all__ = ["main"]

if __name__ == "__main__":
    from odolab.cli.args import run_cli

    raise SystemExit(run_cli(main, "python -m odolab.compare"))
