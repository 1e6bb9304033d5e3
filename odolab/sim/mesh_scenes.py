"""Scenes from mesh files a user brings (GLB/glTF, PLY, OBJ: the formats of Gibson, HM3D, Replica
and ScanNet scans), as :class:`~odolab.sim.scenes.Scene` values the simulator renders and the agent
moves in.

A file is read with trimesh, turned into the world frame (Z up, metres: ``up`` names the file's up
axis, ``unit`` its metres per unit), and its main floor found: the height holding the most
up-facing triangle area, moved to Z = 0. The occupancy grid is cast from the mesh, cell by cell:

- a cell is **floor** where a ray cast down from 0.3 m above the floor's height meets an up-facing
  surface within 0.1 m of it;
- a cell is **blocked** where a ray cast straight up from a height of the body (every 5 cm up to
  ``BODY_HEIGHT``) meets a surface below the body's top or meets a face from behind (the cell lies
  inside a solid there), where rays cast level in three of the four grid directions meet a face from
  behind first (inside a solid whose top or bottom touches another's), or where a surface passes between its centre and a neighbour's at a height of the body
  (rays between neighbouring centres every 10 cm up; the cell behind the surface is blocked), so
  single-sided scanned walls block too;
- ``free`` = floor and not blocked; ``navigable`` = free cells at least the agent's radius from
  every other cell, slivers removed, as for the procedural scenes.

Colour comes from the file (vertex colours, or a texture sampled at each hit's UV; a triangle with
neither is grey), with its lighting as scanned: no shading is added. Faces must face the open
space, as the faces of scans rendered with back-face culling do.
"""

from __future__ import annotations

import functools
import hashlib
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from odolab.config import setting
from odolab.sim.scenes import GRID_RESOLUTION, MIN_GOAL_DISTANCE, Material, Scene, without_slivers

#: Widest scene (m, along either horizontal axis): a home or an office floor; its occupancy grid
#: holds (MAX_SPAN / 0.05)^2 cells at most.
MAX_SPAN = 200.0
#: Files beside a .gltf or .obj that it may draw on (buffers, materials, textures): in its digest.
COMPANIONS = (".bin", ".mtl", ".png", ".jpg", ".jpeg")
#: Largest mesh file read (bytes): a scan of a home is tens to hundreds of megabytes.
MAX_FILE_BYTES = 2 * 1024**3
#: File types read (trimesh's readers).
SUFFIXES = (".glb", ".gltf", ".ply", ".obj")
#: Heights above the floor (m) up to which obstacles block the agent, as in the procedural scenes.
BODY_HEIGHT = 1.0
#: Grey of a triangle without colour.
GREY = 160
#: The grid's margin around the mesh (m).
PAD = 0.5


class MeshError(ValueError):
    """A mesh file that cannot be a scene; the message names the file."""


@dataclass(frozen=True)
class MeshAppearance:
    """What a mesh scene's faces look like: ``corner_colors`` (F, 3, 3) uint8 RGB at each corner
    (interpolated across the face), or, for a face with a texture, ``corner_uv`` (F, 3, 2) float32
    texture coordinates (u right, v up, in [0, 1]) into ``textures[texture_of[f]]`` (H, W, 3)
    uint8; ``texture_of[f]`` is -1 for a face coloured by its corners."""

    corner_colors: np.ndarray
    corner_uv: np.ndarray | None = None
    texture_of: np.ndarray | None = None
    textures: tuple[np.ndarray, ...] = field(default_factory=tuple)


@dataclass(frozen=True)
class MeshData:
    """A mesh in the world frame (Z up, metres), before its floor is found: ``vertices`` (V, 3)
    float32, ``triangles`` (F, 3) int32, ``appearance``, and ``digest`` (SHA-256 of the file's bytes
    and the reading settings: what episodes are cached by)."""

    vertices: np.ndarray
    triangles: np.ndarray
    appearance: MeshAppearance
    digest: str


