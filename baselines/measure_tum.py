"""Side-by-side accuracy and speed of the classical odometers on a TUM RGB-D folder.

    python -m baselines.measure_tum tests/data/tum_fr1_xyz_10

For every consecutive frame pair: relative pose error ``E = inv(T_gt_rel) T_est_rel`` with
``T_rel = T_prev_cur``; translation error ``|t_E|`` (mm) and rotation error ``angle(R_E)`` (deg),
averaged over pairs. A step an odometer marks invalid is scored as no motion (the fallback a
runner has on real data, where no action is known) and counted. Speed: steps per second of
``step()`` alone (frames decoded beforehand; each step meets one new frame, as in a run), the
median of ``--repeat`` passes. Prints a markdown table.
"""
from __future__ import annotations

import argparse
import itertools
import sys
import time
from dataclasses import dataclass

import numpy as np

from odolab.api import Estimate, Frame, invert, load_odometer, load_tum_sequence

NO_MOTION = "no-motion"
DEFAULT_ODOMETERS = (NO_MOTION, "feature-essential", "icp", "open3d-rgbd")


@dataclass(frozen=True)
class Row:
    """One odometer's figures: mean errors (mm, deg), invalid steps, steps per second."""

    name: str
    translation_mm: float
    rotation_deg: float
    invalid: int
    steps: int
    steps_per_s: float | None


def relative_pose_error(T_est: np.ndarray, T_gt: np.ndarray) -> tuple[float, float]:
    """(translation m, rotation rad) of ``inv(T_gt) T_est`` for two 4x4 relative poses."""
    E = invert(T_gt) @ T_est
    cos = np.clip((np.trace(E[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.linalg.norm(E[:3, 3])), float(np.arccos(cos))


def measure(name: str, frames: list[Frame], intrinsics, repeat: int = 3, **options) -> Row:
    """Run odometer ``name`` (or ``"no-motion"``) over ``frames``; errors vs the frames' gt_pose."""
    pairs = list(itertools.pairwise(frames))
    gt = [invert(a.gt_pose) @ b.gt_pose for a, b in pairs]
    if name == NO_MOTION:
        estimates = [Estimate(np.eye(4)) for _ in pairs]
        speed = None
    else:
        times = []
        for _ in range(max(repeat, 1)):
            odo = load_odometer(name, **options)
            odo.reset(intrinsics)
            start = time.perf_counter()
            estimates = [odo.step(a, b, None) for a, b in pairs]
            times.append(time.perf_counter() - start)
        speed = len(pairs) / float(np.median(times))
    errors = np.array(
        [relative_pose_error(e.transform if e.valid else np.eye(4), g) for e, g in zip(estimates, gt)]
    )
    return Row(
        name,
        1000.0 * float(errors[:, 0].mean()),
        float(np.degrees(errors[:, 1].mean())),
        sum(not e.valid for e in estimates),
        len(pairs),
        speed,
    )


def markdown_table(rows: list[Row], width: int, height: int) -> str:
    """The rows as a markdown table."""
    lines = [
        f"| odometer | translation (mm) | rotation (deg) | invalid steps | steps/s at {width}x{height} |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        speed = "-" if r.steps_per_s is None else f"{r.steps_per_s:.1f}"
        lines.append(
            f"| {r.name} | {r.translation_mm:.2f} | {r.rotation_deg:.3f} | {r.invalid}/{r.steps} | {speed} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m baselines.measure_tum", description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", help="TUM RGB-D sequence folder (rgb.txt, depth.txt, groundtruth.txt)")
    parser.add_argument("--odometers", nargs="+", default=list(DEFAULT_ODOMETERS), metavar="NAME",
                        help=f"registered odometer names, or {NO_MOTION!r} (default: %(default)s)")
    parser.add_argument("--max-depth", type=float, default=4.0, help="depth cut, metres (default: 4)")
    parser.add_argument("--repeat", type=int, default=3, help="timed passes per odometer (default: 3)")
    args = parser.parse_args(argv)
    try:
        seq = load_tum_sequence(args.folder)
    except (OSError, ValueError) as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    frames = [seq[i] for i in range(len(seq))]
    if len(frames) < 2:
        print(f"{parser.prog}: error: {args.folder}: needs at least 2 frames", file=sys.stderr)
        return 2
    rows = []
    for name in args.odometers:
        options = {} if name == NO_MOTION else {"max_depth": args.max_depth}
        rows.append(measure(name, frames, seq.intrinsics, args.repeat, **options))
    i = seq.intrinsics
    print(f"{args.folder}: {len(frames)} frames, {len(frames) - 1} consecutive pairs, depth cut {args.max_depth} m\n")
    print(markdown_table(rows, i.width, i.height))
    return 0


if __name__ == "__main__":
    sys.exit(main())
