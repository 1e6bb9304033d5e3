"""Wall time of ``python -m odolab.evaluate`` against ``evo_ape`` on KITTI 00 (4541 poses).

Ours computes ATE (SE(3)-aligned) + RPE + KITTI t_rel/r_rel; ``evo_ape kitti GT EST -a`` computes
the ATE only. Both run as subprocesses (interpreter start-up included), best of ``repeats``.
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

from odolab.benchmarks.commands import timed_command

__all__ = ["DEFAULT_DATA", "run"]

#: evo's KITTI 00 test files, shipped in the repository (see tests/data/evo/README.md).
DEFAULT_DATA = Path(__file__).resolve().parents[2] / "tests" / "data" / "evo"


def _best_wall_time(cmd: list[str], repeats: int) -> float:
    """Smallest wall time (s) of ``repeats`` runs of ``cmd``; :class:`CommandFailed` if the command fails."""
    return min(timed_command(cmd, capture_stderr=True) for _ in range(repeats))


def _evo_ape() -> str | None:
    """``evo_ape`` beside the running interpreter, else on PATH, else None."""
    local = Path(sys.executable).parent / "evo_ape"
    return str(local) if local.exists() else shutil.which("evo_ape")


def run(data_dir: str | os.PathLike = DEFAULT_DATA, repeats: int = 3) -> dict:
    """Time both commands; returns seconds (``odolab_s``, ``evo_ape_s``) and ``ratio`` = ours / evo.

    ``evo_ape_s`` and ``ratio`` are None when evo is not installed.
    """
    data = Path(data_dir)
    gt, est = data / "KITTI_00_gt.txt", data / "KITTI_00_ORB.txt"
    for f in (gt, est):
        if not f.exists():
            raise FileNotFoundError(f"benchmark data missing: {f}")
    ours_cmd = [sys.executable, "-m", "odolab.evaluate", str(gt), str(est), "--format", "kitti", "--align", "se3"]
    ours = _best_wall_time(ours_cmd, repeats)
    evo = _evo_ape()
    theirs = _best_wall_time([evo, "kitti", str(gt), str(est), "-a"], repeats) if evo else None
    return {
        "data": "KITTI 00, ORB-SLAM estimate (evo test data), 4541 poses",
        "odolab_cmd": "python -m odolab.evaluate GT EST --format kitti --align se3 (ATE + RPE + t_rel/r_rel)",
        "evo_cmd": "evo_ape kitti GT EST -a (ATE only)",
        "repeats": repeats,
        "odolab_s": ours,
        "evo_ape_s": theirs,
        "ratio": None if theirs is None else ours / theirs,
    }
