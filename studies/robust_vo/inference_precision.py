"""Does bf16 inference cost the robust VO accuracy? The shipped model run on the same val episodes
with ``precision=fp32`` (the default) and ``precision=bf16``: each one's per-step error and steps/s,
and bf16's paired difference against fp32 on the same steps (:mod:`odolab.running.paired`: mean
over episodes of the per-episode differences, x 1e-2, with a 95 % interval and its verdict).

    python -m studies.robust_vo.inference_precision [--episodes 20] [--max-steps 100] [--out reports/robust-vo/inference-precision]

One process, one torch thread per odometer (the odometer's default), episodes made in memory.
Writes ``summary.json`` (both rows, the paired rows, the machine, the command) and ``manifest.txt``
into ``--out``.
"""

from __future__ import annotations

import dataclasses
import re

from odolab.config import check, setting
from odolab.core.machine import machine
from odolab.core.parallel import SERIAL
from odolab.io.atomic import write_json_atomic
from odolab.odometry.odometer import load_odometer
from odolab.running import runner, summary
from odolab.running.paired import paired_differences, paired_verdicts
from odolab.sim.episodes import EpisodeSpec, load_episodes

FP32, BF16 = "robust-vo", "robust-vo precision=bf16"
#: Who owns ``--out`` (its ``manifest.txt`` says so) and the one file written there.
OWNER, NAMES = "study inference-precision", re.compile(r"summary\.json")


@dataclasses.dataclass(frozen=True)
class ProbeSettings:
    """How many val episodes (seed 0) and how many steps each."""

    episodes: int = setting(20, range=(2, 1000), doc="val episodes (two at least: the unit of the intervals)")
    max_steps: int = setting(100, range=(1, 500), doc="steps per episode")

    def __post_init__(self) -> None:
        check(self)


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


def run(args) -> int:
    """The probe as its command line (:mod:`odolab.cli.study`) asks: ``summary.json`` into ``args.out``,
    listed in its ``manifest.txt`` (a folder another command, or no odolab run, wrote is refused
    before any work)."""
    from odolab.cli import UsageError, check_report_dir
    from odolab.io.owned import UnsafeOutputError
    from odolab.reporting.report import MANIFEST, ManifestError, OutputFolder

    check_report_dir(args.out, "--out")
    try:
        OutputFolder.check(args.out, files=("summary.json", MANIFEST), owner=OWNER, names=NAMES)
    except (UnsafeOutputError, ManifestError) as exc:
        raise UsageError(f"--out {args.out}: {str(exc).removeprefix(f'{args.out}: ')}") from None
    found = measure(args.episodes, args.max_steps)
    folder = OutputFolder(args.out, owner=OWNER, names=NAMES)
    write_json_atomic(folder.path("summary.json"), {"command": args.command, **found})
    folder.finish()
    for row in found["rows"]:
        print(
            f"{row['odometer']}: dx {row['dx']:.3f} dz {row['dz']:.3f} dyaw {row['dyaw']:.3f} x 1e-2, "
            f"{row['fps']:.1f} steps/s"
        )
    print(*found["verdicts"], sep="\n")
    return 0


if __name__ == "__main__":  # python -m studies.robust_vo.inference_precision: the command line is odolab.cli.study's
    import importlib

    study = importlib.import_module("odolab.cli.study")
    study.exit_process(study.command("inference-precision"))
