"""The navigating agent: it never sees its true pose. It is told the goal relative to its start,
integrates an odometer's motions into its own pose estimate, and maps and plans with that estimate.

Frames: the agent's *belief frame* is the world as it believes it, with its start at the origin
facing +X (its own x forward, y left, metres; yaw counter-clockwise). The goal arrives once, in the
start frame (the Challenge's static point-goal sensor); each step the odometer's ``T_prev_cur``
moves the believed camera pose, and the goal relative to the agent is recomputed from it (the
paper's eq. 1): g_t = R(-yaw_t) (g_0 - p_t).

Policy (classical map-and-plan, so that what is measured is the odometry; :class:`PolicyConfig`):
depth pixels (every ``stride``-th) are back-projected with the believed pose; points whose height
above the floor lies in [``min_height``, ``max_height``] m and whose depth is at most ``max_range``
m vote for an obstacle cell (a cell is an obstacle after ``votes`` votes) in a grid of ``cell`` m
cells; cells nearer than the agent radius to an obstacle are blocked, and those within a further
``margin`` are passable at ``margin_speed`` times the speed (so a gap just wide enough is taken when
going round would cost more; unknown cells are traversable); fast marching from the believed goal
gives a travel-time field in metres at full speed (over the box spanning the agent and the goal plus
``plan_margin``, or the whole map when that box holds no way; when the whole map holds none either, as
when a noisy map narrows a doorway below the agent's width, the whole map again for an agent of
radius ``fallback_radius``, 0 = never); the agent heads for the lowest field
value on a circle of 0.25 m around it, among the headings whose straight step passes no obstacle cell
nearer than ``obstacle_gap`` (when none has a finite value, as inside a wall's inflated band, the open
heading nearest the goal's direction; when none is open, the goal's direction; obstacle cells within
``own_clearance`` of the believed position, where the agent itself stands, are misregistered and
ignored by the check): it moves forward when that
heading is within
``heading_tolerance`` of its own, else turns towards it; a forward step that moved the belief by
less than ``stuck_distance`` marks the cell ahead as an obstacle. It calls STOP when the believed
goal is nearer than ``stop_distance``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from odolab.config import assign, check, setting
from odolab.core.errors import InputError
from odolab.core.geometry import agent_from_camera_pose, camera_pose_from_agent, wrap_angle
from odolab.core.types import FORWARD_STEP, Action, Intrinsics


@dataclass(frozen=True)
class PolicyConfig:
    """The map-and-plan policy's parameters (module docstring); lengths in m, angles in degrees."""

    cell: float = setting(0.05, range=(0.02, 1.0), doc="map cell edge, m")
    stride: int = setting(4, range=(1, 64), doc="every n-th depth pixel row and column is back-projected")
    min_height: float = setting(0.15, range=(0.0, 3.0), doc="lowest obstacle point above the floor, m")
    max_height: float = setting(1.2, range=(0.0, 3.0), open_low=True, doc="highest obstacle point above the floor, m")
    max_range: float = setting(3.0, range=(0.1, 10.0), doc="depth readings beyond this are not mapped, m")
    votes: int = setting(2, range=(1, 1000), doc="votes that make a cell an obstacle")
    agent_radius: float = setting(0.18, range=(0.0, 1.0), doc="cells nearer than this to an obstacle are blocked, m")
    margin: float = setting(0.05, range=(0.0, 1.0), doc="a further band round obstacles passed at margin_speed, m")
    margin_speed: float = setting(
        0.5, range=(0.0, 1.0), open_low=True, doc="relative speed through the margin band round obstacles"
    )
    heading_tolerance: float = setting(
        15.0, range=(0.0, 180.0), open_high=True, doc="move forward when the best heading is this near, degrees"
    )
    stop_distance: float = setting(0.2, range=(0.01, 10.0), doc="call STOP when the believed goal is nearer, m")
    stuck_distance: float = setting(
        0.05, range=(0.0, 1.0), doc="a forward step moving the belief less marks the cell ahead an obstacle, m"
    )
    extent: float = setting(8.0, range=(0.5, 20.0), doc="map margin beyond the box round start and goal, m")
    plan_margin: float = setting(5.0, range=(0.5, 20.0), doc="planning window margin round the agent and the goal, m")
    memory: int = setting(1000, range=(1, 10**6), doc="steps an obstacle is remembered without being seen again")
    obstacle_gap: float = setting(
        0.05, range=(0.0, 0.5), doc="a forward step's straight path keeps this far from obstacle cells, m"
    )
    own_clearance: float = setting(
        0.1, range=(0.0, 0.5), doc="obstacle cells this near the believed position are ignored by that check, m"
    )
    fallback_radius: float = setting(
        0.1, range=(0.0, 1.0), open_high=True, doc="the narrower agent planned for when no way fits; 0: off"
    )

    def __post_init__(self) -> None:
        check(self)  # a 1e-6 m cell or a 1e6 m map would not fit in memory
        if not self.min_height < self.max_height:
            raise ValueError(f"need min_height < max_height, got {self.min_height:g}, {self.max_height:g}")
        if self.fallback_radius >= self.agent_radius and self.fallback_radius != 0:
            default = " (its default)" if self.fallback_radius == PolicyConfig.fallback_radius else ""
            raise ValueError(
                f"need fallback_radius < agent_radius, got fallback_radius {self.fallback_radius:g}"
                f"{default} and agent_radius {self.agent_radius:g}: set fallback_radius below "
                f"{self.agent_radius:g}, or to 0 to turn the fallback off"
            )

    @classmethod
    def from_assignments(cls, items: list[str]) -> PolicyConfig:
        """The default policy with ``key=value`` changes (``heading_tolerance=30``); :class:`PolicyError`
        naming the item for an unknown key, a value that is not a number of the field's kind, or a
        value out of range (:func:`odolab.config.assign`)."""
        return assign(cls, items, error=PolicyError)


