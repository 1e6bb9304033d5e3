"""PointNav metrics exactly as habitat-lab defines them (``habitat/tasks/nav/nav.py``; facts in
``docs/reference-facts.md`` section 9); their means with 95 % intervals come from :mod:`odolab.core.stats`.

With d_0 the geodesic distance from start to goal, d_T the geodesic distance at the end, p the
agent's path length (the summed straight-line lengths of its actual steps, true positions):

* success S = 1 if the agent called STOP with d_T < ``SUCCESS_DISTANCE`` (0.36 m), else 0;
* SPL = S * d_0 / max(d_0, p);
* SoftSPL = max(0, 1 - d_T / d_0) * d_0 / max(d_0, p) (no STOP needed).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Habitat PointNav Challenge 2020: stop within this geodesic distance (m) of the goal.
SUCCESS_DISTANCE = 0.36


def path_length(positions: np.ndarray) -> float:
    """Summed straight-line lengths (m) between consecutive positions (N, 2) or (N, 3)."""
    p = np.asarray(positions, np.float64)
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0


@dataclass(frozen=True)
class EpisodeOutcome:
    """One navigation episode: start geodesic distance ``d0`` m, final geodesic distance ``d_end``
    m, path length ``path`` m, whether STOP was called, steps taken and collisions."""

    d0: float
    d_end: float
    path: float
    stopped: bool
    steps: int = 0
    collisions: int = 0

    def __post_init__(self) -> None:
        if not self.d0 > 0:
            raise ValueError(f"the start distance d0 must be > 0 m, got {self.d0}")

    @property
    def success(self) -> float:
        return float(self.stopped and self.d_end < SUCCESS_DISTANCE)

    @property
    def efficiency(self) -> float:
        return self.d0 / max(self.d0, self.path)

    @property
    def spl(self) -> float:
        return self.success * self.efficiency

    @property
    def soft_spl(self) -> float:
        return max(0.0, 1.0 - self.d_end / self.d0) * self.efficiency


def belief_error(row: dict) -> float:
    """How far the agent's belief is from the truth when the episode ends: the distance (m, world
    frame) between its true and its believed final position, the odometry's closed-loop drift (the
    believed path starts on the true start, so this is the error the odometer accumulated)."""
    return float(
        np.hypot(*(np.asarray(row["true_xy"][-1], np.float64) - np.asarray(row["believed_xy"][-1], np.float64)))
    )
