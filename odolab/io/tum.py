"""TUM RGB-D trajectory files and timestamp association.

Format (Sturm et al. IROS 2012, https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats):
one pose per line, ``timestamp tx ty tz qx qy qz qw`` (seconds; metres; unit quaternion, scalar
last) giving ``T_world_cam``; ``#`` starts a comment line. The reader is strict: every problem
raises :class:`~odolab.io.errors.FileFormatError` naming the file and line.
"""

from __future__ import annotations

import os

import numpy as np

from odolab.core.trajectory import Trajectory
from odolab.io.atomic import write_text_atomic
from odolab.io.errors import FileFormatError
from odolab.io.textfiles import format_rows, read_numeric_rows

__all__ = [
    "associate",
    "matrix_to_quaternion",
    "quaternion_to_matrix",
    "read_tum_file",
    "read_tum_trajectory",
    "write_tum_trajectory",
]

_LAYOUT = "t tx ty tz qx qy qz qw"
_ZERO_QUAT = 1e-12


def quaternion_to_matrix(q_xyzw: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(N, 3, 3)`` of quaternions ``(N, 4)`` (x, y, z, w); normalised first."""
    q = np.asarray(q_xyzw, dtype=np.float64).reshape(-1, 4)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    x, y, z, w = q.T
    R = np.empty((len(q), 3, 3))
    R[:, 0, 0] = 1 - 2 * (y * y + z * z)
    R[:, 0, 1] = 2 * (x * y - z * w)
    R[:, 0, 2] = 2 * (x * z + y * w)
    R[:, 1, 0] = 2 * (x * y + z * w)
    R[:, 1, 1] = 1 - 2 * (x * x + z * z)
    R[:, 1, 2] = 2 * (y * z - x * w)
    R[:, 2, 0] = 2 * (x * z - y * w)
    R[:, 2, 1] = 2 * (y * z + x * w)
    R[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def matrix_to_quaternion(R: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(N, 4)`` (x, y, z, w), ``w >= 0``, of rotation matrices ``(N, 3, 3)``.

    Branch-free variant of Shepperd's method: each row uses its best-conditioned pivot.
    """
    R = np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)
    m00, m11, m22 = R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]
    # Four candidate solutions, each scaled by 4 * (its pivot component).
    cand = np.stack(
        [
            np.stack(
                [1 + m00 - m11 - m22, R[:, 0, 1] + R[:, 1, 0], R[:, 0, 2] + R[:, 2, 0], R[:, 2, 1] - R[:, 1, 2]], -1
            ),
            np.stack(
                [R[:, 0, 1] + R[:, 1, 0], 1 - m00 + m11 - m22, R[:, 1, 2] + R[:, 2, 1], R[:, 0, 2] - R[:, 2, 0]], -1
            ),
            np.stack(
                [R[:, 0, 2] + R[:, 2, 0], R[:, 1, 2] + R[:, 2, 1], 1 - m00 - m11 + m22, R[:, 1, 0] - R[:, 0, 1]], -1
            ),
            np.stack(
                [R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1], 1 + m00 + m11 + m22], -1
            ),
        ],
        axis=1,
    )  # (N, 4 candidates, 4 components)
    pivot = np.argmax(np.stack([m00 - m11 - m22, -m00 + m11 - m22, -m00 - m11 + m22, m00 + m11 + m22], -1), axis=1)
    q = cand[np.arange(len(R)), pivot]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q *= np.where(q[:, 3:] < 0, -1.0, 1.0)
    return q


def read_tum_trajectory(path: str | os.PathLike) -> Trajectory:
    """Read a TUM trajectory file into poses ``T_world_cam`` with timestamps (s).

    Same as :func:`read_tum_file` without the count of dropped duplicate timestamps.
    """
    return read_tum_file(path)[0]


