"""``python -m odolab.evaluate``: the command line lives in :mod:`odolab.cli.evaluate`."""

from odolab.cli.evaluate import main

__all__ = ["main"]

if __name__ == "__main__":
    from odolab.cli.args import exit_process, run_cli

    exit_process(run_cli(main, "python -m odolab.evaluate"))
