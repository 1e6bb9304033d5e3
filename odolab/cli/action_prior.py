"""``python -m odolab.action_prior``: fit the action prior, the train split's mean motion per action
(:func:`odolab.odometry.action_prior.fit_action_prior`), and print or write it."""

from __future__ import annotations

import json
from collections.abc import Sequence

from odolab.cli.args import (
    ArgumentParser,
    UsageError,
    add_setting,
    check_output_file,
    check_replaceable,
    exit_process,
    file_arg,
    run_cli,
)
from odolab.odometry import action_prior
from odolab.reporting.report import counted


def main(argv: Sequence[str] | None = None) -> int:
    from odolab.io.atomic import write_text_atomic

    ap = ArgumentParser(prog="python -m odolab.action_prior", description=action_prior.__doc__.split("\n")[0])
    for option, field in (("--episodes", "n_episodes"), ("--max-steps", "max_steps"), ("--seed", "seed")):
        add_setting(ap, option, action_prior.PriorFit, field)
    ap.add_argument("--out", type=file_arg("--out"), default=None, help="write JSON here (atomic); default: print")
    args = ap.parse_args(argv)
    if args.out is not None:
        check_output_file(args.out, "--out", [".json"])  # its folder must exist: nothing is created on a typo
        check_replaceable(args.out, "--out", _is_prior_file, "an action prior (python -m odolab.action_prior --out)")
    prior = action_prior.fit_action_prior(args.episodes, args.max_steps, args.seed)
    unseen = [a.label for a, n in prior.samples.items() if n == 0]
    if unseen:
        raise UsageError(
            f"no {' or '.join(unseen)} step in {counted(args.episodes, 'episode')} of at most {args.max_steps} "
            "steps: a mean of nothing is no prior; use more --episodes or --max-steps"
        )
    text = json.dumps(prior.to_json(), indent=2) + "\n"
    if args.out is None:
        print(text, end="")
        return 0
    write_text_atomic(args.out, text)
    print(f"wrote {args.out}")
    return 0


def _is_prior_file(path) -> bool:
    """Whether ``path`` holds what ``--out`` writes (a JSON object with the prior's fields)."""
    doc = json.loads(path.read_text(encoding="utf-8")[:1_000_000])
    return isinstance(doc, dict) and {"source", "means", "samples"} <= set(doc)


if __name__ == "__main__":
    exit_process(run_cli(main, "python -m odolab.action_prior"))
