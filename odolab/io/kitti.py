"""KITTI odometry pose files.

Format (KITTI odometry devkit, ``readme.txt``): one pose per line, 12 numbers, the first three
rows of the 4x4 ``T_cam0_cami`` in row-major order ``r11 r12 r13 tx r21 r22 r23 ty r31 r32 r33
tz`` (metres): pose *i* maps points of camera *i* into the frame of camera 0 (the first frame).
Poses pair with another file by line index; there are no timestamps.
"""

from __future__ import annotations

import os

import numpy as np

from odolab.core.trajectory import Trajectory
from odolab.io.atomic import write_text_atomic
from odolab.io.errors import FileFormatError
from odolab.io.textfiles import format_rows, read_numeric_rows

__all__ = ["ROTATION_TOLERANCE", "read_kitti_poses", "write_kitti_poses"]

#: Largest accepted ``max |R^T R - I|`` (files store rotations with ~7 significant digits).
ROTATION_TOLERANCE = 1e-3
_LAYOUT = "r11 r12 r13 tx r21 r22 r23 ty r31 r32 r33 tz"


def read_kitti_poses(path: str | os.PathLike) -> Trajectory:
    """Read a KITTI pose file into poses ``T_cam0_cami`` (``timestamps`` None).

    Raises :class:`~odolab.io.errors.FileFormatError` for a wrong column count, a non-finite or
    non-numeric value, an empty file, or a 3x3 block that is not a rotation
    (``max |R^T R - I| > ROTATION_TOLERANCE`` or ``det R < 0``). Rotations are stored as read.
    """
    rows, line_nos = read_numeric_rows(path, 12, _LAYOUT)
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :] = rows.reshape(-1, 3, 4)
    R = poses[:, :3, :3]
    ortho = np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(R)
    bad = np.flatnonzero((ortho > ROTATION_TOLERANCE) | (det < 0))
    if bad.size:
        k = int(bad[0])
        detail = (
            f"det = {det[k]:.3g} < 0 (a reflection)"
            if det[k] < 0 and ortho[k] <= ROTATION_TOLERANCE
            else f"max |R^T R - I| = {ortho[k]:.3g} > {ROTATION_TOLERANCE:g}"
        )
        raise FileFormatError(path, int(line_nos[k]), f"rotation is not a rotation: {detail}")
    return Trajectory(None, poses)


def write_kitti_poses(path: str | os.PathLike, traj: Trajectory) -> None:
    """Write ``traj`` as a KITTI pose file (timestamps are not stored), atomically."""
    write_text_atomic(path, format_rows(traj.poses[:, :3, :].reshape(-1, 12)))
