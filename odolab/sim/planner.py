"""Shortest paths on the occupancy grid: geodesic distance fields and Habitat's greedy follower.

Geodesic distance is the solution of the eikonal equation over the navigable cells (second-order
fast marching, scikit-fmm), in metres: unlike Dijkstra on an 8-connected grid it has no
direction-dependent overestimate (up to 8 % there). Between cell centres it is interpolated
bilinearly.

:class:`ShortestPathFollower` chooses actions as habitat-sim's ``GreedyGeodesicFollower`` does (the
follower behind habitat-lab's ``ShortestPathFollower``, which made the paper's data; MIT-licensed
``src/esp/nav/GreedyFollower.cpp``): it tries every primitive ``[turn] * n + [forward]`` (n = 0..6,
left first, then right) with the agent's own move_forward (in habitat-lab's noisy PointNav
setting that is the noisy actuation, so each look-ahead draws fresh noise) and scores it

    (geodesic before - geodesic after) / 0.25 m  - 0.0125 n
    - 0.25 if the forward step collides  - 0.05 if it ends within 0.2 m of the navigable edge,

keeps the best score above -0.25, stops searching once a score exceeds 0.99, and emits the first
action of the winner (if nothing beats -0.25, habitat reports an error; we turn left and look again); STOP once the geodesic distance is below the goal radius. When the last 16
actions alternate left/right it commits to a whole primitive (its "thrashing" fix).
"""

from __future__ import annotations

import itertools
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from odolab.core.types import FORWARD_STEP, TURN_ANGLE, Action
from odolab.sim.agent import AgentState, advance, apply_motion
from odolab.sim.noise import ActuationNoise
from odolab.sim.scenes import Scene

UNREACHABLE = np.inf


@dataclass(frozen=True)
class GeodesicField:
    """Geodesic distance (m) from one goal to every cell of ``scene``'s grid (inf: unreachable)."""

    scene: Scene
    distance: np.ndarray  # (rows, cols)
    _filled: np.ndarray = field(repr=False)  # unreachable cells take their nearest reachable value

    def at(self, x: float, y: float) -> float:
        """Bilinearly interpolated distance at world point (x, y); inf off navigable space. (A
        navigable cell that fast marching did not reach, e.g. one joined to the rest only through a
        diagonal, takes the value of its nearest reached cell.)"""
        sc = self.scene
        r, c = sc.world_to_cell(x, y)
        rows, cols = self.distance.shape
        if not (0 <= r < rows and 0 <= c < cols) or not sc.navigable[r, c] or not np.isfinite(self._filled[r, c]):
            return UNREACHABLE
        fr = (y - sc.origin[1]) / sc.resolution - 0.5
        fc = (x - sc.origin[0]) / sc.resolution - 0.5
        r0 = int(np.clip(np.floor(fr), 0, rows - 2))
        c0 = int(np.clip(np.floor(fc), 0, cols - 2))
        a, b = float(np.clip(fr - r0, 0, 1)), float(np.clip(fc - c0, 0, 1))
        f = self._filled
        return float(
            (1 - a) * ((1 - b) * f[r0, c0] + b * f[r0, c0 + 1]) + a * ((1 - b) * f[r0 + 1, c0] + b * f[r0 + 1, c0 + 1])
        )


def geodesic_field(scene: Scene, x: float, y: float) -> GeodesicField:
    """Geodesic distances from world point (x, y) over ``scene.navigable`` (fast marching)."""
    import skfmm
    from scipy.ndimage import distance_transform_edt

    res = scene.resolution
    rows, cols = scene.navigable.shape
    cx, cy = scene.cell_to_world(np.arange(rows), np.arange(cols))
    # zero level set: a circle of one cell around the goal; distances are then shifted back by it
    phi = np.hypot(cx[None, :] - x, cy[:, None] - y) - res
    r, c = scene.world_to_cell(x, y)
    inside = 0 <= r < rows and 0 <= c < cols
    dist = np.full((rows, cols), UNREACHABLE)
    if inside and scene.navigable[r, c]:
        d = skfmm.distance(np.ma.MaskedArray(phi, mask=~scene.navigable), dx=res)
        reached = ~np.ma.getmaskarray(d)
        dist[reached] = np.maximum(np.asarray(d)[reached] + res, 0.0)
    reach = np.isfinite(dist)
    if reach.any():
        _, (ir, ic) = distance_transform_edt(~reach, return_indices=True)
        filled = dist[ir, ic]
    else:
        filled = dist
    return GeodesicField(scene, dist, filled)


