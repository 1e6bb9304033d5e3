"""Scenes, rendering and the agent's motion rules."""
import numpy as np
import pytest

from odolab.geometry import camera_pose_from_agent, invert
from odolab.types import Action
from odolab.sim.agent import AgentState, apply_motion, step_agent
from odolab.sim.camera import CameraSpec, Renderer
from odolab.sim.noise import ActuationNoise, Motion
from odolab.sim.planner import ShortestPathFollower, geodesic_distance, largest_component
from odolab.sim.scenes import generate_scene, scene_seed, split_of_seed


def test_scene_is_deterministic_and_splits_are_disjoint():
    a, b = generate_scene(scene_seed("test", 3)), generate_scene(scene_seed("test", 3))
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.navigable, b.navigable)
    assert not np.array_equal(a.vertices.shape, generate_scene(scene_seed("test", 4)).vertices.shape) or \
        not np.array_equal(a.vertices, generate_scene(scene_seed("test", 4)).vertices)
    seeds = {s: {scene_seed(s, k) for k in range(0, 5000, 7)} for s in ("train", "val", "test")}
    assert not (seeds["train"] & seeds["val"]) and not (seeds["train"] & seeds["test"]) and not (seeds["val"] & seeds["test"])
    assert all(split_of_seed(x) == s for s, xs in seeds.items() for x in xs)
    with pytest.raises(ValueError, match="split"):
        scene_seed("validation", 0)


def test_many_scenes_have_room_to_move():
    for k in range(20):
        s = generate_scene(scene_seed("train", k))
        assert largest_component(s).sum() * s.resolution ** 2 > 5.0  # m^2 of navigable floor


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
    row = depth[cam.height // 2, cam.width // 2 - 30: cam.width // 2 + 30]  # +-7 degrees off-axis
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
    v, u = np.mgrid[10:cam.height - 10:7, 10:cam.width - 10:7]
    z = d_a[v, u]
    keep = z > 0
    pts = np.stack([(u + 0.5 - K.cx) / K.fx * z, (v + 0.5 - K.cy) / K.fy * z, z, np.ones_like(z)], -1)[keep]
    pb = (invert(Tb) @ Ta @ pts.T).T
    ub = K.fx * pb[:, 0] / pb[:, 2] + K.cx - 0.5
    vb = K.fy * pb[:, 1] / pb[:, 2] + K.cy - 0.5
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


def test_blocked_forward_step_does_not_slide_but_still_turns():
    scene = generate_scene(scene_seed("test", 2))
    s0 = _corridor_state(scene)
    s1, collided = apply_motion(scene, s0, Motion(forward=0.25, right=0.0, yaw=0.05))
    assert collided and (s1.x, s1.y) == (s0.x, s0.y) and s1.yaw == pytest.approx(s0.yaw + 0.05)
    # A free step moves the full amount: some heading from the same place is free for 0.3 m
    free = next((AgentState(s0.x, s0.y, float(yaw)) for yaw in np.linspace(-np.pi, np.pi, 16, endpoint=False)
                 if np.all(scene.is_navigable(s0.x + np.linspace(0, 0.3, 7) * np.cos(yaw),
                                              s0.y + np.linspace(0, 0.3, 7) * np.sin(yaw)))), None)
    assert free is not None
    s2, c2 = apply_motion(scene, free, Motion(0.25, 0.0, 0.0))
    assert not c2 and np.hypot(s2.x - free.x, s2.y - free.y) == pytest.approx(0.25)


def test_noiseless_follower_reaches_the_goal():
    scene = generate_scene(scene_seed("test", 5))
    comp = np.argwhere(largest_component(scene))
    sx, sy = (float(v) for v in scene.cell_to_world(*comp[0]))
    gx, gy = (float(v) for v in scene.cell_to_world(*comp[-1]))
    follower = ShortestPathFollower(scene, geodesic_distance(scene, gx, gy))
    state, rng, noise = AgentState(sx, sy, 0.0), np.random.default_rng(0), ActuationNoise(multiplier=0.0)
    for _ in range(600):
        a = follower.next_action(state)
        if a == Action.STOP:
            break
        state, collided = step_agent(scene, state, a, noise, rng)
        assert not collided
    assert a == Action.STOP and np.hypot(state.x - gx, state.y - gy) < 0.3


def test_geodesic_distance_is_metric_without_penalty():
    scene = generate_scene(scene_seed("test", 5))
    comp = np.argwhere(largest_component(scene))
    x, y = (float(v) for v in scene.cell_to_world(*comp[len(comp) // 3]))
    D = geodesic_distance(scene, x, y)
    r, c = scene.world_to_cell(x, y)
    assert D[r, c] == 0
    rr, cc = comp[len(comp) // 2]
    ex, ey = scene.cell_to_world(rr, cc)
    assert D[rr, cc] >= np.hypot(ex - x, ey - y) - 1e-9  # never shorter than the straight line
    assert np.isinf(D[~scene.navigable]).all()
    # one grid step costs one cell of distance (rook moves), so distances are in metres
    neighbours = [(r + dr, c + dc) for dr, dc in ((0, 1), (1, 0), (0, -1), (-1, 0)) if scene.navigable[r + dr, c + dc]]
    assert neighbours and all(D[n] == pytest.approx(scene.resolution) for n in neighbours)
