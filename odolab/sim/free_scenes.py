"""Procedural scenes that are not Manhattan: the ``free`` family beside the ``boxes`` one.

A ``free`` scene starts from the floor plan of the same seed in the ``boxes`` family
(:func:`odolab.sim.scenes.floor_plan`), then

* turns each piece of furniture to a random yaw about its centre (where it still fits its room),
* maps the whole plan by a plane homography: straight walls stay straight and meet where they
  met, but at other angles (about 70-110 degrees), rooms become quadrilaterals of other
  orientations and sizes (the local scale varies by up to about 1.4x across a plan), and the
  building is turned to any heading in the world,
* lights every room with a point light under its ceiling: brightness falls off across a room and
  a specular term makes a surface's grey level change with the viewpoint
  (:class:`odolab.sim.camera.Renderer`).

Heights, materials, textures and doorways are the plan's. The occupancy map is the footprints of
the solids below 1 m (as the ``boxes`` family's), rasterised as polygons at the same 5 cm.
"""

from __future__ import annotations

import numpy as np

from odolab.sim.scenes import (
    _BOX_FACES,
    GRID_RESOLUTION,
    WALL_HEIGHT,
    WALL_MATERIALS,
    Box,
    Cylinder,
    Plan,
    Scene,
    _cylinder_mesh,
    _Rect,
    assembled,
    floor_plan,
    generate_scene,
)

__all__ = ["FAMILIES", "family_scene", "free_scene"]

#: The procedural scene families: ``boxes`` (axis-aligned rooms, exactly Manhattan) and ``free``.
FAMILIES = ("boxes", "free")
#: Light under each room's ceiling: metres below it.
LIGHT_DROP = 0.2


def family_scene(
    seed: int, family: str = "boxes", agent_radius: float = 0.18, scale: float = 1.0, length: float | None = None
) -> Scene:
    """The procedural scene of ``seed`` in ``family`` (one of :data:`FAMILIES`)."""
    if family == "boxes":
        return generate_scene(seed, agent_radius, scale=scale, length=length)
    if family == "free":
        return free_scene(seed, agent_radius, scale=scale, length=length)
    raise ValueError(f"scene family: expected one of {', '.join(FAMILIES)}, got {family!r}")


def free_scene(
    seed: int, agent_radius: float = 0.18, n_tiles: int = 12, scale: float = 1.0, length: float | None = None
) -> Scene:
    """The ``free`` scene of ``seed`` (deterministic; the module docstring says what it is)."""
    plan = floor_plan(seed, n_tiles, scale, length)
    rng = np.random.default_rng(np.random.SeedSequence([0xF4EE, int(seed)]))
    prisms = [_turned(b, plan, rng) if b.material >= WALL_MATERIALS[1] else _footprint(b) for b in plan.solids]
    warp = _homography(plan.bounds, rng)
    prisms = [(warp(fp), z0, z1, m) for fp, z0, z1, m in prisms]
    slabs = [(warp(fp), z0, z1, m) for fp, z0, z1, m in map(_footprint, plan.slabs)]
    cylinders = [_moved(c, warp) for c in plan.cylinders]
    parts = [(_prism_mesh(fp, z0, z1), m) for fp, z0, z1, m in slabs + prisms]
    parts += [(_cylinder_mesh(c), c.material) for c in cylinders]
    b = plan.bounds
    outline = warp(np.array([[b.x0, b.y0], [b.x1, b.y0], [b.x0, b.y1], [b.x1, b.y1]]))
    occupancy = _occupancy(prisms, cylinders, outline, GRID_RESOLUTION)
    centres = warp(np.array([[(r.x0 + r.x1) / 2, (r.y0 + r.y1) / 2] for r in plan.rooms]))
    power = rng.uniform(0.7, 1.3, len(centres))
    lights = np.column_stack([centres, np.full(len(centres), WALL_HEIGHT - LIGHT_DROP), power]).astype(np.float32)
    return assembled(seed, parts, plan, occupancy, agent_radius, scale, lights)


Prism = tuple[np.ndarray, float, float, int]  # footprint (4, 2) corners in box-bit order, z0, z1, material


def _footprint(b: Box) -> Prism:
    """A box as a prism: its footprint's corners in the order of its corner bits (x, then y)."""
    (x0, y0, z0), (x1, y1, z1) = b.lo, b.hi
    return np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]], np.float64), float(z0), float(z1), b.material


