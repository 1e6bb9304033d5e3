"""``python -m odolab.training_data``: render simulator episodes into memory-mappable training shards
(:func:`odolab.sim.training_data.make_training_data`; resumable).

    python -m odolab.training_data --split train --episodes 1200 --width 170 --height 96 --out data/vo/train
    python -m odolab.training_data --scenes my-scans/ --split val --episodes 50 --out data/scans/val
"""

from __future__ import annotations

from collections.abc import Sequence

from odolab.cli.args import (
    ArgumentParser,
    add_scene_options,
    check_report_dir,
    execution_of,
    exit_process,
    path_arg,
    run_cli,
    scenes_of,
    setting_help,
    setting_type,
)
from odolab.reporting.report import counted
from odolab.sim.scenes import SPLITS
from odolab.sim.training_data import (
    MANIFEST,
    MAX_EPISODE_INDEX,
    DataConfig,
    TrainingData,
    make_training_data,
)


def main(argv: Sequence[str] | None = None) -> int:
    from odolab.cli.args import check_ray_option

    ap = ArgumentParser(
        prog="python -m odolab.training_data",
        description="Render simulator episodes into memory-mappable training shards (resumable).",
    )
    d = DataConfig()
    ap.add_argument("--split", choices=SPLITS, default=d.split, help=f"scene pool (default {d.split})")
    for field in ("episodes", "first", "seed", "max_steps", "width", "height", "episodes_per_shard"):
        option = "--" + field.replace("_", "-")
        ap.add_argument(
            option,
            type=setting_type(option, DataConfig, field),
            default=getattr(d, field),
            help=setting_help(DataConfig, field),
        )
    ap.add_argument(
        "--clean-depth", action="store_true", help="also store the noiseless depth (the target of a depth corrector)"
    )
    add_scene_options(ap)
    ap.add_argument("--out", type=path_arg("--out"), required=True, help="folder (created; reused to resume)")
    ap.add_argument("--ray-address", default=None, help="Ray cluster address (default: a local instance)")
    ap.add_argument("--serial", action="store_true", help="render in this process, without Ray")
    args = ap.parse_args(argv)
    if args.first + args.episodes - 1 > MAX_EPISODE_INDEX:
        ap.error(
            f"--first {args.first} + --episodes {args.episodes}: the last episode's index would be "
            f"{args.first + args.episodes - 1}, above 2^31 - 1; use a smaller --first"
        )
    cfg = DataConfig(
        split=args.split,
        episodes=args.episodes,
        seed=args.seed,
        first=args.first,
        max_steps=args.max_steps,
        width=args.width,
        height=args.height,
        episodes_per_shard=args.episodes_per_shard,
        clean_depth=args.clean_depth,
    )
    check_ray_option(args.ray_address, args.serial)  # and RAY_ADDRESS: before --out is made
    scenes = scenes_of(args, argv)  # every mesh file read: a bad one before --out is made
    check_report_dir(args.out, "--out", manifest=MANIFEST)  # a folder of the user's own files is refused
    try:
        make_training_data(cfg, args.out, scenes=scenes, family=args.scene_family, execution=execution_of(args))
        data = TrainingData(args.out)
    except ValueError as exc:
        ap.error(str(exc))
    counts = ", ".join(f"{k} {v}" for k, v in data.counts().items())
    print(
        f"{args.out}: {len(data)} pairs ({counts}) from {counted(cfg.episodes, cfg.split + ' episode')} at {cfg.width}x{cfg.height}"
    )
    return 0


if __name__ == "__main__":
    exit_process(run_cli(main, "python -m odolab.training_data"))