def largest_component(scene: Scene) -> np.ndarray:
    """Mask of the largest 4-connected navigable region (the connectivity fast marching uses)."""
    from scipy.ndimage import label

    lab, n = label(scene.navigable)
    if n == 0:
        return np.zeros_like(scene.navigable)
    sizes = np.bincount(lab.ravel())[1:]
    return lab == (1 + int(np.argmax(sizes)))


def edge_distance(scene: Scene) -> np.ndarray:
    """Distance (m) of each cell centre to the nearest non-navigable cell (habitat-sim's
    ``distance_to_closest_obstacle`` on the navmesh, which is already shrunk by the agent radius)."""
    from scipy.ndimage import distance_transform_edt

    return distance_transform_edt(scene.navigable) * scene.resolution


# habitat-sim GreedyGeodesicFollowerImpl constants
COLLISION_COST = 0.25
CLOSE_TO_OBSTACLE = 0.2  # m
CLOSE_COST = 0.05
TURN_COST = 0.0125
GOOD_ENOUGH = 0.99
THRASHING_THRESHOLD = 16


@dataclass
class ShortestPathFollower:
    """Habitat's greedy geodesic follower towards the goal of ``geodesic`` (module docstring).

    ``goal_radius`` (m): STOP when the geodesic distance is below it (the PointNav success distance).
    """

    geodesic: GeodesicField
    goal_radius: float = 0.36
    noise: ActuationNoise | None = None  # the look-ahead's forward step: noiseless if None
    rng: np.random.Generator | None = None  # draws the look-ahead's noise
    stop_at_contact: bool = True  # the agent's collision rule (odolab.sim.agent.advance)
    _edge: np.ndarray = field(init=False, repr=False)
    _history: deque = field(init=False, repr=False)
    _queued: list = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._edge = edge_distance(self.geodesic.scene)
        self._history = deque(maxlen=THRASHING_THRESHOLD)
        self._queued = []

    def _edge_at(self, x: float, y: float) -> float:
        r, c = self.geodesic.scene.world_to_cell(x, y)
        rows, cols = self._edge.shape
        return float(self._edge[r, c]) if 0 <= r < rows and 0 <= c < cols else 0.0

    def _reward(self, state: AgentState, yaw: float, turns: int, here: float) -> float:
        if self.noise is None:
            x, y, collided = advance(
                self.geodesic.scene,
                state.x,
                state.y,
                state.x + FORWARD_STEP * np.cos(yaw),
                state.y + FORWARD_STEP * np.sin(yaw),
                self.stop_at_contact,
            )
        else:  # habitat's follower tries the agent's own (noisy) move_forward
            end, collided = apply_motion(
                self.geodesic.scene,
                AgentState(state.x, state.y, yaw),
                self.noise.sample(Action.MOVE_FORWARD, self.rng),
                self.stop_at_contact,
            )
            x, y = end.x, end.y
        after = self.geodesic.at(x, y)
        return (
            (here - after) / FORWARD_STEP
            - TURN_COST * turns
            - (COLLISION_COST if collided else 0.0)
            - (CLOSE_COST if self._edge_at(x, y) < CLOSE_TO_OBSTACLE else 0.0)
        )

    def best_primitive(self, state: AgentState) -> list[Action]:
        """The best ``[turn] * n + [MOVE_FORWARD]`` from ``state`` ([] if none beats a collision)."""
        here = self.geodesic.at(state.x, state.y)
        best, best_prim = -COLLISION_COST, []
        for n in range(int(round(np.pi / TURN_ANGLE)) + 1):  # up to a half turn
            for turn, sign in ((Action.TURN_LEFT, 1.0), (Action.TURN_RIGHT, -1.0)):
                reward = self._reward(state, state.yaw + sign * n * TURN_ANGLE, n, here)
                if reward > best:
                    best, best_prim = reward, [turn] * n + [Action.MOVE_FORWARD]
            if best > GOOD_ENOUGH:
                break
        return best_prim

    def _thrashing(self) -> bool:
        h = list(self._history)
        if len(h) < THRASHING_THRESHOLD or h[-1] not in (Action.TURN_LEFT, Action.TURN_RIGHT):
            return False
        return all({a, b} == {Action.TURN_LEFT, Action.TURN_RIGHT} for a, b in itertools.pairwise(h))

    def next_action(self, state: AgentState) -> Action:
        """STOP at the goal, else the first action of the best primitive (TURN_LEFT if boxed in)."""
        if self.geodesic.at(state.x, state.y) < self.goal_radius:
            return Action.STOP
        if self._queued:
            action = self._queued.pop(0)
        else:
            prim = self.best_primitive(state) or [Action.TURN_LEFT]
            if self._thrashing():
                self._queued = prim[1:]
            action = prim[0]
        self._history.append(action)
        return action