def _turned(b: Box, plan: Plan, rng: np.random.Generator, margin: float = 0.08) -> Prism:
    """A piece of furniture turned about its centre by a random yaw that keeps it inside its room
    (``margin`` m off the walls; the first of four draws that fits, else as it was). Its distance
    to the doorways is unchanged: the plan kept its circumscribed circle off them."""
    corners, z0, z1, m = _footprint(b)
    centre = corners.mean(axis=0)
    room = next((r for r in plan.rooms if r.x0 <= centre[0] <= r.x1 and r.y0 <= centre[1] <= r.y1), None)
    for yaw in rng.uniform(-np.pi, np.pi, 4):
        c, s = np.cos(yaw), np.sin(yaw)
        turned = (corners - centre) @ np.array([[c, s], [-s, c]]) + centre
        if room is not None and _inside(turned, room, margin):
            return turned, z0, z1, m
    return corners, z0, z1, m


def _inside(points: np.ndarray, room: _Rect, margin: float) -> bool:
    x, y = points[:, 0], points[:, 1]
    return bool(
        np.all(x >= room.x0 + margin)
        and np.all(x <= room.x1 - margin)
        and np.all(y >= room.y0 + margin)
        and np.all(y <= room.y1 - margin)
    )


def _homography(bounds: _Rect, rng: np.random.Generator):
    """A plane homography about the plan's centre: shear (+-0.3), stretch (0.85-1.18 against its
    inverse across), perspective terms (+-0.15 over half the plan's longer side) and a heading
    (any); it preserves orientation. Returns the map of (N, 2) points (m)."""
    cx, cy = (bounds.x0 + bounds.x1) / 2, (bounds.y0 + bounds.y1) / 2
    half = max(bounds.x1 - bounds.x0, bounds.y1 - bounds.y0) / 2
    shear, stretch = rng.uniform(-0.3, 0.3), rng.uniform(0.85, 1.18)
    g, h = rng.uniform(-0.15, 0.15, 2)
    heading = rng.uniform(-np.pi, np.pi)
    c, s = np.cos(heading), np.sin(heading)
    A = np.array([[c, -s], [s, c]]) @ np.array([[1.0, shear], [0.0, 1.0]]) @ np.diag([stretch, 1.0 / stretch])

    def warp(points: np.ndarray) -> np.ndarray:
        u = (np.asarray(points, np.float64) - (cx, cy)) / half
        w = 1.0 + g * u[:, 0] + h * u[:, 1]
        return (u @ A.T) / w[:, None] * half + (cx, cy)

    return warp


def _moved(c: Cylinder, warp) -> Cylinder:
    """A cylinder at its centre's image (its radius kept)."""
    ((x, y),) = warp(np.array([[c.x, c.y]]))
    return Cylinder(float(x), float(y), c.radius, c.height, c.material)


def _prism_mesh(footprint: np.ndarray, z0: float, z1: float) -> tuple[np.ndarray, np.ndarray]:
    """A prism's eight corners (indexed by bits x, y, z as a box's) and outward triangles."""
    corners = np.array([[*footprint[i & 3], z1 if i & 4 else z0] for i in range(8)])
    return corners, _BOX_FACES


def _occupancy(
    prisms: list[Prism], cylinders: list[Cylinder], outline: np.ndarray, res: float
) -> tuple[np.ndarray, tuple[float, float]]:
    """Free cells: centres inside the building's ``outline`` (a footprint) and outside every solid
    below 1 m (door lintels are above the agent); the grid covers the outline and 0.5 m around."""
    from matplotlib.path import Path as Polygon

    loop = [0, 1, 3, 2]  # box-bit order around the footprint
    lo, hi = outline.min(axis=0) - 0.5, outline.max(axis=0) + 0.5
    cols, rows = (int(np.ceil(v)) for v in (hi - lo) / res)
    xs, ys = lo[0] + (np.arange(cols) + 0.5) * res, lo[1] + (np.arange(rows) + 0.5) * res
    grid = np.stack(np.meshgrid(xs, ys), axis=-1)  # (rows, cols, 2) cell centres
    free = Polygon(outline[loop]).contains_points(grid.reshape(-1, 2)).reshape(rows, cols)
    for fp, z0, _, _ in prisms:
        if z0 > 1.0:
            continue
        (c0, r0), (c1, r1) = (
            (np.floor((fp.min(axis=0) - lo) / res) - 1).astype(int),
            (np.ceil((fp.max(axis=0) - lo) / res) + 1).astype(int),
        )
        r0, c0, r1, c1 = max(r0, 0), max(c0, 0), min(r1, rows), min(c1, cols)
        window = grid[r0:r1, c0:c1]
        inside = Polygon(fp[loop]).contains_points(window.reshape(-1, 2)).reshape(window.shape[:2])
        free[r0:r1, c0:c1] &= ~inside
    for c in cylinders:
        free &= (grid[..., 0] - c.x) ** 2 + (grid[..., 1] - c.y) ** 2 > c.radius**2
    return free, (float(lo[0]), float(lo[1]))
