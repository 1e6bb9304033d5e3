"""Side-by-side accuracy and speed of odometers on a TUM RGB-D folder, per frame pair.

    python -m baselines.measure_tum tests/data/tum_fr1_xyz_10

A thin use of odolab's runner (:func:`odolab.api.run_odometers`: same frames to each odometer,
timing, failures) scored with the relative pose error of every consecutive pair,
``E = inv(T_gt_rel) T_est_rel`` with ``T_rel = T_prev_cur``: translation ``|t_E|`` (mm) and rotation
``angle(R_E)`` (deg), averaged over pairs, the figures facts are quoted in for Open3D and KISS-ICP.
A step an odometer cannot answer is scored as no motion (the runner's fallback on real data, where
no action is known) and counted. ``no-motion`` is that fallback as a row of its own (the registered
``action-prior`` odometer). Speed: steps per second of ``step()`` alone, median over ``--repeat``
passes. Prints a markdown table; bad input is one line on stderr and exit code 2.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np

from baselines.depth_geometry import DepthRange
from odolab.api import (
    SequenceResult,
    UnknownCameraError,
    invert,
    load_odometer,
    load_tum_sequence,
    run_odometers,
)

NO_MOTION = "no-motion"
DEFAULT_ODOMETERS = (NO_MOTION, "feature-essential", "icp", "open3d-rgbd")


@dataclass(frozen=True)
class Row:
    """One odometer's figures: mean errors (mm, deg), invalid steps, steps per second (None: untimed)."""

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


def score(result: SequenceResult, steps_per_s: float | None) -> Row:
    """Mean per-pair errors of one runner result (its estimates as used: failed steps = no motion)."""
    errors = np.array([relative_pose_error(e, g) for e, g in zip(result.estimates, result.truth)])
    return Row(
        result.odometer,
        1000.0 * float(errors[:, 0].mean()),
        float(np.degrees(errors[:, 1].mean())),
        result.failures,
        len(result.estimates),
        steps_per_s,
    )


def load(name: str, max_depth: float):
    """The odometer ``name`` with the depth cut where it takes one (reference rows take none)."""
    target = "action-prior" if name == NO_MOTION else name
    try:
        return load_odometer(target, max_depth=max_depth)
    except TypeError:  # no max_depth option: run it as it is
        return load_odometer(target)


def markdown_table(rows: list[Row], width: int, height: int) -> str:
    """The rows as a markdown table."""
    lines = [
        f"| odometer | translation (mm) | rotation (deg) | invalid steps | steps/s at {width}x{height} |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        speed = "-" if r.steps_per_s is None else f"{r.steps_per_s:.1f}"
        lines.append(f"| {r.name} | {r.translation_mm:.2f} | {r.rotation_deg:.3f} | {r.invalid}/{r.steps} | {speed} |")
    return "\n".join(lines)


def run(args) -> int:
    """Measure as the command line (:mod:`odolab.cli.measure_tum`) asks: ``args.folder``,
    ``odometers``, ``max_depth`` (m), ``repeat``, ``depth_scale`` (None: TUM's), ``intrinsics``
    (None: from the folder's name) and ``prog`` (for a warning); prints the table. ``ValueError``
    (and the loaders' errors) for bad input, in one line."""
    if args.max_depth <= DepthRange().min_depth:
        raise ValueError(
            f"--max-depth must be above the odometers' min_depth {DepthRange().min_depth:g} m, got {args.max_depth:g}"
        )
    scale = {} if args.depth_scale is None else {"depth_scale": args.depth_scale}
    try:
        seq = load_tum_sequence(args.folder, args.intrinsics, **scale)
    except UnknownCameraError:
        raise ValueError(
            f"{args.folder}: cannot tell the camera from the folder's name (no fr1, fr2 or fr3 "
            "in it); give it with --intrinsics fx,fy,cx,cy (pixels)"
        ) from None
    if len(seq) < 2:
        raise ValueError(f"{args.folder}: needs at least 2 frames with depth and ground truth")
    odometers = {name: load(name, args.max_depth) for name in dict.fromkeys(args.odometers)}
    warning = seq.depth_warning()
    if warning:
        print(f"{args.prog}: warning: {warning} (--depth-scale)", file=sys.stderr)
    rows = []
    for name, odo in odometers.items():
        timed = name not in (NO_MOTION, "action-prior", "ground-truth")
        passes = [run_odometers({name: odo}, [seq])[0] for _ in range(args.repeat if timed else 1)]
        speed = float(np.median([len(p.step_seconds) / p.step_seconds.sum() for p in passes])) if timed else None
        rows.append(score(passes[0], speed))
    i = seq.intrinsics
    print(f"{args.folder}: {len(seq)} frames, {len(seq) - 1} consecutive pairs, depth cut {args.max_depth:g} m\n")
    print(markdown_table(rows, i.width, i.height))
    return 0


if __name__ == "__main__":  # python -m baselines.measure_tum: the command line is odolab.cli.measure_tum's
    import runpy

    runpy.run_module("odolab.cli.measure_tum", run_name="__main__", alter_sys=True)
