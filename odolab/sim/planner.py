"""Shortest paths on the occupancy grid: geodesic distance fields and a greedy path follower.

Geodesic distance is Dijkstra over the navigable cells with 8-connectivity (edge lengths 1 and
sqrt(2) cells), in metres. The follower greedily descends that field one action at a time (the
paper's data came from Habitat's shortest-path follower; this is the same idea on our grid).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from odolab.sim.agent import AgentState, path_is_free
from odolab.types import FORWARD_STEP, TURN_ANGLE, Action
from odolab.sim.scenes import Scene

_NEIGHBOURS = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]


def geodesic_distance(scene: Scene, x: float, y: float, wall_penalty: float = 0.0) -> np.ndarray:
    """Geodesic distance (m) from world point (x, y) to every cell; inf where unreachable.

    ``wall_penalty`` > 0 makes cells near obstacles dearer (a path *cost*, no longer metres): an
    edge into a cell with clearance c costs ``1 + wall_penalty * clip((0.45 - c) / 0.27, 0, 1)``
    times its length, so followed paths keep off walls where there is room, as a driver would.
    """
    from scipy.ndimage import distance_transform_edt
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    clearance = np.pad(distance_transform_edt(scene.free) * scene.resolution, 1)
    cost = 1.0 + wall_penalty * np.clip((0.45 - clearance) / 0.27, 0.0, 1.0)

    nav = np.pad(scene.navigable, 1)  # a blocked border, so rolled neighbours never wrap
    index = np.full(nav.shape, -1, dtype=np.int64)
    n = int(nav.sum())
    index[nav] = np.arange(n)
    src, dst, w = [], [], []
    for dr, dc in _NEIGHBOURS:
        both = nav & np.roll(nav, (-dr, -dc), axis=(0, 1))
        src.append(index[both])
        dst.append(np.roll(index, (-dr, -dc), axis=(0, 1))[both])
        w.append(np.hypot(dr, dc) * scene.resolution * np.roll(cost, (-dr, -dc), axis=(0, 1))[both])
    graph = coo_matrix((np.concatenate(w), (np.concatenate(src), np.concatenate(dst))), shape=(n, n)).tocsr()
    r, c = scene.world_to_cell(x, y)
    out = np.full(nav.shape, np.inf)
    if 0 <= r < scene.navigable.shape[0] and 0 <= c < scene.navigable.shape[1] and nav[r + 1, c + 1]:
        out[nav] = dijkstra(graph, indices=int(index[r + 1, c + 1]))
    return out[1:-1, 1:-1]


def largest_component(scene: Scene) -> np.ndarray:
    """Mask of the largest 8-connected navigable region."""
    from scipy.ndimage import label

    lab, n = label(scene.navigable, structure=np.ones((3, 3)))
    if n == 0:
        return np.zeros_like(scene.navigable)
    sizes = np.bincount(lab.ravel())[1:]
    return lab == (1 + int(np.argmax(sizes)))


@dataclass(frozen=True)
class ShortestPathFollower:
    """Greedy follower of a distance (or path-cost) field ``distance`` towards its zero (the goal).

    For every heading reachable by turns (multiples of 30 deg), it scores the field one noiseless
    forward step ahead along that heading (inf if the step would collide) plus ``turn_cost`` per
    turn needed; it steps forward if the current heading scores best, else turns towards the best
    heading. Scores of headings do not depend on the current heading, so it never dithers.
    """

    scene: Scene
    distance: np.ndarray
    success_distance: float = 0.3
    turn_cost: float = 0.02

    def distance_at(self, x: float, y: float) -> float:
        """Field value at world point (x, y) (inf off the grid)."""
        r, c = self.scene.world_to_cell(x, y)
        rows, cols = self.distance.shape
        if not (0 <= r < rows and 0 <= c < cols):
            return float("inf")
        return float(self.distance[r, c])

    def next_action(self, state: AgentState) -> Action:
        """STOP at the goal, else MOVE_FORWARD or the turn towards the best heading."""
        here = self.distance_at(state.x, state.y)
        if here <= self.success_distance:
            return Action.STOP
        best_k, best = 0, np.inf
        for k in range(-6, 7):
            yaw = state.yaw + k * TURN_ANGLE
            x1, y1 = state.x + FORWARD_STEP * np.cos(yaw), state.y + FORWARD_STEP * np.sin(yaw)
            if not path_is_free(self.scene, state.x, state.y, x1, y1):
                continue
            score = self.distance_at(x1, y1) + self.turn_cost * abs(k)
            if score < best - 1e-9:
                best_k, best = k, score
        if not np.isfinite(best):
            return Action.TURN_LEFT  # boxed in: look around
        if best_k == 0:
            return Action.MOVE_FORWARD
        return Action.TURN_LEFT if best_k > 0 else Action.TURN_RIGHT