def read_mesh(path: str | os.PathLike, up: Literal["y", "z"] = "y", unit: float = 1.0) -> MeshData:
    """Read a GLB/glTF, PLY or OBJ file: every geometry of it, placed by its transforms, turned so
    that ``up`` (the file's up axis: glTF's and Habitat's scenes are Y-up) becomes Z, and scaled by
    ``unit`` metres per file unit. :class:`MeshError` names the file for anything else."""
    import trimesh

    path = Path(path)
    digest = file_digest(path, up, unit)
    try:
        loaded = trimesh.load(str(path), file_type=path.suffix.lower()[1:], process=False)
    except Exception as exc:  # noqa: BLE001 (trimesh raises whatever its parsers raise)
        raise MeshError(
            f"{path}: not a readable {path.suffix.lower()[1:].upper()} mesh ({type(exc).__name__}: {exc})"
        ) from None
    meshes = loaded.dump() if isinstance(loaded, trimesh.Scene) else [loaded]
    meshes = [m for m in meshes if isinstance(m, trimesh.Trimesh) and len(m.faces)]
    if not meshes:
        raise MeshError(f"{path}: holds no triangles")
    vertices, triangles, colors, uvs, texture_of, textures, offset = [], [], [], [], [], [], 0
    for m in meshes:
        faces = np.asarray(m.faces, np.int64)
        vertices.append(np.asarray(m.vertices, np.float64))
        triangles.append(faces + offset)
        offset += len(m.vertices)
        corner_colors, corner_uv, texture = _look(m, faces)
        colors.append(corner_colors)
        uvs.append(corner_uv if corner_uv is not None else np.zeros((len(faces), 3, 2), np.float32))
        if texture is None:
            texture_of.append(np.full(len(faces), -1, np.int32))
        else:
            texture_of.append(np.full(len(faces), len(textures), np.int32))
            textures.append(texture)
    v = np.concatenate(vertices) * unit
    if up == "y":  # (x, y, z) Y-up -> (x, -z, y) Z-up: a right-handed turn about x, exact in floats
        v = np.stack([v[:, 0], -v[:, 2], v[:, 1]], axis=1)
    if not np.isfinite(v).all():
        raise MeshError(f"{path}: vertices hold NaN or infinity")
    span = v[:, :2].max(axis=0) - v[:, :2].min(axis=0)
    if span.max() > MAX_SPAN:
        raise MeshError(
            f"{path}: spans {span[0]:.3g} x {span[1]:.3g} m, above the {MAX_SPAN:g} m a scene may; a scan in "
            "millimetres or centimetres needs a unit of 0.001 or 0.01 (--scene-unit)"
        )
    appearance = MeshAppearance(
        corner_colors=np.concatenate(colors),
        corner_uv=np.concatenate(uvs) if textures else None,
        texture_of=np.concatenate(texture_of) if textures else None,
        textures=tuple(textures),
    )
    return MeshData(v.astype(np.float32), np.concatenate(triangles).astype(np.int32), appearance, digest)


def file_digest(path: str | os.PathLike, up: Literal["y", "z"] = "y", unit: float = 1.0) -> str:
    """SHA-256 of a mesh file's bytes, the files beside it that it may draw on and the reading
    settings (what episodes are cached by), without parsing it; :class:`MeshError` names the file
    for a setting, a type, a path or a size that :func:`read_mesh` refuses."""
    path = Path(path)
    if up not in ("y", "z"):
        raise MeshError(f"{path}: up: expected 'y' or 'z', got {up!r}")
    if not (np.isfinite(unit) and 1e-6 <= unit <= 1e6):
        raise MeshError(f"{path}: unit: expected metres per file unit in [1e-06, 1e+06], got {unit!r}")
    if not path.exists():
        raise MeshError(f"{path}: no such file or folder")
    if path.suffix.lower() not in SUFFIXES:
        raise MeshError(
            f"{path}: unknown mesh type {path.suffix or '(no extension)'!r}; expected {', '.join(SUFFIXES)}"
        )
    if not path.is_file():
        raise MeshError(f"{path}: not a regular file")
    size = path.stat().st_size
    if size > MAX_FILE_BYTES:
        raise MeshError(f"{path}: {size / 1024**3:.1f} GB, above the {MAX_FILE_BYTES / 1024**3:.0f} GB a scene may be")
    blob = path.read_bytes() + _companions(path) + f"|up={up}|unit={float(unit)!r}".encode()
    return hashlib.sha256(blob).hexdigest()


