"""``reports/index.html``: a link to every report page under the reports folder, with its title.

    python -m studies.reports_index [--reports reports]

Every study refreshes it when it writes a report there; this command refreshes it after any other
command's report (compare, navigate) was written or removed. A page there that odolab did not write
(another title) is left alone.
"""

from __future__ import annotations

from collections.abc import Sequence

from studies import framework

PROG = "python -m studies.reports_index"


def main(argv: Sequence[str] | None = None) -> int:
    from odolab.cli import ArgumentParser, UsageError, path_arg
    from odolab.io.owned import UnsafeOutputError

    ap = ArgumentParser(prog=PROG, description=__doc__.split("\n")[0].replace("``", ""))
    ap.add_argument(
        "--reports",
        type=path_arg("--reports"),
        default=framework.DEFAULT_REPORTS,
        help=f"the reports folder (default {framework.DEFAULT_REPORTS})",
    )
    args = ap.parse_args(argv)
    if not args.reports.is_dir():
        raise UsageError(f"--reports {args.reports}: not a folder")
    try:
        path = framework.write_reports_index(args.reports)
    except UnsafeOutputError as exc:
        raise UsageError(f"--reports {args.reports}: {exc}") from None
    print(path)
    return 0


if __name__ == "__main__":
    from odolab.cli import run_cli

    raise SystemExit(run_cli(main, PROG))
