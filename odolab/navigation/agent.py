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
radius ``fallback_radius``, 0 = never; with ``plan_step`` n > 1 the field beyond ``fine_radius`` of the
agent is marched on blocks of n x n cells and joined to a march on every cell near the agent, a few
times faster and not the same field: docs/navigation.md#speed; with ``plan_every`` n > 1 it marches
every n-th step, or sooner when the last field has no time at any open heading, and reads the last
field between); the agent heads for the lowest field
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

import dataclasses
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
    plan_step: int = setting(
        1,
        range=(1, 8),
        doc="beyond fine_radius of the agent, fast marching runs on blocks of n x n map cells (1: every cell)",
    )
    fine_radius: float = setting(
        2.0,
        range=(1.0, 20.0),
        doc="with plan_step > 1: within this of the agent, fast marching runs on every map cell, m",
    )
    fallback_radius: float = setting(
        0.1, range=(0.0, 1.0), open_high=True, doc="the narrower agent planned for when no way fits; 0: off"
    )
    plan_every: int = setting(
        1,
        range=(1, 20),
        doc="fast marching every n-th step; between, the last field is read where it has times (1: every step)",
    )

    def __post_init__(self) -> None:
        check(self)  # a 1e-6 m cell or a 1e6 m map would not fit in memory
        if not self.min_height < self.max_height:
            raise ValueError(f"need min_height < max_height, got {self.min_height:g}, {self.max_height:g}")
        if self.plan_step == 1 and self.fine_radius != PolicyConfig.fine_radius:
            raise ValueError(
                f"fine_radius only matters with plan_step > 1, got fine_radius {self.fine_radius:g} with plan_step 1: "
                "set plan_step too, or leave fine_radius out"
            )
        if self.fallback_radius >= self.agent_radius and self.fallback_radius != 0:
            default = " (its default)" if self.fallback_radius == PolicyConfig.fallback_radius else ""
            raise ValueError(
                f"need fallback_radius < agent_radius, got fallback_radius {self.fallback_radius:g}"
                f"{default} and agent_radius {self.agent_radius:g}: set fallback_radius below "
                f"{self.agent_radius:g}, or to 0 to turn the fallback off"
            )

    def record(self) -> dict:
        """The parameters as results record them (keys of saved runs, a folder's ``config.json``):
        the coarse far field's two only where it is on (``plan_step`` > 1) and ``plan_every`` only
        where it is not 1, so a run saved before they existed names the same policy as today's default."""
        doc = dataclasses.asdict(self)
        if self.plan_step == 1:
            for name in _FAR_FIELD:
                del doc[name]
        if self.plan_every == 1:
            del doc["plan_every"]
        return doc

    @classmethod
    def completed(cls, doc: dict) -> dict:
        """A :meth:`record` with the parameters it leaves out at their defaults, as the policy it names has them."""
        defaults = cls()
        return {**{name: getattr(defaults, name) for name in (*_FAR_FIELD, "plan_every")}, **doc}

    @classmethod
    def from_assignments(cls, items: list[str]) -> PolicyConfig:
        """The default policy with ``key=value`` changes (``heading_tolerance=30``); :class:`PolicyError`
        naming the item for an unknown key, a value that is not a number of the field's kind, or a
        value out of range (:func:`odolab.config.assign`)."""
        return assign(cls, items, error=PolicyError)


#: The coarse far field's parameters (:meth:`PolicyConfig.record` leaves them out where it is off).
_FAR_FIELD = ("plan_step", "fine_radius")

#: Cells added round a cut-short march's box (:meth:`MapPlanAgent._goal_march`): fast marching's
#: times are never much below the straight distance from the goal; these keep any that are, inside.
_MARCH_GUARD = 3


def _stops(straight: float, hint: float | None) -> list[float]:
    """Where fast marching from the goal first stops, m, for cells at most ``straight`` m from it:
    at ``hint`` (when below the next), at twice ``straight`` plus 2 m, then not at all (0)."""
    stops = [2.0 * straight + 2.0, 0.0]
    return [hint, *stops] if hint is not None and 0 < hint < stops[0] else stops


