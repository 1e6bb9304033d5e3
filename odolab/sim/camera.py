"""Clean RGB-D rendering of a :class:`~odolab.sim.scenes.Scene` by Open3D ray casting.

The camera is a level pinhole (LoCoBot-like, Habitat PointNav Challenge 2020): 341 x 192 pixels,
70 degree horizontal field of view, 0.88 m above the floor, depth range 0.1-10 m. Ray directions
are computed once in the camera frame with z = 1, so the ray parameter of a hit *is* the z-depth;
per pose they are only rotated. Each ray passes through a pixel centre, at integer image coordinates
with cx = (W - 1) / 2 (the convention of :class:`~odolab.core.types.Intrinsics`, used everywhere).
Noise is added separately (:mod:`odolab.sim.noise`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from odolab.core.types import Intrinsics
from odolab.sim.scenes import Scene
from odolab.sim.textures import TEXEL_SIZE, make_tiles, mip_stack

_KEY_LIGHT = np.array([0.45, 0.3, 0.84]) / np.linalg.norm([0.45, 0.3, 0.84])  # world direction to the light
AMBIENT, KEY, FILL = 0.4, 0.7, 0.25  # shading = AMBIENT + KEY max(n.l, 0) + FILL max(-n.l, 0)
TEX_FLOOR, TEX_GAIN = 0.25, 1.25  # brightness factor of a texel with reflectance r: TEX_FLOOR + TEX_GAIN r
MIP_LEVELS = 7  # 512 -> 8 texels
_TEXEL_OFFSET = 1 << 16  # texels
_T_STEPS = 16  # mip lookup bins per metre of hit distance


@dataclass(frozen=True)
class Hits:
    """One ray cast: ``t`` (H * W,) float32 hit distance along the z = 1 ray, i.e. z-depth (inf for a
    miss); ``tri`` (H * W,) int32 triangle ids (-1 for a miss); the rays: ``origin`` (3,) float32 and
    ``dirs`` (3, H * W) float32 (world, z-depth 1); ``keep``: the Open3D result whose memory ``t`` and
    ``tri`` share."""

    t: np.ndarray
    tri: np.ndarray
    origin: np.ndarray
    dirs: np.ndarray
    keep: object = None


@dataclass(frozen=True)
class CameraSpec:
    """Sensor geometry: image size (pixels), horizontal FOV (deg), mount height and depth range (m)."""

    width: int = 341
    height: int = 192
    hfov_deg: float = 70.0
    mount_height: float = 0.88
    min_depth: float = 0.1
    max_depth: float = 10.0

    @property
    def intrinsics(self) -> Intrinsics:
        """Pinhole intrinsics (fx = fy = 243.5 px at the default 341 x 192, 70 deg)."""
        return Intrinsics.from_hfov(self.width, self.height, self.hfov_deg)


def _aligned_empty(shape: tuple[int, ...], align: int = 64) -> np.ndarray:
    """An uninitialised float32 array whose data starts on an ``align``-byte boundary."""
    n = int(np.prod(shape)) * 4
    buf = np.empty(n + align, np.uint8)
    offset = (-buf.ctypes.data) % align
    return buf[offset : offset + n].view(np.float32).reshape(shape)


def _normals(scene: Scene) -> np.ndarray:
    """(F, 3) unit normals of the scene's triangles (float64)."""
    v = scene.vertices[scene.triangles].astype(np.float64)
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    return n / (np.linalg.norm(n, axis=1, keepdims=True) + 1e-12)


def shaded_colours(scene: Scene) -> np.ndarray:
    """(F, 3) uint8: each triangle's material colour under the renderer's lights (ambient, key and
    fill), before its texture: what a flat texture (reflectance 0.6, brightness factor 1) shows."""
    lit = _normals(scene) @ _KEY_LIGHT
    shade = AMBIENT + KEY * np.maximum(lit, 0.0) + FILL * np.maximum(-lit, 0.0)
    colors = np.array([m.color for m in scene.materials], dtype=np.float32)
    return np.clip(np.round(colors[scene.triangle_material] * shade[:, None] * 255.0), 0, 255).astype(np.uint8)


