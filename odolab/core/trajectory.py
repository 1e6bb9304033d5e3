"""The :class:`Trajectory` value shared by every trajectory reader and writer.

A trajectory is a sequence of poses ``T_world_cam`` (4x4, metres): pose *i* maps points in the
camera frame at time/frame *i* into the trajectory's world frame (for KITTI files: camera 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Trajectory"]


@dataclass(eq=False)
class Trajectory:
    """Poses ``(N, 4, 4)`` float64 with optional timestamps ``(N,)`` float64 in seconds.

    ``timestamps`` is None for index-paired formats (KITTI).
    """

    timestamps: np.ndarray | None
    poses: np.ndarray

    def __post_init__(self) -> None:
        self.poses = np.asarray(self.poses, dtype=np.float64)
        if self.poses.ndim != 3 or self.poses.shape[1:] != (4, 4):
            raise ValueError(f"Trajectory: poses must have shape (N, 4, 4), got {self.poses.shape}")
        if self.timestamps is not None:
            self.timestamps = np.asarray(self.timestamps, dtype=np.float64).reshape(-1)
            if len(self.timestamps) != len(self.poses):
                raise ValueError(f"Trajectory: {len(self.timestamps)} timestamps for {len(self.poses)} poses")

    def __len__(self) -> int:
        return len(self.poses)

    @property
    def positions(self) -> np.ndarray:
        """Camera centres in the world frame, ``(N, 3)`` metres."""
        return self.poses[:, :3, 3]

    def subset(self, idx: np.ndarray) -> Trajectory:
        """A new trajectory holding the poses (and timestamps) at the integer indices ``idx``."""
        idx = np.asarray(idx, dtype=np.intp)
        stamps = None if self.timestamps is None else self.timestamps[idx]
        return Trajectory(stamps, self.poses[idx])