def _pooled(grid: np.ndarray, f: int, reduce: np.ufunc) -> np.ndarray:
    """``reduce`` over f x f blocks of ``grid`` (the last, partial ones padded with their edge)."""
    h, w = grid.shape
    padded = np.pad(grid, ((0, -h % f), (0, -w % f)), mode="edge")
    out = padded[::f, ::f].copy()
    for i in range(f):  # f^2 strided passes: several times faster than reducing reshaped blocks
        for j in range(f):
            reduce(out, padded[i::f, j::f], out=out)
    return out


def _bilinear(grid: np.ndarray, qr: np.ndarray, qc: np.ndarray) -> np.ndarray:
    """``grid`` read at fractional (row, column) positions, bilinearly over the finite corners
    (their weights renormalised; inf where none with a weight is finite). At whole positions it is
    the cell's own value, to the bit."""
    h, w = grid.shape
    r0 = np.clip(np.floor(qr).astype(np.int64), 0, max(h - 2, 0))
    c0 = np.clip(np.floor(qc).astype(np.int64), 0, max(w - 2, 0))
    fr, fc = np.clip(qr - r0, 0.0, 1.0), np.clip(qc - c0, 0.0, 1.0)
    total, weight = np.zeros(len(qr)), np.zeros(len(qr))
    for dr, wr in ((0, 1.0 - fr), (1, fr)):
        for dc, wc in ((0, 1.0 - fc), (1, fc)):
            value = grid[np.minimum(r0 + dr, h - 1), np.minimum(c0 + dc, w - 1)]
            use = (wr * wc > 0) & np.isfinite(value)
            total[use] += wr[use] * wc[use] * value[use]
            weight[use] += wr[use] * wc[use]
    out = np.full(len(qr), np.inf)
    np.divide(total, weight, out=out, where=weight > 0)
    return out