class Renderer:
    """Ray-casts one scene; :meth:`render` returns clean (noise-free) RGB and z-depth.

    Colour = material albedo x texture x shading. Textures are sampled from a mip pyramid at the
    level matching each pixel's footprint: from the hit distance, plus, on floor and ceiling, the
    foreshortening a level camera sees there (so distant and grazing surfaces blur a little rather
    than alias). Shading is Lambertian under a directional key
    light and a weaker fill light from the opposite side, on top of ambient light, so walls facing
    different ways differ in brightness.
    """

    def __init__(
        self, scene: Scene, camera: CameraSpec = CameraSpec(), tiles: np.ndarray | None = None, nthreads: int = 0
    ) -> None:
        import open3d as o3d

        self.camera = camera
        tiles = make_tiles() if tiles is None else tiles
        size = tiles.shape[-1]
        if size & (size - 1):
            raise ValueError("texture tiles must have a power-of-two size")
        self._log_size = size.bit_length() - 1
        self._tile_mask = size - 1
        # every mip level at full size (nearest-upsampled), as brightness codes: factor x 128
        self._tex = mip_stack(tiles, min(MIP_LEVELS, self._log_size + 1), TEX_FLOOR, TEX_GAIN)
        self._levels = self._tex.shape[0]
        self._level_stride = int(self._tex[0].size)
        self._rc = o3d.t.geometry.RaycastingScene(nthreads=nthreads)
        self._rc.add_triangles(o3d.core.Tensor(scene.vertices), o3d.core.Tensor(scene.triangles.astype(np.uint32)))

        normals = _normals(scene)
        axis = np.argmax(np.abs(normals), axis=1)
        self._tri_axis = np.append(axis, 2).astype(np.int8)  # dominant normal axis: the texture plane
        rgb = shaded_colours(scene)
        # (3, F + 1) 8-bit colour x shading, and each triangle's tile; the last entry is for misses
        self._tri_rgb_t = np.ascontiguousarray(np.append(rgb, np.zeros((1, 3)), axis=0).T, dtype=np.uint16)
        tile = np.array([m.tile for m in scene.materials])[scene.triangle_material] % len(tiles)
        self._tri_tile_offset = np.append(tile * size * size, 0).astype(np.int32)

        K = camera.intrinsics
        u, v_ = np.meshgrid(np.arange(camera.width), np.arange(camera.height))  # pixel centres (Intrinsics)
        self._dirs_cam = (
            np.stack([(u - K.cx) / K.fx, (v_ - K.cy) / K.fy, np.ones_like(u)], axis=-1)
            .reshape(-1, 3)
            .astype(np.float32)
        )
        self._dirs_cam_t = np.ascontiguousarray(self._dirs_cam.T)
        # Mip level = log2 of a pixel's footprint in texels, t |d| / (fx TEXEL_SIZE) / sqrt(cos), cos the
        # incidence: from the hit distance by a lookup (centre |d| = 1), plus for floor and ceiling the
        # per-pixel foreshortening of a level camera, cos = |d_y| / |d|.
        t_bins = (np.arange(int(camera.max_depth * _T_STEPS) + 2) + 0.5) / _T_STEPS
        by_t = np.floor(np.log2(np.maximum(t_bins / (K.fx * TEXEL_SIZE), 1.0)))
        self._level_by_t = (np.clip(by_t, 0, self._levels - 1) * self._level_stride).astype(np.int32)
        norm = np.linalg.norm(self._dirs_cam, axis=1)
        tilt = np.round(0.5 * np.log2(norm / np.maximum(np.abs(self._dirs_cam[:, 1]), 1e-3)) + np.log2(norm))
        self._floor_bias = (np.clip(tilt, 0, self._levels - 1) * self._level_stride).astype(np.int32)
        self._look = None if scene.appearance is None else _MeshLook(scene.appearance)
        self._lights = None if scene.lights is None else _PointLights(scene.lights, normals)
        self._rays = _aligned_empty((self._dirs_cam.shape[0], 6))
        self._dirs_world = np.empty((3, self._dirs_cam.shape[0]), np.float32)  # rays' directions, by axis

    @property
    def raycasting_scene(self):
        """The underlying ``open3d.t.geometry.RaycastingScene``."""
        return self._rc

    def rays(self, T_world_cam: np.ndarray) -> np.ndarray:
        """(H * W, 6) float32 rays (origin, direction with camera-z = 1) in world coordinates.

        The array is a buffer reused by the next call (fresh 1.5 MB arrays cost page faults), aligned
        to 64 bytes (Embree casts unaligned rays 30% slower). Copy it to keep it.
        """
        R = T_world_cam[:3, :3].astype(np.float32)
        d, rays, world = self._dirs_cam_t, self._rays, self._dirs_world
        for i in range(3):  # elementwise, not BLAS: BLAS threads fight Open3D's spinning OpenMP pool
            row = world[i]  # contiguous: cheaper to build here and to read again in colour()
            np.multiply(d[0], R[i, 0], out=row)
            if R[i, 1] != 0:  # zero for the vertical axis of a level camera
                row += R[i, 1] * d[1]
            row += R[i, 2]  # d[2] == 1
            rays[:, 3 + i] = row
            rays[:, i] = T_world_cam[i, 3]
        return rays

    def _rays_tensor(self, T_world_cam: np.ndarray):
        """:meth:`rays` as an Open3D tensor sharing the buffer (no 1.5 MB copy per frame)."""
        import open3d as o3d

        return o3d.core.Tensor.from_numpy(self.rays(T_world_cam))

    def render(self, T_world_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Clean ``rgb`` (H, W, 3) uint8 and ``depth`` (H, W) float32 metres (0 = no reading).

        ``T_world_cam``: 4x4 camera pose (OpenCV camera axes, world Z up).
        """
        hit = self.cast(T_world_cam)
        return self.colour(hit), self.depth(hit)

    def cast(self, T_world_cam: np.ndarray) -> Hits:
        """Cast every pixel's ray from ``T_world_cam``; :meth:`colour` and :meth:`depth` read the
        result (independently: they may run in two threads) until the next cast, which reuses the
        ray buffer."""
        hit = self._rc.cast_rays(self._rays_tensor(T_world_cam))
        # a miss carries the invalid id 2^32 - 1 = -1 as int32: with mode="wrap" it reads the last entry
        # of each per-triangle table, a black "miss" triangle.
        return Hits(
            hit["t_hit"].numpy(),
            hit["primitive_ids"].numpy().view(np.int32),
            self._rays[0, :3].copy(),
            self._dirs_world,
            hit,
        )

    def depth(self, hit: Hits) -> np.ndarray:
        """Clean z-depth (H, W) float32 metres of a :meth:`cast` (0 = no reading: a miss or out of range)."""
        cam, t = self.camera, hit.t
        return np.where((t >= cam.min_depth) & (t < cam.max_depth), t, np.float32(0.0)).reshape(cam.height, cam.width)

    def colour(self, hit: Hits) -> np.ndarray:
        """Clean RGB (H, W, 3) uint8 of a :meth:`cast`: albedo x shading x texture (a mesh file's
        scene: the file's own colours at each hit)."""
        cam, t, tri = self.camera, hit.t, hit.tri
        if self._look is not None:
            return self._look.colour(tri, hit.keep["primitive_uvs"].numpy()).reshape(cam.height, cam.width, 3)
        # Hit point coordinates, then the triangle's texture plane:
        # normal along X -> (Y, Z), along Y -> (X, Z), along Z (floor, ceiling) -> (X, Y). np.take: 3x faster than [].
        with np.errstate(invalid="ignore"):  # misses: inf / nan coordinates, cast to any int, unseen
            px, py, pz = (hit.origin[i] + t * hit.dirs[i] for i in range(3))
            axis = np.take(self._tri_axis, tri, mode="wrap")
            pu = np.where(axis == 0, py, px)
            pv = np.where(axis == 2, py, pz)
            # the offset keeps coordinates positive (no mirrored seam at 0); it is a multiple of the tile
            iu = (pu * (1.0 / TEXEL_SIZE) + _TEXEL_OFFSET).astype(np.int32) & self._tile_mask
            iv = (pv * (1.0 / TEXEL_SIZE) + _TEXEL_OFFSET).astype(np.int32) & self._tile_mask
            level = np.take(self._level_by_t, (t * _T_STEPS).astype(np.int32), mode="clip")
        level += (axis == 2) * self._floor_bias
        np.minimum(level, (self._levels - 1) * self._level_stride, out=level)
        index = level + np.take(self._tri_tile_offset, tri, mode="wrap") + (iv << self._log_size) + iu
        tex = np.take(self._tex.reshape(-1), index).astype(np.uint16)
        rgb = np.empty((len(t), 3), np.uint8)
        if self._lights is not None:
            light = self._lights.factor(hit.origin, (px, py, pz), hit.dirs, tri) * np.float32(1 / 128)
            for k in range(3):
                lit = np.take(self._tri_rgb_t[k], tri, mode="wrap") * tex * light
                rgb[:, k] = np.minimum(lit, 255.0)
            return rgb.reshape(cam.height, cam.width, 3)
        for k in range(3):  # one 1-D gather per channel: 3x faster than gathering (N, 3) rows
            rgb[:, k] = np.minimum((np.take(self._tri_rgb_t[k], tri, mode="wrap") * tex) >> 7, 255)
        return rgb.reshape(cam.height, cam.width, 3)


class _PointLights:
    """A scene's point lights (:attr:`Scene.lights`) as a brightness factor at each ray hit: ambient,
    a Lambertian term and a Blinn-Phong specular one (so a surface's grey level changes with the
    viewpoint), each light falling off as ``1 / (1 + (d / FALLOFF)^2)``; the :data:`NEAREST` lights
    nearest the camera are summed (farther ones add little)."""

    BASE, DIFFUSE, SPECULAR, SHININESS = 0.45, 0.9, 0.35, 16
    FALLOFF = 3.0  # m
    NEAREST = 4

    def __init__(self, lights: np.ndarray, normals: np.ndarray) -> None:
        self._lights = np.asarray(lights, np.float32)
        self._normals_t = np.ascontiguousarray(np.append(normals, np.zeros((1, 3)), axis=0).T, dtype=np.float32)

    def factor(self, origin: np.ndarray, points, dirs: np.ndarray, tri: np.ndarray) -> np.ndarray:
        """(N,) float32 brightness factors of hits at ``points`` (three (N,) world coordinates) on
        triangles ``tri`` (-1: a miss, factor 0), seen along ``dirs`` (3, N) from ``origin``."""
        n = [np.take(self._normals_t[i], tri, mode="wrap") for i in range(3)]
        norm = np.sqrt(dirs[0] ** 2 + dirs[1] ** 2 + dirs[2] ** 2)
        view = [-dirs[i] / norm for i in range(3)]  # towards the camera
        near = np.argsort(np.linalg.norm(self._lights[:, :2] - origin[:2], axis=1))[: self.NEAREST]
        diffuse = np.zeros(len(tri), np.float32)
        shine = np.zeros(len(tri), np.float32)
        with np.errstate(invalid="ignore", over="ignore"):  # misses: infinite points
            for lx, ly, lz, power in self._lights[near]:
                d = [lx - points[0], ly - points[1], lz - points[2]]
                d2 = d[0] ** 2 + d[1] ** 2 + d[2] ** 2
                inv = 1.0 / np.sqrt(d2)
                fall = power / (1.0 + d2 * np.float32(1 / self.FALLOFF**2))
                diffuse += fall * np.maximum((n[0] * d[0] + n[1] * d[1] + n[2] * d[2]) * inv, 0.0)
                h = [d[i] * inv + view[i] for i in range(3)]
                cos_h = (n[0] * h[0] + n[1] * h[1] + n[2] * h[2]) / np.sqrt(h[0] ** 2 + h[1] ** 2 + h[2] ** 2)
                shine += fall * np.maximum(cos_h, 0.0) ** self.SHININESS
            out = self.BASE + self.DIFFUSE * diffuse + self.SPECULAR * shine
        return np.where((tri >= 0) & np.isfinite(out), out, 0.0).astype(np.float32)


class _MeshLook:
    """A mesh file's colours at ray hits: its corner colours interpolated across each face, or its
    texture at the interpolated UV (nearest texel); black where a ray meets nothing."""

    def __init__(self, look) -> None:
        colors = np.asarray(look.corner_colors, np.float32)
        self._colors = np.concatenate([colors, np.zeros((1, 3, 3), np.float32)])  # the last row: misses
        self._textured = look.texture_of is not None
        if self._textured:
            self._uv = np.concatenate([np.asarray(look.corner_uv, np.float32), np.zeros((1, 3, 2), np.float32)])
            self._texture_of = np.append(np.asarray(look.texture_of, np.int32), -1)
            self._textures = [np.asarray(tex, np.uint8) for tex in look.textures]

    def colour(self, tri: np.ndarray, bary: np.ndarray) -> np.ndarray:
        """(N, 3) uint8 RGB of hits on triangles ``tri`` (-1: a miss) at barycentric ``bary`` (N, 2):
        the point is (1 - u - v) corner 0 + u corner 1 + v corner 2."""
        f = np.where(tri < 0, len(self._colors) - 1, tri)
        w = np.stack([1.0 - bary[:, 0] - bary[:, 1], bary[:, 0], bary[:, 1]], axis=1).astype(np.float32)
        rgb = np.einsum("nk,nkc->nc", w, self._colors[f])
        if self._textured:
            uv = np.einsum("nk,nkc->nc", w, self._uv[f])
            which = self._texture_of[f]
            for k, tex in enumerate(self._textures):
                sel = which == k
                if sel.any():
                    h, wd = tex.shape[:2]
                    col = np.clip(np.floor(np.mod(uv[sel, 0], 1.0) * wd), 0, wd - 1).astype(np.int64)
                    row = np.clip(np.floor((1.0 - np.mod(uv[sel, 1], 1.0)) * h), 0, h - 1).astype(np.int64)
                    rgb[sel] = tex[row, col]
        return np.clip(np.round(rgb), 0, 255).astype(np.uint8)
