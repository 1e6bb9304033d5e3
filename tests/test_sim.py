"""Scenes, rendering and the agent's motion rules."""

import numpy as np
import pytest

from odolab.core.geometry import camera_pose_from_agent, invert
from odolab.core.types import Action
from odolab.sim.agent import AgentState, apply_motion, step_agent
from odolab.sim.camera import CameraSpec, Renderer
from odolab.sim.noise import ActuationNoise, Motion
from odolab.sim.planner import ShortestPathFollower, geodesic_field, largest_component
from odolab.sim.scenes import generate_scene, scene_seed, split_of_seed


def test_scene_is_deterministic_and_splits_are_disjoint():
    a, b = generate_scene(scene_seed("test", 3)), generate_scene(scene_seed("test", 3))
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.navigable, b.navigable)
    assert not np.array_equal(
        a.vertices.shape, generate_scene(scene_seed("test", 4)).vertices.shape
    ) or not np.array_equal(a.vertices, generate_scene(scene_seed("test", 4)).vertices)
    seeds = {s: {scene_seed(s, k) for k in range(0, 5000, 7)} for s in ("train", "val", "test")}
    assert (
        not (seeds["train"] & seeds["val"])
        and not (seeds["train"] & seeds["test"])
        and not (seeds["val"] & seeds["test"])
    )
    assert all(split_of_seed(x) == s for s, xs in seeds.items() for x in xs)
    with pytest.raises(ValueError, match="split"):
        scene_seed("validation", 0)


def test_many_scenes_have_room_to_move():
    for k in range(20):
        s = generate_scene(scene_seed("train", k))
        assert largest_component(s).sum() * s.resolution**2 > 5.0  # m^2 of navigable floor