@dataclass(frozen=True)
class _Field:
    """A fast-marching field kept for the steps that do not march (``plan_every``): travel times (m)
    on a box of map cells whose first cell is ``origin`` (row, column)."""

    times: np.ndarray
    origin: tuple[int, int]

    def at(self, r: np.ndarray, c: np.ndarray) -> np.ndarray:
        """The times of map cells (r, c); inf off the box."""
        out = np.full(len(r), np.inf)
        rr, cc = r - self.origin[0], c - self.origin[1]
        inside = (rr >= 0) & (rr < self.times.shape[0]) & (cc >= 0) & (cc < self.times.shape[1])
        out[inside] = self.times[rr[inside], cc[inside]]
        return out


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
        self._voted = 0  # vote() calls so far: with the step, what obstacles() depends on
        self._obstacles: tuple[tuple[int, int, int, int], np.ndarray] | None = None

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
        self._voted += 1

    def obstacles(self, votes: int, memory: int) -> np.ndarray:
        """Cells with at least ``votes`` votes, last voted within ``memory`` steps (read-only: the
        array is kept until the next vote or step)."""
        key = (votes, memory, self.step, self._voted)
        if self._obstacles is None or self._obstacles[0] != key:
            grid = (self.votes >= votes) & (self.step - self.last <= memory)
            grid.flags.writeable = False
            self._obstacles = (key, grid)
        return self._obstacles[1]


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
        self._reach_hint: float | None = None  # where the next march may first stop, m (_costs)
        self._field: _Field | None = None  # the last march's field (_costs), read between marches
        self._unplanned = 0  # steps since the last march

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
        self,
        x: float,
        y: float,
        margin: float | None,
        radius: float,
        r: np.ndarray,
        c: np.ndarray,
        hint: float | None = None,
    ) -> np.ndarray:
        """Fast-marching travel time (m at full speed) to the believed goal from the map cells (r, c),
        for an agent of ``radius`` m, over the traversable cells of the window spanning the agent at
        (x, y) and the goal plus ``margin`` m (None: the whole map); inf for cells off the window or
        with no way to the goal.

        Only these cells' times are needed, so the work is cut short where that cannot change
        them: distances to obstacles are taken in a box round them (beyond it they exceed the
        radius plus the margin, all that matters of them); cells with no 4-connected way to the
        goal (where fast marching never arrives) get inf without marching, and the march first
        stops at ``hint`` m (the caller's guess: the last step's farthest time plus a little), then
        at twice the farthest reachable cell's straight distance plus 2 m (fast marching fixes times
        in increasing order, so every time below the stop is the full march's, to the bit), marching
        on over the whole window only when a reachable cell lies beyond both. A march that stops at
        s m is run on the window's cells within s m (plus a guard of cells) of the goal along each
        axis: no time below s comes from a cell farther than s (speeds are at most 1)."""
        from scipy.ndimage import distance_transform_edt, label

        cfg, m = self.cfg, self.map
        out = np.full(len(r), np.inf)
        self._field = None
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
        qr, qc = r[ok] - r0, c[ok] - c0
        if self.cfg.plan_step > 1:
            near = self._two_level(blocked, speed, (r0, c0), (lr, lc), (ar - r0, ac - c0), qr, qc, hint)
            if near is not None:
                self._field = _Field(near[0], (r0 + near[1][0], c0 + near[1][1]))
                out[ok] = self._field.at(r[ok], c[ok])
                return out
        tx, ty = m.to_world(r[ok], c[ok])
        stops = _stops(float(np.hypot(tx - self.goal[0], ty - self.goal[1]).max()), hint)
        times = self._goal_march(blocked, speed, (r0, c0), (lr, lc), 1, stops, (qr, qc))
        self._field = _Field(times, (r0, c0))
        out[ok] = times[qr, qc]
        return out

    def _goal_march(
        self,
        blocked: np.ndarray,
        speed: np.ndarray,
        origin: tuple[int, int],
        goal: tuple[int, int],
        f: int,
        stops: list[float],
        check: tuple[np.ndarray, np.ndarray],
    ) -> np.ndarray:
        """Travel times (m) from the believed goal over a grid of ``f`` x ``f`` map-cell blocks
        (``blocked``, ``speed``: that grid; its block (0, 0) starts at map cell ``origin``; ``goal``:
        the goal's block), inf where unreached: a march stopped at each of ``stops`` in turn (0: none)
        until every block of ``check`` (rows, columns; fractional: read bilinearly) has a time. A march
        that stops at s m runs on the blocks within s m (plus a guard) of the goal along each axis: no
        time below s comes from a block farther (speeds are at most 1)."""
        import skfmm

        cfg, m = self.cfg, self.map
        dx, o = f * cfg.cell, (f - 1) / 2  # a block's size, and its centre in map cells
        wx, wy = m.to_world(
            origin[0] + o + f * np.arange(blocked.shape[0]), origin[1] + o + f * np.arange(blocked.shape[1])
        )
        phi = np.hypot(wx[None, :] - self.goal[0], wy[:, None] - self.goal[1]) - dx
        for narrow in stops:
            times = np.full(phi.shape, np.inf)
            n = max(phi.shape) if narrow == 0 else int(np.ceil(narrow / dx)) + _MARCH_GUARD
            box = (slice(max(goal[0] - n, 0), goal[0] + n + 1), slice(max(goal[1] - n, 0), goal[1] + n + 1))
            # skfmm reads its arrays' memory as C-ordered: a strided view gives wrong results or errors
            part = np.ma.MaskedArray(np.ascontiguousarray(phi[box]), mask=np.ascontiguousarray(blocked[box]))
            d = skfmm.travel_time(part, np.ascontiguousarray(speed[box]), dx=dx, narrow=narrow)
            times[box] = np.ma.filled(d.astype(np.float64), np.inf)
            if np.isfinite(_bilinear(times, *check)).all():
                break
        return times

    def _two_level(
        self,
        blocked: np.ndarray,
        speed: np.ndarray,
        origin: tuple[int, int],
        goal: tuple[int, int],
        agent: tuple[int, int],
        qr: np.ndarray,
        qc: np.ndarray,
        hint: float | None,
    ) -> tuple[np.ndarray, tuple[int, int]] | None:
        """Travel times (m) to the goal of the window cells near the agent (window cell ``agent``),
        on the box round it, and the box's first window cell (row, column): far from it on blocks of ``plan_step`` x ``plan_step`` cells (a block
        passable where any of its cells is, at its fastest cell's speed: no way closes), near it on
        every cell: a march over the cells within ``fine_radius`` of the agent from the coarse
        field's level set ``fine_radius`` - 0.5 m nearer the goal than the agent, plus that level.
        None (the caller then marches on every cell) where the agent is within ``fine_radius`` of
        the goal, or the coarse field does not reach the agent, or its level set misses the box,
        or a cell asked (``qr``, ``qc``) gets no time."""
        import skfmm

        cfg, f = self.cfg, self.cfg.plan_step
        n = int(np.ceil(cfg.fine_radius / cfg.cell))
        if max(abs(agent[0] - goal[0]), abs(agent[1] - goal[1])) <= n:
            return None
        coarse_blocked, coarse_speed = _pooled(blocked, f, np.logical_and), _pooled(speed, f, np.maximum)
        o = (f - 1) / 2
        at = (np.array([(agent[0] - o) / f]), np.array([(agent[1] - o) / f]))
        straight = float(np.hypot(*(np.subtract(agent, goal) * cfg.cell)))
        coarse = self._goal_march(
            coarse_blocked, coarse_speed, origin, (goal[0] // f, goal[1] // f), f, _stops(straight + 1.0, hint), at
        )
        here = float(_bilinear(coarse, *at)[0])
        if not np.isfinite(here):
            return None
        level = here - (cfg.fine_radius - 0.5)
        rows = slice(max(agent[0] - n, 0), min(agent[0] + n + 1, blocked.shape[0]))
        cols = slice(max(agent[1] - n, 0), min(agent[1] + n + 1, blocked.shape[1]))
        if not ((qr >= rows.start) & (qr < rows.stop) & (qc >= cols.start) & (qc < cols.stop)).all():
            return None
        br, bc = np.mgrid[rows, cols]
        phi = (_bilinear(coarse, ((br - o) / f).ravel(), ((bc - o) / f).ravel()) - level).reshape(br.shape)
        phi[~np.isfinite(phi)] = 1e6  # no time on the coarse grid: far beyond the level
        free = ~blocked[rows, cols]
        if not ((phi < 0) & free).any() or not ((phi > 0) & free).any():
            return None
        part = np.ma.MaskedArray(phi, mask=np.ascontiguousarray(blocked[rows, cols]))
        try:
            d = skfmm.travel_time(part, np.ascontiguousarray(speed[rows, cols]), dx=cfg.cell)
        except ValueError:  # the level's free cells on either side do not touch
            return None
        near = level + np.ma.filled(d.astype(np.float64), np.inf)
        return (near, (rows.start, cols.start)) if np.isfinite(near[qr - rows.start, qc - cols.start]).all() else None

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
        if self._field is not None and self._unplanned + 1 < cfg.plan_every:  # the last field, where it has times
            cost[wanted] = self._field.at(r[wanted], c[wanted])
            self._unplanned += 1
        if not np.isfinite(cost).any():
            self._unplanned = 0
            for margin, radius in plans:
                cost[wanted] = self._costs(x, y, margin, radius, r[wanted], c[wanted], self._reach_hint)
                if np.isfinite(cost).any():
                    break
        finite = cost[np.isfinite(cost)]
        # the next step's headings lie a step from these: their times are rarely a metre beyond
        self._reach_hint = float(finite.max()) + 1.0 if len(finite) else None
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
