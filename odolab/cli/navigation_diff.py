"""``python -m odolab.navigation.diff``: two navigation runs compared episode by episode
(:mod:`odolab.navigation.diff`).

    python -m odolab.navigation.diff reports/navigation runs/nav-new
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence

from odolab.cli.args import ArgumentParser, UsageError, exit_process, path_arg, run_cli
from odolab.navigation import diff


def main(argv: Sequence[str] | None = None) -> int:
    ap = ArgumentParser(prog="python -m odolab.navigation.diff", description=diff.__doc__.splitlines()[0])
    ap.add_argument("before", type=path_arg("before"), help="a navigation folder (python -m odolab.navigate --out)")
    ap.add_argument("after", type=path_arg("after"), help="another one, of the same episodes")
    args = ap.parse_args(argv)
    for name, folder in (("before", args.before), ("after", args.after)):
        if os.path.isfile(folder):  # e.g. the episodes.csv itself (False, not OSError, on a 300-char name)
            raise UsageError(
                f"{name} {folder}: is a file; expected the folder python -m odolab.navigate --out wrote"
                + (f" ({folder.parent})" if folder.name == "episodes.csv" else "")
            )
    try:
        before, after = diff.read_episodes(args.before), diff.read_episodes(args.after)
    except diff.EpisodesTableError as exc:
        raise UsageError(str(exc)) from None
    diffs = diff.diff_runs(before, after)
    if not diffs:  # refused before any note, so the refusal is the one line said
        raise UsageError(
            f"{args.before} and {args.after} share no episode of any odometer (same --split, --seed "
            "and odometer names are needed)"
        )
    other = diff.episode_difference(args.before, args.after)
    if other is not None:
        raise UsageError(
            f"{args.before} and {args.after} ran other episodes ({other}); a diff pairs runs of the same episodes"
        )
    for note in diff.unpaired(before, after) + diff.setting_notes(args.before, args.after):
        print(f"note: {note}", file=sys.stderr)
    print(diff.markdown(diffs), end="")
    return 0


if __name__ == "__main__":
    exit_process(run_cli(main, "python -m odolab.navigation.diff"))