def _companions(path: Path) -> bytes:
    """The bytes of the files beside a .gltf or .obj that it may draw on (:data:`COMPANIONS`), named
    and in name order, so that a changed buffer, material or texture changes the digest."""
    if path.suffix.lower() not in (".gltf", ".obj"):
        return b""
    parts = []
    for f in sorted(path.parent.iterdir()):
        if f.suffix.lower() in COMPANIONS and f.is_file():
            parts += [f.name.encode(), hashlib.sha256(f.read_bytes()).digest()]
    return b"".join(parts)


def _look(mesh, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """A trimesh mesh's corner colours (F, 3, 3) uint8, and its corner UVs and texture image where it
    has a texture."""
    visual = mesh.visual
    grey = np.full((len(faces), 3, 3), GREY, np.uint8)
    if visual.kind == "texture":
        material = visual.material  # glTF's PBR material or OBJ's simple one
        image = getattr(material, "baseColorTexture", None)
        image = getattr(material, "image", None) if image is None else image
        uv = getattr(visual, "uv", None)
        if image is not None and uv is not None and len(uv) == len(mesh.vertices):
            texture = np.asarray(image.convert("RGB"), np.uint8)
            return grey, np.asarray(uv, np.float32)[faces], texture
        color = getattr(material, "baseColorFactor", None)
        color = getattr(material, "diffuse", None) if color is None else color
        if color is not None:
            return np.broadcast_to(np.asarray(color, np.uint8)[:3], grey.shape).copy(), None, None
        return grey, None, None
    if visual.kind == "vertex":
        return np.asarray(visual.vertex_colors, np.uint8)[:, :3][faces], None, None
    if visual.kind == "face":
        return np.repeat(np.asarray(visual.face_colors, np.uint8)[:, None, :3], 3, axis=1), None, None
    return grey, None, None


def floor_height(vertices: np.ndarray, triangles: np.ndarray, bin_m: float = 0.02) -> float:
    """The main floor's height (m): the area-weighted height of the lowest ``bin_m`` height bin
    holding at least half as much up-facing triangle area (normal within 25 degrees of +Z) as the
    bin holding most (a building's ground floor rather than a roof or an upper storey)."""
    v = vertices[triangles].astype(np.float64)
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    area = 0.5 * np.linalg.norm(n, axis=1)
    up = n[:, 2] > 0.9 * 2.0 * np.maximum(area, 1e-30)
    if not up.any():
        raise MeshError("no up-facing surface: no floor to stand on")
    z = v[up, :, 2].mean(axis=1)
    bins = np.floor(z / bin_m).astype(np.int64)
    _, index = np.unique(bins, return_inverse=True)
    weight = np.bincount(index, weights=area[up])
    main = index == np.flatnonzero(weight >= 0.5 * weight.max())[0]  # the lowest of the large ones
    return float(np.average(z[main], weights=area[up][main]))


def mesh_scene(data: MeshData, agent_radius: float = 0.18, name: str = "mesh") -> Scene:
    """The scene of a mesh (:func:`read_mesh`): its main floor moved to Z = 0, its occupancy cast
    from the mesh (the module's rules), its look kept. :class:`MeshError` (naming ``name``) for a
    mesh with no floor or no free space."""
    from scipy.ndimage import distance_transform_edt

    try:
        floor = floor_height(data.vertices, data.triangles)
    except MeshError as exc:
        raise MeshError(f"{name}: {exc}") from None
    vertices = (data.vertices - np.array([0.0, 0.0, floor], np.float32)).astype(np.float32)
    side, height = float((vertices[:, :2].max(axis=0) - vertices[:, :2].min(axis=0)).max()), float(vertices[:, 2].max())
    if height > side:  # a wall read as the floor: the file's up axis is another
        raise MeshError(
            f"{name}: {height:.3g} m tall above its floor and {side:.3g} m across at most: is its up axis the one "
            "given (--scene-up)?"
        )
    free, origin = occupancy(vertices, data.triangles)
    if not free.any():
        raise MeshError(f"{name}: no free floor: no cell with a floor and room above it for the agent")
    navigable = without_slivers(distance_transform_edt(free) * GRID_RESOLUTION >= agent_radius)
    if not navigable.any():
        raise MeshError(f"{name}: no navigable floor for an agent of radius {agent_radius:g} m")
    scene = Scene(
        seed=int(data.digest[:8], 16),
        vertices=vertices,
        triangles=data.triangles,
        triangle_material=np.zeros(len(data.triangles), np.int32),
        materials=(Material((1.0, 1.0, 1.0), 0),),
        free=free,
        navigable=navigable,
        origin=origin,
        resolution=GRID_RESOLUTION,
        agent_radius=agent_radius,
        appearance=data.appearance,
    )
    span = floor_span(scene)
    if span < MIN_GOAL_DISTANCE:  # geodesic >= straight: no episode's start and goal fit
        raise MeshError(
            f"{name}: its largest navigable floor is {span:.2g} m across; an episode's start and goal are at "
            f"least {MIN_GOAL_DISTANCE:g} m apart"
        )
    return scene


def floor_span(scene: Scene) -> float:
    """The largest straight distance (m) between two cell centres of the scene's largest navigable
    region (the one episodes start and end in): no episode's geodesic start-goal distance exceeds it
    by being shorter."""
    from scipy.spatial import ConvexHull, QhullError
    from scipy.spatial.distance import pdist

    from odolab.sim.planner import largest_component

    points = np.argwhere(largest_component(scene)) * scene.resolution
    try:
        points = points[ConvexHull(points).vertices]
    except (QhullError, ValueError):  # a line of cells, or fewer than three: its ends are among the extremes
        points = points[[points[:, 0].argmin(), points[:, 0].argmax(), points[:, 1].argmin(), points[:, 1].argmax()]]
    return float(pdist(points).max()) if len(points) > 1 else 0.0


def occupancy(
    vertices: np.ndarray, triangles: np.ndarray, res: float = GRID_RESOLUTION
) -> tuple[np.ndarray, tuple[float, float]]:
    """``free`` (rows, cols) and the grid's ``origin`` (x, y) of a mesh whose floor is at Z = 0 (the
    module's rules); the origin is a multiple of ``res``, so grids of one world line up."""
    import open3d as o3d

    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(triangles.astype(np.uint32)))
    lo, hi = vertices[:, :2].min(axis=0).astype(np.float64) - PAD, vertices[:, :2].max(axis=0).astype(np.float64) + PAD
    ox, oy = np.floor(lo / res) * res
    cols, rows = (np.ceil((hi - (ox, oy)) / res)).astype(int)
    xs = ox + (np.arange(cols) + 0.5) * res
    ys = oy + (np.arange(rows) + 0.5) * res
    cx, cy = (a.astype(np.float32).ravel() for a in np.meshgrid(xs, ys))

    def cast(origins: np.ndarray, direction: tuple[float, float, float]) -> dict:
        rays = np.concatenate([origins, np.broadcast_to(np.float32(direction), origins.shape)], axis=1)
        hit = rc.cast_rays(o3d.core.Tensor(np.ascontiguousarray(rays, np.float32)))
        return {"t": hit["t_hit"].numpy(), "n": hit["primitive_normals"].numpy()}

    def at(z: float) -> np.ndarray:
        return np.stack([cx, cy, np.full_like(cx, z)], axis=1)

    down = cast(at(0.3), (0.0, 0.0, -1.0))
    floor = (np.abs(down["t"] - 0.3) <= 0.1) & (down["n"][:, 2] > 0.5)
    blocked = np.zeros(len(cx), bool)
    for h in np.arange(1, round(BODY_HEIGHT / 0.05) + 1) * 0.05:  # a surface over the floor, or a solid's inside
        upward = cast(at(h), (0.0, 0.0, 1.0))
        blocked |= np.isfinite(upward["t"]) & ((upward["t"] <= BODY_HEIGHT - h) | (upward["n"][:, 2] > 0.0))
    grid = np.arange(rows * cols).reshape(rows, cols)
    sides = (  # direction, the cells with a neighbour that way, those neighbours
        ((1.0, 0.0, 0.0), grid[:, :-1], grid[:, 1:]),
        ((-1.0, 0.0, 0.0), grid[:, 1:], grid[:, :-1]),
        ((0.0, 1.0, 0.0), grid[:-1, :], grid[1:, :]),
        ((0.0, -1.0, 0.0), grid[1:, :], grid[:-1, :]),
    )
    for h in np.arange(1, round(BODY_HEIGHT / 0.1) + 1) * 0.1:
        behind = np.zeros(len(cx), np.int8)  # directions in which the first face is met from behind
        for d, a, b in sides:
            hit = cast(at(h), d)
            back = np.isfinite(hit["t"]) & ((hit["n"] @ np.float32(d)) > 0)
            behind += back
            a, b = a.ravel(), b.ravel()
            crossing = hit["t"][a] < res  # a surface between a's centre and b's: the cell behind it is blocked
            blocked[b[crossing & ~back[a]]] = True
            blocked[a[crossing & back[a]]] = True
        blocked |= behind >= 3  # inside a solid, whichever of its faces touch another's
    return (floor & ~blocked).reshape(rows, cols), (float(ox), float(oy))


