"""Open3D's solvers on one thread, so that the same call gives the same answer.

Open3D sums its per-point terms in OpenMP reductions whose order follows thread timing: on two
threads the same ``compute_rgbd_odometry`` call on the same frames answered differently in the
last bits (up to 7e-14 here, three runs of six turns), and a closed loop (navigation) grows such
differences into different runs. On one thread the answers are identical run to run. The
classical odometers therefore call Open3D's registration inside :func:`one_thread` (the previous
setting is restored after the call, so the simulator's ray casting keeps its threads).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import open3d as o3d

__all__ = ["one_thread"]


@contextlib.contextmanager
def one_thread() -> Iterator[None]:
    """Run the block with Open3D limited to one thread."""
    before = o3d.utility.get_max_threads()
    o3d.utility.set_max_threads(1)
    try:
        yield
    finally:
        o3d.utility.set_max_threads(before)
