"""Shortest paths on the occupancy grid: geodesic distance fields and a greedy path follower.

Geodesic distance is Dijkstra over the navigable cells with 8-connectivity (edge lengths 1 and
sqrt(2) cells), in metres. The follower is Habitat's ``ShortestPathFollower`` in spirit: look a
little way down the shortest path, turn towards it when it is more than half a turn (15 deg) off
the heading, otherwise step forward; stop within ``success_distance`` of the goal.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from odolab.geometry import wrap_angle
from odolab.odometer import Action
from odolab.sim.agent import AgentState
from odolab.sim.noise import TURN_ANGLE
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
    out[nav] = dijkstra(graph, indices=int(index[r, c]))
    return out


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
    """Greedy follower of a distance (or path-cost) field ``distance`` towards its zero (the goal)."""

    scene: Scene
    distance: np.ndarray
    success_distance: float = 0.2
    lookahead: float = 0.5

    def distance_at(self, x: float, y: float) -> float:
        """Geodesic distance (m) from world point (x, y) to the goal (inf off the grid)."""
        r, c = self.scene.world_to_cell(x, y)
        rows, cols = self.distance.shape
        if not (0 <= r < rows and 0 <= c < cols):
            return float("inf")
        return float(self.distance[r, c])

    def waypoint(self, x: float, y: float) -> tuple[float, float]:
        """World point about ``lookahead`` m down the shortest path from (x, y)."""
        D = self.distance
        r, c = (int(v) for v in self.scene.world_to_cell(x, y))
        steps = int(round(self.lookahead / self.scene.resolution))
        for _ in range(steps):
            best, nxt = D[r, c], None
            for dr, dc in _NEIGHBOURS:
                rr, cc = r + dr, c + dc
                if 0 <= rr < D.shape[0] and 0 <= cc < D.shape[1] and D[rr, cc] < best:
                    best, nxt = D[rr, cc], (rr, cc)
            if nxt is None:
                break
            r, c = nxt
        wx, wy = self.scene.cell_to_world(r, c)
        return float(wx), float(wy)

    def next_action(self, state: AgentState) -> Action:
        """STOP at the goal, else turn towards the path or move forward."""
        if self.distance_at(state.x, state.y) <= self.success_distance:
            return Action.STOP
        wx, wy = self.waypoint(state.x, state.y)
        if np.hypot(wx - state.x, wy - state.y) < 1e-6:
            return Action.MOVE_FORWARD
        err = wrap_angle(np.arctan2(wy - state.y, wx - state.x) - state.yaw)
        if abs(err) <= TURN_ANGLE / 2:
            return Action.MOVE_FORWARD
        return Action.TURN_LEFT if err > 0 else Action.TURN_RIGHT
