"""``python -m baselines.measure_tum FOLDER`` (= ``odolab measure-tum FOLDER``): per-pair errors and
speed of odometers on a TUM RGB-D folder. The work is :func:`baselines.measure_tum.run`; bad input
is one line on stderr and exit code 2."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable, Sequence

from odolab.cli.args import ArgumentParser, UsageError, exit_process, pinhole, run_cli

__all__ = ["command", "main", "parser"]

PROG = "python -m baselines.measure_tum"


def _positive(kind: type, high: float = 1000) -> Callable[[str], float]:
    """An argparse ``type``: ``kind`` (int or float) in (0, ``high``]."""
    noun = "an integer" if kind is int else "a number"

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {noun}, got {text!r}") from None
        if not math.isfinite(value) or value <= 0 or value > high:
            raise argparse.ArgumentTypeError(f"must be in (0, {high:g}], got {text}")
        return value

    return parse


def parser(prog: str = PROG) -> ArgumentParser:
    """The command's options (the defaults are :mod:`baselines.measure_tum`'s)."""
    from baselines.depth_geometry import DepthRange
    from baselines.measure_tum import DEFAULT_ODOMETERS, NO_MOTION
    from baselines.measure_tum import __doc__ as doc

    ap = ArgumentParser(prog=prog, description=(doc or "").split("\n\n")[0])
    ap.add_argument("folder", help="TUM RGB-D sequence folder (rgb.txt, depth.txt, groundtruth.txt)")
    ap.add_argument(
        "--odometers",
        nargs="+",
        default=list(DEFAULT_ODOMETERS),
        metavar="NAME",
        help=f"registered odometer names, or {NO_MOTION!r} (default: %(default)s)",
    )
    ap.add_argument(
        "--max-depth",
        type=_positive(float),
        default=4.0,
        help=f"depth cut for every odometer (open3d-rgbd's own default is 6), metres, "
        f"({DepthRange().min_depth:g}, 1000] (4)",
    )
    ap.add_argument("--repeat", type=_positive(int), default=3, help="timed passes per odometer, 1-1000 (3)")
    ap.add_argument(
        "--depth-scale",
        type=_positive(float, 1e6),
        default=None,
        metavar="S",
        help="depth PNG values per metre (default TUM's 5000; millimetres: 1000)",
    )
    ap.add_argument(
        "--intrinsics",
        type=pinhole("--intrinsics"),
        default=None,
        metavar="FX,FY,CX,CY",
        help="the camera's pinhole in pixels (default: the TUM camera the folder's name says)",
    )
    return ap


def main(argv: Sequence[str] | None = None, prog: str = PROG) -> int:
    """Parse and measure; :class:`UsageError` for bad input (a file, a name, a number)."""
    from baselines.measure_tum import run
    from odolab.api import UnknownOdometerError

    ap = parser(prog)
    args = ap.parse_args(list(sys.argv[1:] if argv is None else argv))
    args.prog = ap.prog  # the name it was typed with (odolab measure-tum), for its warning
    try:
        return run(args)
    except (OSError, ValueError, UnknownOdometerError, TypeError) as exc:
        raise UsageError(str(exc)) from None


def command(argv: Sequence[str] | None = None) -> int:
    """``python -m baselines.measure_tum``: :func:`main` under :func:`~odolab.cli.args.run_cli`."""
    return run_cli(main, PROG, argv)


if __name__ == "__main__":
    exit_process(command())
