"""Does bf16 inference cost the robust VO accuracy? The shipped model run on the same val episodes
with ``precision=fp32`` (the default) and ``precision=bf16``: each one's per-step error and steps/s,
and bf16's paired difference against fp32 on the same steps (:mod:`odolab.running.paired`: mean
over episodes of the per-episode differences, x 1e-2, with a 95 % interval and its verdict).

    python -m studies.robust_vo.inference_precision [--episodes 20] [--max-steps 100] [--out reports/robust-vo/inference-precision]

One process, one torch thread per odometer (the odometer's default), episodes made in memory.
Writes ``summary.json`` (both rows, the paired rows, the machine) into ``--out``.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from odolab.core.machine import machine
from odolab.core.parallel import SERIAL
from odolab.io.atomic import write_json_atomic
from odolab.odometry.odometer import load_odometer
from odolab.running import runner, summary
from odolab.running.paired import paired_differences, paired_verdicts
from odolab.sim.episodes import EpisodeSpec, load_episodes

FP32, BF16 = "robust-vo", "robust-vo precision=bf16"


def measure(episodes: int, max_steps: int) -> dict:
    """Both precisions on the first ``episodes`` val episodes (seed 0) of at most ``max_steps`` steps."""
    specs = [EpisodeSpec(split="val", index=i, seed=0, max_steps=max_steps) for i in range(episodes)]
    eps = load_episodes(specs, execution=SERIAL)  # made in memory
    odometers = {FP32: load_odometer("robust-vo"), BF16: load_odometer("robust-vo", precision="bf16")}
    results = runner.run(odometers, eps)
    paired = paired_differences(results, [(BF16, FP32)])
    return {
        "episodes": episodes,
        "max_steps": max_steps,
        "rows": [dataclasses.asdict(r) for r in summary.summarize(results)],
        "paired": [dataclasses.asdict(r) for r in paired],
        "verdicts": paired_verdicts(paired),
        "machine": machine(),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m studies.robust_vo.inference_precision", description=__doc__)
    parser.add_argument("--episodes", type=int, default=20, help="val episodes (default 20)")
    parser.add_argument("--max-steps", type=int, default=100, help="steps per episode (default 100)")
    parser.add_argument("--out", type=Path, default=Path("reports/robust-vo/inference-precision"))
    args = parser.parse_args(argv)
    if not 2 <= args.episodes <= 1000 or not 1 <= args.max_steps <= 500:
        parser.error(
            f"--episodes must be in [2, 1000] and --max-steps in [1, 500], got {args.episodes}, {args.max_steps}"
        )
    found = measure(args.episodes, args.max_steps)
    args.out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out / "summary.json", found)
    for row in found["rows"]:
        print(
            f"{row['odometer']}: dx {row['dx']:.3f} dz {row['dz']:.3f} dyaw {row['dyaw']:.3f} x 1e-2, {row['fps']:.1f} steps/s"
        )
    print(*found["verdicts"], sep="\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