def read_tum_file(path: str | os.PathLike) -> tuple[Trajectory, int]:
    """Read a TUM trajectory file: ``(poses T_world_cam with timestamps (s), duplicates dropped)``.

    A timestamp equal to the previous line's (real TUM ground-truth files have some) keeps the
    first line and drops the repeat, as evo does; the count of dropped lines is returned.
    Quaternions are normalised; a zero quaternion, a non-finite number, a wrong column count,
    a timestamp before the previous one, or an empty file raise
    :class:`~odolab.io.errors.FileFormatError`.
    """
    rows, line_nos = read_numeric_rows(path, 8, _LAYOUT)
    stamps = rows[:, 0]
    steps = np.diff(stamps)
    bad = np.flatnonzero(steps < 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise FileFormatError(
            path,
            int(line_nos[k]),
            f"timestamp goes backwards: {float(stamps[k])!r} (previous line {line_nos[k - 1]} has "
            f"{float(stamps[k - 1])!r}); timestamps must increase",
        )
    keep = np.concatenate([[True], steps > 0])
    rows, line_nos = rows[keep], line_nos[keep]
    # a quaternion with a component beyond 1e100 is divided by its largest one first (one of 1e308
    # then normalises without overflow); the others are read as they are
    quats = rows[:, 4:8].copy()
    largest = np.abs(quats).max(axis=1, keepdims=True)
    np.divide(quats, largest, out=quats, where=largest > 1e100)
    norms = np.linalg.norm(quats, axis=1)
    zero = np.flatnonzero(norms < _ZERO_QUAT)
    if zero.size:
        q = rows[zero[0], 4:8]
        said = (
            "zero quaternion (qx qy qz qw all 0)"
            if not np.any(q)
            else (
                f"quaternion ({' '.join(f'{v:g}' for v in q)}) too near zero to normalise (norm below {_ZERO_QUAT:g})"
            )
        )
        raise FileFormatError(path, int(line_nos[zero[0]]), said)
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :3] = quaternion_to_matrix(quats)
    poses[:, :3, 3] = rows[:, 1:4]
    return Trajectory(rows[:, 0].copy(), poses), int((~keep).sum())


def write_tum_trajectory(path: str | os.PathLike, traj: Trajectory) -> None:
    """Write ``traj`` (timestamps required) as a TUM file, atomically (temp file + rename)."""
    if traj.timestamps is None:
        raise ValueError("write_tum_trajectory: the trajectory has no timestamps")
    values = np.column_stack([traj.timestamps, traj.positions, matrix_to_quaternion(traj.poses[:, :3, :3])])
    write_text_atomic(path, "# " + _LAYOUT + "\n" + format_rows(values))


def associate(t_ref: np.ndarray, t_est: np.ndarray, max_diff: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Pair timestamps (s) by nearest time, exactly as evo's ``sync.associate_trajectories``.

    Rule (evo 1.38, ``evo/core/sync.py``, nearest-time method): the list with fewer stamps is the
    *short* one (``t_est`` when both are equally long). Each short stamp that lies within
    ``[long[0] - max_diff, long[-1] + max_diff]`` is paired with its nearest long stamp if the gap
    is ``<= max_diff``; on an exact tie the earlier long stamp wins. Short stamps without a partner
    are dropped. Every short stamp is used at most once; a long stamp can in principle be the
    nearest of two short ones (only when the short list is locally denser), as in evo.

    Both inputs must be increasing. Returns index arrays ``(idx_ref, idx_est)`` of equal length,
    increasing along the short list.
    """
    t_ref = np.asarray(t_ref, dtype=np.float64).reshape(-1)
    t_est = np.asarray(t_est, dtype=np.float64).reshape(-1)
    for name, t in (("t_ref", t_ref), ("t_est", t_est)):
        if np.any(np.diff(t) < 0):
            raise ValueError(f"associate: {name} must be sorted in increasing order")
    empty = np.zeros(0, dtype=np.intp)
    if len(t_ref) == 0 or len(t_est) == 0:
        return empty, empty
    ref_is_short = len(t_est) > len(t_ref)
    short, long_ = (t_ref, t_est) if ref_is_short else (t_est, t_ref)

    in_range = (short >= long_[0] - max_diff) & (short <= long_[-1] + max_diff)
    upper = np.minimum(np.searchsorted(long_, short, side="right"), len(long_) - 1)
    diff_ub = long_[upper] - short
    diff_lb = np.where(upper > 0, short - long_[np.maximum(upper - 1, 0)], np.inf)
    take_ub = (diff_ub <= max_diff) & (diff_ub < diff_lb)
    take_lb = ~take_ub & (diff_lb <= max_diff) & (diff_lb <= diff_ub)
    keep = in_range & (take_ub | take_lb)
    idx_short = np.flatnonzero(keep)
    idx_long = np.where(take_ub, upper, upper - 1)[keep].astype(np.intp)
    return (idx_short, idx_long) if ref_is_short else (idx_long, idx_short)