def test_depth_is_z_distance_to_the_wall():
    """Facing the west outer wall (inner face at x = 0) from x = 1 m over free floor, every pixel of the
    centre row that sees the wall reads 1 m: z distance, not ray length (which grows off-centre)."""
    scene = generate_scene(scene_seed("test", 0))
    cam = CameraSpec()
    r = Renderer(scene, cam)
    xs = np.linspace(0.01, 1.0, 100)

    def clear(y):  # nothing stands between the camera and the wall, +-0.15 m around the line of sight
        rows, cols = scene.world_to_cell(np.repeat(xs, 3), np.tile([y - 0.15, y, y + 0.15], len(xs)))
        return bool(np.all(scene.free[rows, cols]))

    cells = np.argwhere(scene.navigable)
    ys = sorted({float(v) for v in scene.cell_to_world(cells[:, 0], cells[:, 1])[1]})
    y = next((y for y in ys if scene.is_navigable(1.0, y) and clear(y)), None)
    assert y is not None, "no clear line of sight to the west wall in this scene"
    rgb, depth = r.render(camera_pose_from_agent(1.0, y, np.pi, cam.mount_height))
    row = depth[cam.height // 2, cam.width // 2 - 30 : cam.width // 2 + 30]  # +-7 degrees off-axis
    assert row == pytest.approx(np.ones_like(row), abs=2e-3)
    assert rgb.dtype == np.uint8 and depth.dtype == np.float32 and rgb.shape == (cam.height, cam.width, 3)


def test_texture_is_fixed_to_the_world():
    """A surface point has the same colour from two viewpoints (so features are trackable)."""
    scene = generate_scene(scene_seed("test", 1))
    cam = CameraSpec()
    r = Renderer(scene, cam)
    K = cam.intrinsics
    cells = np.argwhere(largest_component(scene))
    x, y = (float(v) for v in scene.cell_to_world(*cells[len(cells) // 2]))
    Ta = camera_pose_from_agent(x, y, 0.3, cam.mount_height)
    Tb = camera_pose_from_agent(x, y, 0.3 + np.radians(10), cam.mount_height)
    rgb_a, d_a = r.render(Ta)
    rgb_b, d_b = r.render(Tb)
    v, u = np.mgrid[10 : cam.height - 10 : 7, 10 : cam.width - 10 : 7]
    z = d_a[v, u]
    keep = z > 0
    pts = np.stack([(u - K.cx) / K.fx * z, (v - K.cy) / K.fy * z, z, np.ones_like(z)], -1)[keep]
    pb = (invert(Tb) @ Ta @ pts.T).T
    ub = K.fx * pb[:, 0] / pb[:, 2] + K.cx
    vb = K.fy * pb[:, 1] / pb[:, 2] + K.cy
    ui, vi = np.round(ub).astype(int), np.round(vb).astype(int)
    inside = (ui >= 0) & (ui < cam.width) & (vi >= 0) & (vi < cam.height) & (pb[:, 2] > 0)
    same_depth = np.abs(d_b[vi[inside], ui[inside]] - pb[inside, 2]) < 0.02
    ca = rgb_a[v[keep], u[keep]][inside][same_depth].astype(int)
    cb = rgb_b[vi[inside], ui[inside]][same_depth].astype(int)
    assert len(ca) > 100
    assert np.median(np.abs(ca - cb).sum(1)) < 15


def _corridor_state(scene):
    """A navigable state facing the nearest blocked cell straight ahead within 1 m."""
    cells = np.argwhere(scene.navigable)
    for r_, c_ in cells[:: max(1, len(cells) // 400)]:
        x, y = (float(v) for v in scene.cell_to_world(r_, c_))
        for yaw in np.linspace(-np.pi, np.pi, 8, endpoint=False):
            ahead = scene.is_navigable(x + 0.2 * np.cos(yaw), y + 0.2 * np.sin(yaw))
            if not ahead:
                return AgentState(x, y, float(yaw))
    raise AssertionError("no state next to an obstacle")


def test_blocked_forward_step_stops_at_contact_without_sliding_and_still_turns():
    scene = generate_scene(scene_seed("test", 2))
    s0 = _corridor_state(scene)
    s1, collided = apply_motion(scene, s0, Motion(forward=0.25, right=0.0, yaw=0.05))
    moved = np.hypot(s1.x - s0.x, s1.y - s0.y)
    assert collided and moved < 0.2 and s1.yaw == pytest.approx(s0.yaw + 0.05)
    assert scene.is_navigable(s1.x, s1.y)  # stopped at contact, inside the navigable area
    # no sliding: the agent stays on the line of the commanded step
    cross = (s1.x - s0.x) * np.sin(s0.yaw) - (s1.y - s0.y) * np.cos(s0.yaw)
    assert abs(cross) < 1e-9
    # ... and it stopped within 1 cm of where the straight path leaves the navigable area
    nx, ny = s1.x + 0.011 * np.cos(s0.yaw), s1.y + 0.011 * np.sin(s0.yaw)
    assert not scene.is_navigable(nx, ny) or not scene.is_navigable(
        nx + 0.01 * np.cos(s0.yaw), ny + 0.01 * np.sin(s0.yaw)
    )
    # the other rule: a blocked step leaves the agent where it was
    s3, c3 = apply_motion(scene, s0, Motion(forward=0.25, right=0.0, yaw=0.05), stop_at_contact=False)
    assert c3 and (s3.x, s3.y) == (s0.x, s0.y) and s3.yaw == pytest.approx(s0.yaw + 0.05)
    # A free step moves the full amount: some heading from the same place is free for 0.3 m
    free = next(
        (
            AgentState(s0.x, s0.y, float(yaw))
            for yaw in np.linspace(-np.pi, np.pi, 16, endpoint=False)
            if np.all(
                scene.is_navigable(
                    s0.x + np.linspace(0, 0.3, 7) * np.cos(yaw), s0.y + np.linspace(0, 0.3, 7) * np.sin(yaw)
                )
            )
        ),
        None,
    )
    assert free is not None
    s2, c2 = apply_motion(scene, free, Motion(0.25, 0.0, 0.0))
    assert not c2 and np.hypot(s2.x - free.x, s2.y - free.y) == pytest.approx(0.25)


def test_noiseless_follower_reaches_the_goal():
    scene = generate_scene(scene_seed("test", 5))
    comp = np.argwhere(largest_component(scene))
    sx, sy = (float(v) for v in scene.cell_to_world(*comp[0]))
    gx, gy = (float(v) for v in scene.cell_to_world(*comp[-1]))
    field = geodesic_field(scene, gx, gy)
    follower = ShortestPathFollower(field)
    state, rng, noise = AgentState(sx, sy, 0.0), np.random.default_rng(0), ActuationNoise(multiplier=0.0)
    collisions = 0
    for _ in range(600):
        a = follower.next_action(state)
        if a == Action.STOP:
            break
        state, collided = step_agent(scene, state, a, noise, rng)
        collisions += collided
    assert a == Action.STOP and field.at(state.x, state.y) < follower.goal_radius
    assert collisions <= 2  # habitat's greedy follower may graze a corner: a collision costs 0.25, not inf


def test_geodesic_distance_is_metric_and_has_no_grid_bias():
    scene = generate_scene(scene_seed("test", 5))
    comp = np.argwhere(largest_component(scene))
    x, y = (float(v) for v in scene.cell_to_world(*comp[len(comp) // 3]))
    field = geodesic_field(scene, x, y)
    assert field.at(x, y) < 0.5 * scene.resolution
    assert np.isinf(field.distance[~scene.navigable]).all()
    # Where the straight line is free, geodesic = euclidean in every direction (an 8-connected grid
    # overestimates by up to 8 % at 22.5 deg); elsewhere it is never shorter than the straight line.
    rel, checked = [], 0
    for rr, cc in comp[:: max(1, len(comp) // 300)]:
        ex, ey = (float(v) for v in scene.cell_to_world(rr, cc))
        euclid = np.hypot(ex - x, ey - y)
        if euclid < 1.0:
            continue
        geo = field.at(ex, ey)
        assert geo >= euclid - 0.02
        s = np.linspace(0, 1, 200)
        if scene.is_navigable(x + s * (ex - x), y + s * (ey - y)).all():
            rel.append(geo / euclid - 1)
            checked += 1
    assert checked > 10 and np.max(np.abs(rel)) < 0.03 and abs(np.mean(rel)) < 0.01


def test_one_pixel_convention_reprojects_noiseless_depth_exactly():
    """Frame t's depth, back-projected with Intrinsics, moved by the true relative pose and projected
    into frame t+1, agrees with frame t+1's depth (a half-pixel error would show as ~1 mm)."""
    scene = generate_scene(scene_seed("test", 1))
    cam = CameraSpec()
    r = Renderer(scene, cam)
    K = cam.intrinsics
    assert (K.cx, K.cy) == ((cam.width - 1) / 2, (cam.height - 1) / 2)
    cells = np.argwhere(largest_component(scene))
    x, y = (float(v) for v in scene.cell_to_world(*cells[len(cells) // 2]))
    Ta = camera_pose_from_agent(x, y, 0.3, cam.mount_height)
    Tb = camera_pose_from_agent(x + 0.2 * np.cos(0.5), y + 0.2 * np.sin(0.5), 0.3 + np.radians(8), cam.mount_height)
    _, d_a = r.render(Ta)
    _, d_b = r.render(Tb)
    v, u = np.nonzero(d_a > 0)
    z = d_a[v, u].astype(np.float64)
    pts = np.stack([(u - K.cx) / K.fx * z, (v - K.cy) / K.fy * z, z, np.ones_like(z)], -1)
    pb = (invert(Tb) @ Ta @ pts.T).T
    ub, vb = K.fx * pb[:, 0] / pb[:, 2] + K.cx, K.fy * pb[:, 1] / pb[:, 2] + K.cy
    # inverse depth is affine in (u, v) on a plane: interpolate it bilinearly where 4 neighbours agree
    u0, v0 = np.floor(ub).astype(int), np.floor(vb).astype(int)
    ok = (u0 >= 0) & (u0 < cam.width - 1) & (v0 >= 0) & (v0 < cam.height - 1) & (pb[:, 2] > 0)
    u0, v0, a, b, zb = u0[ok], v0[ok], (ub - np.floor(ub))[ok], (vb - np.floor(vb))[ok], pb[ok, 2]
    quad = np.stack([d_b[v0, u0], d_b[v0, u0 + 1], d_b[v0 + 1, u0], d_b[v0 + 1, u0 + 1]]).astype(np.float64)
    good = (quad > 0).all(0) & (np.ptp(quad, axis=0) < 0.05)
    inv = 1 / quad[:, good]
    a, b = a[good], b[good]
    interp = 1 / ((1 - b) * ((1 - a) * inv[0] + a * inv[1]) + b * ((1 - a) * inv[2] + a * inv[3]))
    diff = np.abs(interp - zb[good])
    diff = diff[diff < 0.05]  # drop occlusions
    assert len(diff) > 1000
    assert np.median(diff) < 1e-5  # < 0.01 mm
