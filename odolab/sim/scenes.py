"""Procedural indoor scenes: rooms split by walls with doorways, corridors, boxes and cylinders.

A :class:`Scene` is pure data (numpy): a triangle soup with one material per triangle, and the
top-down occupancy grid the agent moves on. World frame: X east, Y north, Z up, metres; the floor
is Z = 0 (see :mod:`odolab.core.geometry`).

Scene seeds are split into disjoint pools, so no test scene is ever seen in training::

    train: seeds [0, 1_000_000)   val: [1_000_000, 1_000_100)   test: [2_000_000, 2_000_100)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

SPLITS = ("train", "val", "test")
#: Actions per episode at most: the PointNav Challenge 2020's limit, and the command lines'.
MAX_EPISODE_STEPS = 500
_SPLIT_POOLS = {"train": (0, 1_000_000), "val": (1_000_000, 100), "test": (2_000_000, 100)}

WALL_HEIGHT = 2.6  # m
WALL_THICKNESS = 0.12  # m
DOOR_HEIGHT = 2.1  # m
GRID_RESOLUTION = 0.05  # m per occupancy cell
#: An episode's least geodesic start-goal distance by default, m (habitat-lab's PointNav generator: 1-30 m).
MIN_GOAL_DISTANCE = 1.0
WALL_MATERIALS = (2, 5)  # material indices [first, end) used by walls


def scene_seed(split: str, k: int) -> int:
    """The k-th scene seed of a split (k wraps around the split's pool)."""
    if split not in _SPLIT_POOLS:
        raise ValueError(f"unknown split {split!r}; expected one of {', '.join(SPLITS)}")
    start, size = _SPLIT_POOLS[split]
    return start + int(k) % size


def split_of_seed(seed: int) -> str:
    """Which split a scene seed belongs to."""
    for split, (start, size) in _SPLIT_POOLS.items():
        if start <= seed < start + size:
            return split
    raise ValueError(f"scene seed {seed} is in no split")


@dataclass(frozen=True)
class Material:
    """Surface look: base colour (RGB in [0, 1]) modulated by texture tile ``tile``."""

    color: tuple[float, float, float]
    tile: int


@dataclass(frozen=True)
class Scene:
    """A furnished floor plan.

    ``vertices`` (V, 3) float32 m; ``triangles`` (F, 3) int32; ``triangle_material`` (F,) int32 index
    into ``materials``. ``free`` (rows, cols) bool: cell (r, c) covers world
    x in [origin_x + c * res, +res), y in [origin_y + r * res, +res), True = no obstacle at any height
    the agent occupies. ``navigable`` = free cells whose centre is at least ``agent_radius`` from
    any obstacle. ``scale``: the floor plan's linear scale (:func:`generate_scene`; 1 in every
    episode's scene). ``appearance``: None for a procedural scene (materials and texture tiles),
    else a mesh file's own look (:class:`odolab.sim.mesh_scenes.MeshAppearance`). ``lights``: None
    (directional light only), or (K, 4) float32 point lights ``x, y, z`` (m) and power (about 1)
    that the renderer adds (:mod:`odolab.sim.free_scenes`).
    """

    seed: int
    vertices: np.ndarray
    triangles: np.ndarray
    triangle_material: np.ndarray
    materials: tuple[Material, ...]
    free: np.ndarray
    navigable: np.ndarray
    origin: tuple[float, float]
    resolution: float
    agent_radius: float
    scale: float = 1.0
    appearance: Any = None
    lights: np.ndarray | None = None

    def world_to_cell(self, x: np.ndarray | float, y: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """(row, col) integer indices of world points (not clipped)."""
        c = np.floor((np.asarray(x) - self.origin[0]) / self.resolution).astype(np.int64)
        r = np.floor((np.asarray(y) - self.origin[1]) / self.resolution).astype(np.int64)
        return r, c

    def cell_to_world(self, r: np.ndarray | int, c: np.ndarray | int) -> tuple[np.ndarray, np.ndarray]:
        """World (x, y) of cell centres."""
        x = self.origin[0] + (np.asarray(c) + 0.5) * self.resolution
        y = self.origin[1] + (np.asarray(r) + 0.5) * self.resolution
        return x, y

    def is_navigable(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        """True where the agent's centre may be (outside the grid counts as blocked)."""
        r, c = self.world_to_cell(x, y)
        inside = (r >= 0) & (r < self.navigable.shape[0]) & (c >= 0) & (c < self.navigable.shape[1])
        out = np.zeros(np.shape(r), dtype=bool)
        out[inside] = self.navigable[r[inside], c[inside]]
        return out


# ---------------------------------------------------------------------------------------------
# Building blocks: a scene is assembled from axis-aligned boxes and vertical cylinders.


@dataclass(frozen=True)
class Box:
    """Axis-aligned box from ``lo`` to ``hi`` (x, y, z metres) with a material index."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    material: int


@dataclass(frozen=True)
class Cylinder:
    """Vertical cylinder standing on the floor: centre (x, y), radius, height (m)."""

    x: float
    y: float
    radius: float
    height: float
    material: int


_BOX_FACES = np.array(  # corners indexed by bits (x, y, z); outward-facing triangles
    [
        [0, 2, 1],
        [1, 2, 3],
        [4, 5, 6],
        [5, 7, 6],
        [0, 1, 4],
        [1, 5, 4],
        [2, 6, 3],
        [3, 6, 7],
        [0, 4, 2],
        [2, 4, 6],
        [1, 3, 5],
        [3, 7, 5],
    ],
    dtype=np.int32,
)


def _box_mesh(b: Box) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = np.asarray(b.lo), np.asarray(b.hi)
    corners = np.array([[(hi if (i >> k) & 1 else lo)[k] for k in range(3)] for i in range(8)])
    return corners, _BOX_FACES


def _cylinder_mesh(c: Cylinder, segments: int = 16) -> tuple[np.ndarray, np.ndarray]:
    a = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    ring = np.stack([c.x + c.radius * np.cos(a), c.y + c.radius * np.sin(a)], axis=1)
    verts = np.concatenate(
        [
            np.column_stack([ring, np.zeros(segments)]),
            np.column_stack([ring, np.full(segments, c.height)]),
            [[c.x, c.y, c.height]],
        ]
    )
    i = np.arange(segments)
    j = (i + 1) % segments
    top = 2 * segments
    faces = np.concatenate(
        [
            np.stack([i, j, segments + i], 1),
            np.stack([j, segments + j, segments + i], 1),
            np.stack([segments + i, segments + j, np.full(segments, top)], 1),
        ]
    ).astype(np.int32)
    return verts, faces


# ---------------------------------------------------------------------------------------------
# Floor plan: recursive division of a rectangle into rooms, each cut wall keeping one doorway.


@dataclass(frozen=True)
class _Rect:
    x0: float
    y0: float
    x1: float
    y1: float


def _divide(rect: _Rect, rng: np.random.Generator, depth: int, walls: list, doors: list) -> list[_Rect]:
    w, h = rect.x1 - rect.x0, rect.y1 - rect.y0
    if depth == 0 or max(w, h) < 4.0 or min(w, h) < 2.2:
        return [rect]
    vertical = w >= h  # cut across the longer side
    length = w if vertical else h
    start = rect.x0 if vertical else rect.y0
    # Keep the new wall's ends away from doorways of the walls it meets.
    blocked = [dx if vertical else dy for dx, dy in doors]
    for _attempt in range(20):
        # Sometimes carve a corridor (a 1.1-1.5 m strip), else a room-sized split.
        if rng.random() < 0.3 and length > 5.0:
            cut = rng.uniform(1.1, 1.5) * (1 if rng.random() < 0.5 else -1)
            cut = cut if cut > 0 else length + cut
        else:
            cut = rng.uniform(0.35, 0.65) * length
        if all(abs(start + cut - b) > 0.9 for b in blocked):
            break
    else:
        return [rect]
    lo, hi = (rect.y0, rect.y1) if vertical else (rect.x0, rect.x1)
    door_w = rng.uniform(0.7, 0.95)
    door_c = rng.uniform(lo + 0.3 + door_w / 2, hi - 0.3 - door_w / 2)
    at = start + cut
    walls.append((vertical, at, lo, hi, door_c - door_w / 2, door_c + door_w / 2))
    doors.append((at, door_c) if vertical else (door_c, at))
    if vertical:
        parts = [_Rect(rect.x0, rect.y0, at, rect.y1), _Rect(at, rect.y0, rect.x1, rect.y1)]
    else:
        parts = [_Rect(rect.x0, rect.y0, rect.x1, at), _Rect(rect.x0, at, rect.x1, rect.y1)]
    return [r for p in parts for r in _divide(p, rng, depth - 1, walls, doors)]


def _wall_boxes(walls: list, rng: np.random.Generator) -> list[Box]:
    t = WALL_THICKNESS / 2
    boxes = []
    for vertical, at, lo, hi, d0, d1 in walls:
        material = int(rng.integers(WALL_MATERIALS[0], WALL_MATERIALS[1]))
        spans = [(lo, d0, 0.0, WALL_HEIGHT), (d1, hi, 0.0, WALL_HEIGHT), (d0, d1, DOOR_HEIGHT, WALL_HEIGHT)]
        for s0, s1, z0, z1 in spans:
            if vertical:
                boxes.append(Box((at - t, s0, z0), (at + t, s1, z1), material))
            else:
                boxes.append(Box((s0, at - t, z0), (s1, at + t, z1), material))
    return boxes


def _furnish(rooms: list[_Rect], doors: list, rng: np.random.Generator, n_materials: int) -> tuple[list, list]:
    boxes, cylinders = [], []
    m = 0.08  # keep furniture off the walls' faces
    for room in rooms:
        w, h = room.x1 - room.x0, room.y1 - room.y0
        corridor = min(w, h) < 2.0  # corridors get at most a couple of small round things
        for _ in range(rng.integers(0, 4) if corridor else rng.integers(4, 13)):
            mat = int(rng.integers(WALL_MATERIALS[1], n_materials))
            for _attempt in range(10):
                if not corridor and rng.random() < 0.7:
                    sx, sy = rng.uniform(0.4, min(1.6, w / 2)), rng.uniform(0.4, min(1.0, h / 2))
                    if rng.random() < 0.5:
                        sx, sy = sy, sx
                    x = rng.uniform(room.x0 + m, room.x1 - m - sx)
                    y = rng.uniform(room.y0 + m, room.y1 - m - sy)
                    cx, cy, r = x + sx / 2, y + sy / 2, np.hypot(sx, sy) / 2
                    cand = Box((x, y, 0.0), (x + sx, y + sy, float(rng.uniform(0.4, 2.0))), mat)
                else:
                    r = rng.uniform(0.1, 0.2) if corridor else rng.uniform(0.12, 0.4)
                    cx = rng.uniform(room.x0 + m + r, room.x1 - m - r)
                    cy = rng.uniform(room.y0 + m + r, room.y1 - m - r)
                    cand = Cylinder(cx, cy, r, float(rng.uniform(0.5, 1.5)), mat)
                if all(np.hypot(cx - dx, cy - dy) > r + 0.7 for dx, dy in doors):
                    (boxes if isinstance(cand, Box) else cylinders).append(cand)
                    break
    return boxes, cylinders


def _materials(rng: np.random.Generator, n_tiles: int, n: int = 14) -> tuple[Material, ...]:
    """0 floor, 1 ceiling, 2-4 walls (``WALL_MATERIALS``), 5.. furniture."""
    floor = Material(tuple(rng.uniform([0.6, 0.45, 0.3], [0.95, 0.8, 0.65])), int(rng.integers(n_tiles)))
    ceiling = Material((0.9, 0.9, 0.88), int(rng.integers(n_tiles)))
    walls = [Material(tuple(rng.uniform(0.7, 1.0, 3)), int(rng.integers(n_tiles))) for _ in range(3)]
    furniture = [Material(tuple(rng.uniform(0.3, 1.0, 3)), int(rng.integers(n_tiles))) for _ in range(n - 5)]
    return (floor, ceiling, *walls, *furniture)


def _occupancy(
    boxes: list[Box], cylinders: list[Cylinder], bounds: _Rect, res: float
) -> tuple[np.ndarray, tuple[float, float]]:
    pad = 0.5
    ox, oy = bounds.x0 - pad, bounds.y0 - pad
    cols = int(np.ceil((bounds.x1 - bounds.x0 + 2 * pad) / res))
    rows = int(np.ceil((bounds.y1 - bounds.y0 + 2 * pad) / res))
    xs = ox + (np.arange(cols) + 0.5) * res
    ys = oy + (np.arange(rows) + 0.5) * res
    inside = (
        (xs[None, :] > bounds.x0) & (xs[None, :] < bounds.x1) & (ys[:, None] > bounds.y0) & (ys[:, None] < bounds.y1)
    )
    free = inside.copy()
    # each solid clears only the cells of its own footprint (the same comparisons as on the whole grid)
    for b in boxes:
        if b.lo[2] > 1.0:  # door lintels are above the agent
            continue
        c0, c1 = np.searchsorted(xs, b.lo[0], "left"), np.searchsorted(xs, b.hi[0], "right")
        r0, r1 = np.searchsorted(ys, b.lo[1], "left"), np.searchsorted(ys, b.hi[1], "right")
        free[r0:r1, c0:c1] = False
    for c in cylinders:
        c0, c1 = np.searchsorted(xs, c.x - c.radius, "left"), np.searchsorted(xs, c.x + c.radius, "right")
        r0, r1 = np.searchsorted(ys, c.y - c.radius, "left"), np.searchsorted(ys, c.y + c.radius, "right")
        free[r0:r1, c0:c1] &= (xs[None, c0:c1] - c.x) ** 2 + (ys[r0:r1, None] - c.y) ** 2 > c.radius**2
    return free, (ox, oy)


def without_slivers(navigable: np.ndarray, width: float = 0.1) -> np.ndarray:
    """Remove navigable strips narrower than about ``width`` m (a morphological opening with a
    disk), as a navmesh's region filtering does: the agent's centre cannot follow a 5 cm sliver."""
    from scipy.ndimage import binary_opening

    r = int(round(width / 2 / GRID_RESOLUTION))
    yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
    return binary_opening(navigable, structure=(xx**2 + yy**2) <= r * r)


def scale_depth(scale: float) -> int:
    """Extra levels of room division for a floor plan ``scale`` times as long and as wide: the area
    grows by ``scale**2`` and each level doubles the rooms, so ``round(2 log2 scale)`` levels keep
    rooms about their default size (0 at scale 1)."""
    return int(round(2.0 * np.log2(scale)))


@dataclass(frozen=True)
class Plan:
    """A floor plan before it is made a mesh: the building's ``bounds``, its ``rooms``, the
    doorways' centres ``doors`` (x, y), ``materials``, the ``solids`` (outer and inner walls, door
    lintels, furniture: :class:`Box`) and ``cylinders``, and the floor and ceiling ``slabs``."""

    bounds: _Rect
    rooms: list[_Rect]
    doors: list[tuple[float, float]]
    materials: tuple[Material, ...]
    solids: list[Box]
    cylinders: list[Cylinder]
    slabs: list[Box]


def floor_plan(seed: int, n_tiles: int = 12, scale: float = 1.0, length: float | None = None) -> Plan:
    """The floor plan of ``seed`` (deterministic; :func:`generate_scene` says what it holds)."""
    if not 1.0 <= float(scale) <= 10.0:
        raise ValueError(f"generate_scene: scale: expected a number in [1, 10], got {scale!r}")
    if length is not None and not 20.0 <= float(length) <= 2000.0:
        raise ValueError(f"generate_scene: length: expected a number of metres in [20, 2000], got {length!r}")
    rng = np.random.default_rng(np.random.SeedSequence([0x5CE7E, int(seed)]))
    # the same draws at every scale: at 1 the sides are multiplied by exactly 1.0 and no level is added
    side_x, side_y = float(rng.uniform(7.0, 18.0)), float(rng.uniform(6.0, 14.0))
    bounds = _Rect(0.0, 0.0, side_x * scale if length is None else float(length), side_y * scale)
    walls, doors = [], []
    extra = scale_depth(scale) if length is None else max(0, int(round(np.log2(length * scale / side_x))))
    depth = int(rng.integers(2, 5)) + extra
    rooms = _divide(bounds, rng, depth=depth, walls=walls, doors=doors)
    materials = _materials(rng, n_tiles)
    t = WALL_THICKNESS
    outer = [
        Box((bounds.x0 - t, bounds.y0 - t, 0.0), (bounds.x1 + t, bounds.y0, WALL_HEIGHT), 2),
        Box((bounds.x0 - t, bounds.y1, 0.0), (bounds.x1 + t, bounds.y1 + t, WALL_HEIGHT), 2),
        Box((bounds.x0 - t, bounds.y0, 0.0), (bounds.x0, bounds.y1, WALL_HEIGHT), 2),
        Box((bounds.x1, bounds.y0, 0.0), (bounds.x1 + t, bounds.y1, WALL_HEIGHT), 2),
    ]
    furniture, cylinders = _furnish(rooms, doors, rng, len(materials))
    slabs = [  # floor and ceiling as thin boxes, so every surface is a closed solid
        Box((bounds.x0 - t, bounds.y0 - t, -0.05), (bounds.x1 + t, bounds.y1 + t, 0.0), 0),
        Box((bounds.x0 - t, bounds.y0 - t, WALL_HEIGHT), (bounds.x1 + t, bounds.y1 + t, WALL_HEIGHT + 0.05), 1),
    ]
    return Plan(bounds, rooms, doors, materials, outer + _wall_boxes(walls, rng) + furniture, cylinders, slabs)


def assembled(
    seed: int,
    parts: list[tuple[tuple[np.ndarray, np.ndarray], int]],
    plan: Plan,
    occupancy: tuple[np.ndarray, tuple[float, float]],
    agent_radius: float,
    scale: float,
    lights: np.ndarray | None = None,
) -> Scene:
    """The scene of ``seed``: one mesh of ``parts`` ((vertices, triangles), material), the plan's
    materials, the ``occupancy`` (free cells, origin) and what the agent's radius leaves of it."""
    verts, faces, mats, offset = [], [], [], 0
    for (v, f), mat in parts:
        verts.append(v)
        faces.append(f + offset)
        mats.append(np.full(len(f), mat, dtype=np.int32))
        offset += len(v)
    free, origin = occupancy
    return Scene(
        seed=int(seed),
        vertices=np.concatenate(verts).astype(np.float32),
        triangles=np.concatenate(faces).astype(np.int32),
        triangle_material=np.concatenate(mats),
        materials=plan.materials,
        free=free,
        navigable=navigable_of(free, agent_radius),
        origin=origin,
        resolution=GRID_RESOLUTION,
        agent_radius=agent_radius,
        scale=float(scale),
        lights=lights,
    )


def navigable_of(free: np.ndarray, agent_radius: float) -> np.ndarray:
    """Free cells whose centre is at least ``agent_radius`` (m) from any obstacle, slivers removed."""
    from scipy.ndimage import distance_transform_edt

    return without_slivers(distance_transform_edt(free) * GRID_RESOLUTION >= agent_radius)


def generate_scene(
    seed: int, agent_radius: float = 0.18, n_tiles: int = 12, scale: float = 1.0, length: float | None = None
) -> Scene:
    """Build the scene of ``seed`` (deterministic): a 7-18 m x 6-14 m floor plan of 2-16 rooms and
    corridors, walls with doorways, furniture. ``scale`` (1-10) multiplies both sides of the plan
    and divides it :func:`scale_depth` levels deeper (rooms keep their sizes, doorways join them
    all), for routes longer than an episode; at 1 the scene is the default one, bit for bit.
    ``length`` (m, 20-2000): a long building instead, ``length`` m along x and the plan's width
    (times ``scale``) along y, divided as many levels deeper as keep its rooms their sizes: a chain
    of rooms a route can cross from end to end."""
    plan = floor_plan(seed, n_tiles, scale, length)
    parts = [(_box_mesh(b), b.material) for b in plan.slabs + plan.solids]
    parts += [(_cylinder_mesh(c), c.material) for c in plan.cylinders]
    occupancy = _occupancy(plan.solids, plan.cylinders, plan.bounds, GRID_RESOLUTION)
    return assembled(seed, parts, plan, occupancy, agent_radius, scale)