def export_scene(scene: Scene, path: str | os.PathLike, up: Literal["y", "z"] = "y") -> Path:
    """Write a procedural scene as a mesh file (``.glb``: its colours in a texture; ``.ply``: as
    vertex colours; ``.obj``: geometry only) with ``up`` its up axis, every triangle with corners of
    its own and its colour under the renderer's lights (:func:`odolab.sim.camera.shaded_colours`,
    the texture tiles left out): what a mesh viewer or :func:`read_mesh` shows of it."""
    import trimesh
    from PIL import Image

    from odolab.sim.camera import shaded_colours

    path = Path(path)
    kind = path.suffix.lower()
    if up not in ("y", "z"):
        raise MeshError(f"{path}: up: expected 'y' or 'z', got {up!r}")
    if kind not in (".glb", ".ply", ".obj"):
        raise MeshError(f"{path}: cannot write {kind or '(no extension)'!r}; expected .glb, .ply or .obj")
    v = scene.vertices[scene.triangles].reshape(-1, 3).astype(np.float64)
    if up == "y":  # Z-up (x, y, z) -> Y-up (x, z, -y), the inverse of read_mesh's turn
        v = np.stack([v[:, 0], v[:, 2], -v[:, 1]], axis=1)
    faces = np.arange(len(v)).reshape(-1, 3)
    rgb = shaded_colours(scene)
    if kind == ".ply":
        mesh = trimesh.Trimesh(v, faces, vertex_colors=np.repeat(rgb, 3, axis=0), process=False)
    elif kind == ".glb":  # one texel per colour, each corner's UV at its colour's texel centre
        palette, index = np.unique(rgb, axis=0, return_inverse=True)
        image = Image.fromarray(palette[None, :, :].astype(np.uint8))
        uv = np.stack([(index.ravel() + 0.5) / len(palette), np.full(len(index), 0.5)], axis=1)
        visual = trimesh.visual.TextureVisuals(uv=np.repeat(uv, 3, axis=0), image=image)
        mesh = trimesh.Trimesh(v, faces, visual=visual, process=False)
    else:
        mesh = trimesh.Trimesh(v, faces, process=False)
    data = mesh.export(file_type=kind[1:])
    path.write_bytes(data.encode() if isinstance(data, str) else data)
    return path


