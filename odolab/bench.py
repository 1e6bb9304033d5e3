"""``python -m odolab.bench``: the command line lives in :mod:`odolab.cli.bench`; what it times, in
:mod:`odolab.benchmarks`."""

from odolab.cli.bench import main

__all__ = ["main"]

if __name__ == "__main__":
    from odolab.cli.args import exit_process, run_cli

    exit_process(run_cli(main, "python -m odolab.bench"))