class PolicyError(InputError):
    """``key=value`` changes of :class:`PolicyConfig` that cannot be made; ``named("--policy")`` words
    it after a command line's option."""

    subject = "policy"


def in_agent_frame(point: np.ndarray, x: float, y: float, yaw: float) -> np.ndarray:
    """A point (world x, y, m) seen from an agent at (x, y) with heading ``yaw`` (rad): (forward, left) m."""
    d = np.asarray(point, np.float64) - (x, y)
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])


class OccupancyMap:
    """Obstacle votes in a square grid of the belief frame covering ``[-half, half]^2`` m, with the
    step each cell was last voted for (so that old, possibly misregistered obstacles can be forgotten)."""

    def __init__(self, half: float, cell: float) -> None:
        self.cell = cell
        self.n = int(np.ceil(2 * half / cell))
        self.half = self.n * cell / 2
        self.votes = np.zeros((self.n, self.n), np.int32)
        self.last = np.full((self.n, self.n), -(1 << 30), np.int64)
        self.step = 0

    def to_cell(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(row, col, inside) of belief-frame points: row along y, col along x."""
        c = np.floor((np.asarray(x) + self.half) / self.cell).astype(np.int64)
        r = np.floor((np.asarray(y) + self.half) / self.cell).astype(np.int64)
        inside = (r >= 0) & (r < self.n) & (c >= 0) & (c < self.n)
        return r, c, inside

    def to_world(self, r: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (np.asarray(c) + 0.5) * self.cell - self.half, (np.asarray(r) + 0.5) * self.cell - self.half

    def vote(self, x: np.ndarray, y: np.ndarray, weight: int = 1) -> None:
        r, c, inside = self.to_cell(x, y)
        np.add.at(self.votes, (r[inside], c[inside]), weight)
        self.last[r[inside], c[inside]] = self.step

    def obstacles(self, votes: int, memory: int) -> np.ndarray:
        """Cells with at least ``votes`` votes, last voted within ``memory`` steps."""
        return (self.votes >= votes) & (self.step - self.last <= memory)


class MapPlanAgent:
    """Chooses actions from depth frames and odometry alone (module docstring)."""

    def __init__(
        self,
        goal_start: tuple[float, float],
        intrinsics: Intrinsics,
        mount_height: float,
        config: PolicyConfig | None = None,
    ) -> None:
        self.cfg = config or PolicyConfig()
        self.goal = np.asarray(goal_start, np.float64)
        self.K, self.height = intrinsics, float(mount_height)
        self.pose = camera_pose_from_agent(0.0, 0.0, 0.0, self.height)  # believed T_world_cam
        half = max(abs(self.goal).max(), 1.0) + self.cfg.extent
        self.map = OccupancyMap(half, self.cfg.cell)
        self._last_action: Action | None = None
        self._last_xy = np.zeros(2)
        self.plan_seconds = 0.0  # wall time spent in fast marching so far (the benchmark reads it)

    @property
    def belief(self) -> tuple[float, float, float]:
        """Believed (x m, y m, yaw rad) in the belief frame."""
        return agent_from_camera_pose(self.pose)

    def relative_goal(self) -> np.ndarray:
        """The goal in the agent's believed frame (x forward, y left), m: the paper's eq. 1."""
        return in_agent_frame(self.goal, *self.belief)

    def update(self, T_prev_cur: np.ndarray) -> None:
        """Move the belief by an odometer's motion (camera axes)."""
        self.pose = self.pose @ np.asarray(T_prev_cur, np.float64)

    def observe(self, depth: np.ndarray) -> None:
        """Vote obstacle cells from a depth image (m, 0 = no reading) at the believed pose."""
        cfg, K = self.cfg, self.K
        d = depth[:: cfg.stride, :: cfg.stride].astype(np.float64)
        v, u = np.mgrid[0 : depth.shape[0] : cfg.stride, 0 : depth.shape[1] : cfg.stride]
        ok = (d > 0) & (d <= cfg.max_range)
        z = d[ok]
        pts = np.stack([(u[ok] - K.cx) / K.fx * z, (v[ok] - K.cy) / K.fy * z, z, np.ones_like(z)])
        world = self.pose @ pts
        height = world[2] - (self.pose[2, 3] - self.height)  # above the believed floor
        keep = (height >= cfg.min_height) & (height <= cfg.max_height)
        self.map.vote(world[0, keep], world[1, keep])

    def _costs(
        self, x: float, y: float, margin: float | None, radius: float, r: np.ndarray, c: np.ndarray
    ) -> np.ndarray:
        """Fast-marching travel time (m at full speed) to the believed goal from the map cells (r, c),
        for an agent of ``radius`` m, over the traversable cells of the window spanning the agent at
        (x, y) and the goal plus ``margin`` m (None: the whole map); inf for cells off the window or
        with no way to the goal.

        Only these cells' times are needed, so the work is cut short where that cannot change
        them: distances to obstacles are taken in a box round them (beyond it they exceed the
        radius plus the margin, all that matters of them); cells with no 4-connected way to the
        goal (where fast marching never arrives) get inf without marching, and the march first
        stops at a travel time twice the farthest reachable cell's straight distance plus 2 m
        (fast marching fixes times in increasing order, so every time below the stop is the full
        march's, to the bit), marching on over the whole window only when a reachable cell lies
        beyond it."""
        import skfmm
        from scipy.ndimage import distance_transform_edt, label

        cfg, m = self.cfg, self.map
        out = np.full(len(r), np.inf)
        gr, gc, goal_inside = m.to_cell(*self.goal)
        if not goal_inside:
            return out
        ar, ac, _ = m.to_cell(x, y)
        pad = m.n if margin is None else int(np.ceil(margin / cfg.cell))
        r0, r1 = max(min(ar, gr) - pad, 0), min(max(ar, gr) + pad + 1, m.n)
        c0, c1 = max(min(ac, gc) - pad, 0), min(max(ac, gc) + pad + 1, m.n)
        obstacle = m.obstacles(cfg.votes, cfg.memory)[r0:r1, c0:c1]
        reach = int(np.ceil((radius + cfg.margin) / cfg.cell))  # cells within which an obstacle counts
        clearance = np.full(obstacle.shape, np.inf)  # m to the nearest obstacle cell
        rows, cols = np.flatnonzero(obstacle.any(axis=1)), np.flatnonzero(obstacle.any(axis=0))
        if len(rows):  # around the obstacles only: every obstacle is in the box, so its distances are exact
            k = reach + 1
            box = (slice(max(rows[0] - k, 0), rows[-1] + k + 1), slice(max(cols[0] - k, 0), cols[-1] + k + 1))
            clearance[box] = distance_transform_edt(~obstacle[box]) * cfg.cell
        blocked = clearance < radius
        speed = np.where(clearance < radius + cfg.margin, cfg.margin_speed, 1.0)
        lr, lc = gr - r0, gc - c0
        near_goal = (slice(max(lr - reach, 0), lr + reach + 1), slice(max(lc - reach, 0), lc + reach + 1))
        blocked[near_goal], speed[near_goal] = False, 1.0  # the goal may sit beside a wall
        parts, _ = label(~blocked)  # 4-connected, as fast marching spreads
        ok = (r >= r0) & (r < r1) & (c >= c0) & (c < c1)  # on the window, then joined to the goal
        ok[ok] = parts[r[ok] - r0, c[ok] - c0] == parts[lr, lc]
        if not ok.any():
            return out
        wx, wy = m.to_world(np.arange(r0, r1), np.arange(c0, c1))
        phi = np.hypot(wx[None, :] - self.goal[0], wy[:, None] - self.goal[1]) - cfg.cell
        straight = float(np.hypot(wx[c[ok] - c0] - self.goal[0], wy[r[ok] - r0] - self.goal[1]).max())
        for narrow in (2.0 * straight + 2.0, 0.0):  # 0: no stop
            d = skfmm.travel_time(np.ma.MaskedArray(phi, mask=blocked), speed, dx=cfg.cell, narrow=narrow)
            out[ok] = np.ma.filled(d.astype(np.float64), np.inf)[r[ok] - r0, c[ok] - c0]
            if np.isfinite(out[ok]).all():
                break
        return out

    def _open_headings(self, x: float, y: float, headings: np.ndarray) -> np.ndarray:
        """(len(headings),) bool: whether a forward step along each heading (rad, belief frame) from
        (x, y) keeps ``obstacle_gap`` m from every obstacle cell (sampled every half cell). The field
        is read 0.25 m ahead; without this check a wall seen as one cell thick, with unknown (free)
        cells behind it, would be stepped over in the plan and bumped into for ever."""
        cfg, m = self.cfg, self.map
        obstacle = m.obstacles(cfg.votes, cfg.memory)
        reach = int(np.ceil(cfg.obstacle_gap / cfg.cell))
        dist = np.arange(cfg.cell / 2, FORWARD_STEP + 1e-9, cfg.cell / 2)
        px = x + dist[None, :] * np.cos(headings)[:, None]
        py = y + dist[None, :] * np.sin(headings)[:, None]
        r, c, _ = m.to_cell(px, py)
        ar, ac, _ = m.to_cell(x, y)
        own = int(np.floor(cfg.own_clearance / cfg.cell))  # cells the agent stands on: ghosts if marked
        blocked = np.zeros(r.shape, bool)
        for dr in range(-reach, reach + 1):
            for dc in range(-reach, reach + 1):
                if dr * dr + dc * dc <= reach * reach:
                    rr, cc = r + dr, c + dc
                    ok = (rr >= 0) & (rr < m.n) & (cc >= 0) & (cc < m.n)
                    ok &= (rr - ar) ** 2 + (cc - ac) ** 2 > own * own
                    blocked[ok] |= obstacle[rr[ok], cc[ok]]
        return ~blocked.any(axis=1)

    def act(self, depth: np.ndarray) -> Action:
        """The next action after seeing ``depth`` at the current believed pose."""
        cfg = self.cfg
        x, y, yaw = self.belief
        if (
            self._last_action is Action.MOVE_FORWARD
            and np.hypot(x - self._last_xy[0], y - self._last_xy[1]) < cfg.stuck_distance
        ):
            ahead = np.array([x, y]) + (cfg.agent_radius + cfg.cell) * np.array([np.cos(yaw), np.sin(yaw)])
            self.map.vote(np.array([ahead[0]]), np.array([ahead[1]]), weight=cfg.votes)
        self.map.step += 1
        self.observe(depth)
        self._last_xy = np.array([x, y])
        if np.hypot(*(self.goal - (x, y))) < cfg.stop_distance:
            self._last_action = Action.STOP
            return Action.STOP
        headings = yaw + np.radians(np.arange(-180, 180, 10.0))
        px, py = x + FORWARD_STEP * np.cos(headings), y + FORWARD_STEP * np.sin(headings)
        r, c, inside = self.map.to_cell(px, py)
        cost = np.full(len(headings), np.inf)
        open_way = self._open_headings(x, y, headings)
        started = time.perf_counter()
        plans = [(cfg.plan_margin, cfg.agent_radius), (None, cfg.agent_radius)]  # the window, then the whole map
        if 0 < cfg.fallback_radius < cfg.agent_radius:
            plans.append((None, cfg.fallback_radius))  # then a narrower agent through a gap the map narrowed
        wanted = inside & open_way  # a heading that is not open costs inf whatever the plan
        for margin, radius in plans:
            cost[wanted] = self._costs(x, y, margin, radius, r[wanted], c[wanted])
            if np.isfinite(cost).any():
                break
        self.plan_seconds += time.perf_counter() - started
        if not np.isfinite(cost).any():  # off the map or boxed in (e.g. in a wall's inflated band)
            goal_dir = np.arctan2(*(self.goal - (x, y))[::-1])
            if open_way.any():  # the open heading nearest the goal's direction: out of the band first
                gap = np.abs(wrap_angle(headings - goal_dir))
                target = headings[int(np.argmin(np.where(open_way, gap, np.inf)))]
            else:  # obstacles all round in the belief (a drifted map): head for the goal
                target = goal_dir
        else:
            turn = np.abs(np.radians(np.arange(-180, 180, 10.0)))  # ties go to the smaller turn
            target = headings[int(np.argmin(cost + 1e-3 * turn))]
        error = float(wrap_angle(target - yaw))
        if abs(error) <= np.radians(cfg.heading_tolerance):
            action = Action.MOVE_FORWARD
        else:
            action = Action.TURN_LEFT if error > 0 else Action.TURN_RIGHT
        self._last_action = action
        return action
