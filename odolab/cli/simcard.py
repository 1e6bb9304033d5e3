"""``python -m odolab.simcard``: the simulator in numbers, beside the paper's and Habitat's
(:mod:`odolab.simcard` measures and writes the card)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from odolab import simcard
from odolab.cli.args import (
    ArgumentParser,
    UsageError,
    add_scene_options,
    add_setting,
    check_ray_option,
    check_report_dir,
    execution_of,
    exit_process,
    hold_folder,
    path_arg,
    run_cli,
    scene_words,
    scenes_of,
)


def build_parser() -> ArgumentParser:
    ap = ArgumentParser(prog="python -m odolab.simcard", description=simcard.__doc__.splitlines()[0])
    ap.add_argument("--split", default="train", choices=["train", "val", "test"], help="scene split (default train)")
    for option in ("--episodes", "--rendered", "--frames", "--max-steps", "--seed"):
        add_setting(ap, option, simcard.CardConfig, option[2:].replace("-", "_"))
    add_scene_options(ap)
    ap.add_argument(
        "--out", type=path_arg("--out"), default=Path("runs/simcard"), help="output folder (default runs/simcard)"
    )
    ap.add_argument("--ray-address", default=None, help="Ray cluster address (default: a local instance)")
    ap.add_argument("--serial", action="store_true", help="no Ray: everything in this process")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    check_ray_option(args.ray_address, args.serial)  # and RAY_ADDRESS: before --out is made
    scenes = scenes_of(args, argv)  # every mesh file read: a bad one before --out is made
    check_report_dir(args.out, "--out")  # a folder of the user's own files is refused, as compare refuses it
    with hold_folder(args.out, "--out"):  # a second run into --out is refused until this one has written
        return _run(args, scenes)


def _run(args: argparse.Namespace, scenes) -> int:
    from odolab.io.owned import UnsafeOutputError
    from odolab.reporting.report import MANIFEST, ManifestError, OutputFolder
    from odolab.sim.redwood import default_table

    try:
        OutputFolder.check(args.out, files=(*simcard.CARD_FILES, MANIFEST), owner="simcard", names=simcard.CARD_NAMES)
    except ManifestError as exc:
        raise UsageError(f"--out {exc}") from None
    except UnsafeOutputError as exc:
        raise UsageError(f"--out: {exc}; remove it or choose another --out") from None
    try:
        source = default_table().source  # a bad ODOLAB_REDWOOD_TABLE is one line, before any work
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    config = simcard.CardConfig(args.split, args.episodes, args.rendered, args.frames, args.max_steps, args.seed)
    motion, images, samples = simcard.measure(
        config,
        family=args.scene_family,
        scenes=scenes,
        execution=execution_of(args),
    )
    command = (
        f"python -m odolab.simcard --split {args.split} --episodes {args.episodes} --rendered {args.rendered} "
        f"--frames {args.frames} --max-steps {args.max_steps} --seed {args.seed}" + scene_words(args)
    )
    simcard.write_card(args.out, motion, images, samples, source, command)
    print((args.out / "card.md").read_text())
    print(f"wrote {args.out / 'card.md'}, card.json, motion.png, depth.png, frames.png")
    return 0


if __name__ == "__main__":
    exit_process(run_cli(main, "python -m odolab.simcard"))