#: Which split a file of a folder of scenes belongs to: the first 8 hex digits of its digest,
#: modulo 10: 0-7 train, 8 val, 9 test (about 80/10/10, the same on every machine).
SPLIT_OF_REMAINDER = {**dict.fromkeys(range(8), "train"), 8: "val", 9: "test"}


@dataclass(frozen=True)
class SceneFiles:
    """Mesh files as the scenes of a split: ``files`` (absolute paths), their ``digests``
    (:func:`read_mesh`, which episodes are cached by), read with ``up`` and ``unit``. Episode after
    episode draws one of them, as the procedural split draws a seed."""

    files: tuple[str, ...]
    digests: tuple[str, ...]
    up: Literal["y", "z"] = "y"
    unit: float = setting(1.0, range=(1e-6, 1e6), doc="metres per file unit")

    def scene(self, draw: int) -> Scene:
        """The scene of file ``draw`` modulo their number (read once per process)."""
        if not self.files:
            raise MeshError("these mesh scenes are known by their digests only (read from a record): no file to render")
        k = int(draw) % len(self.files)
        return _mesh_scene_of(self.files[k], self.digests[k], self.up, float(self.unit))

    def file(self, draw: int) -> str:
        """The file of the scene :meth:`scene` gives for ``draw``."""
        return self.files[int(draw) % len(self.files)]

    def identity(self) -> dict:
        """What episodes depend on: the files' digests and the reading settings, not their paths."""
        return {"digests": list(self.digests), "up": self.up, "unit": float(self.unit)}

    @classmethod
    def recorded(cls, identity: object, source: str) -> SceneFiles:
        """The scenes an :meth:`identity` record (read from ``source``) describes, without files:
        enough for the episodes' keys, not to render them. :class:`MeshError` names the bad field."""
        if not isinstance(identity, dict) or set(identity) != {"digests", "up", "unit"}:
            raise MeshError(f"{source}: field scenes: expected digests, up and unit, got {identity!r:.80}")
        digests, up, unit = identity["digests"], identity["up"], identity["unit"]
        if (
            not isinstance(digests, list)
            or not digests
            or not all(isinstance(d, str) and re.fullmatch(r"[0-9a-f]{64}", d) for d in digests)
        ):
            raise MeshError(f"{source}: field scenes.digests: expected SHA-256 hex digests, got {digests!r:.80}")
        if up not in ("y", "z"):
            raise MeshError(f"{source}: field scenes.up: expected 'y' or 'z', got {up!r:.40}")
        if isinstance(unit, bool) or not isinstance(unit, (int, float)) or not 1e-6 <= unit <= 1e6:
            raise MeshError(
                f"{source}: field scenes.unit: expected metres per unit in [1e-06, 1e+06], got {unit!r:.40}"
            )
        return cls((), tuple(digests), up, float(unit))


def scene_files(path: str | os.PathLike, split: str, up: Literal["y", "z"] = "y", unit: float = 1.0) -> SceneFiles:
    """The scenes of ``split`` from ``path``: a mesh file is every split's one scene; a folder's
    mesh files (of :data:`SUFFIXES`, not in subfolders) are split by :data:`SPLIT_OF_REMAINDER`.
    Every file is read and made a scene here, so a bad one is one :class:`MeshError` line before any
    episode."""
    path = Path(path).absolute()  # as typed: a link is named as the link
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in SUFFIXES and p.is_file())
        if not files:
            raise MeshError(f"{path}: no mesh file ({', '.join(SUFFIXES)}) in this folder")
    else:
        files = [path]
    chosen = []
    for f in files:  # each file parsed once: made a scene when in the split, else read to check it
        digest = file_digest(f, up, unit)
        if len(files) == 1 or SPLIT_OF_REMAINDER[int(digest[:8], 16) % 10] == split:
            _mesh_scene_of(str(f), digest, up, float(unit))  # a bad scene stops here
            chosen.append((str(f), digest))
        else:
            read_mesh(f, up, unit)
    if not chosen:
        raise MeshError(
            f"{path}: none of its {len(files)} mesh files falls in the {split} split (a file's split: the first 8 hex "
            "digits of its digest modulo 10, 0-7 train, 8 val, 9 test); give one file to use it for every split"
        )
    chosen.sort(key=lambda fd: fd[1])
    return SceneFiles(tuple(f for f, _ in chosen), tuple(d for _, d in chosen), up, float(unit))


@functools.lru_cache(maxsize=4)
def _mesh_scene_of(path: str, digest: str, up: str, unit: float) -> Scene:
    """The scene of a mesh file, made once per process (the last few kept); :class:`MeshError` when
    the file changed since its digest was taken."""
    data = read_mesh(path, up, unit)
    if data.digest != digest:
        raise MeshError(f"{path}: changed since the episodes were specified (another digest); run again")
    return mesh_scene(data, name=path)
