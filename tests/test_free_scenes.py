"""odolab/sim/free_scenes.py: the ``free`` family. Its walls are not at right angles to each other
or to the world axes, its furniture stands at any yaw, its occupancy map keeps the agent clear of
the mesh, its lights make a surface's grey level change with the viewpoint, and its episodes run
from every command; the ``boxes`` family and its keys are as they were."""

from __future__ import annotations

import numpy as np
import pytest

from odolab.core.geometry import camera_pose_from_agent
from odolab.sim.camera import CameraSpec, Renderer, _normals
from odolab.sim.episodes import EpisodeSpec, rollout
from odolab.sim.free_scenes import free_scene
from odolab.sim.scenes import WALL_MATERIALS, generate_scene, scene_seed

SEEDS = [scene_seed("test", k) for k in range(4)]


def _wall_angles(scene) -> np.ndarray:
    """Directions (deg, modulo 90) of the normals of the scene's walls (their vertical faces)."""
    n = _normals(scene)
    walls = (np.abs(n[:, 2]) < 1e-6) & (scene.triangle_material < WALL_MATERIALS[1])
    return np.degrees(np.arctan2(n[walls, 1], n[walls, 0])) % 90.0


def test_free_walls_meet_at_other_angles_and_face_every_way():
    for seed in SEEDS:
        boxes, free = _wall_angles(generate_scene(seed)), _wall_angles(free_scene(seed))
        assert np.all(np.minimum(boxes, 90 - boxes) < 1e-3)  # boxes: every wall on a world axis
        spread = np.minimum(free - np.median(free), 90 - np.abs(free - np.median(free)))
        assert np.mean(np.abs(spread) > 3.0) > 0.2, seed  # free: a fifth of the walls off the main direction
    headings = [np.median(_wall_angles(free_scene(s))) for s in SEEDS]
    assert np.ptp(headings) > 5.0  # and buildings turned other ways in the world


def test_a_free_scene_is_determined_by_its_seed_and_keeps_the_agent_clear_of_its_mesh():
    """Every navigable cell's centre, 0.5 m up, is as far from the mesh as in the boxes family: the
    agent's radius (0.18 m) less at most 0.07 m, the 5 cm map's rounding (a solid marks the cells
    whose centres it covers)."""
    import open3d as o3d

    a, b = free_scene(SEEDS[0]), free_scene(SEEDS[0])
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.navigable, b.navigable)
    for seed in SEEDS:
        for scene in (generate_scene(seed), free_scene(seed)):
            rc = o3d.t.geometry.RaycastingScene()
            rc.add_triangles(o3d.core.Tensor(scene.vertices), o3d.core.Tensor(scene.triangles.astype(np.uint32)))
            cells = np.argwhere(scene.navigable)
            assert len(cells) * scene.resolution**2 > 15.0  # m^2 to move in
            x, y = scene.cell_to_world(cells[:, 0], cells[:, 1])
            at = np.stack([x, y, np.full_like(x, 0.5)], 1).astype(np.float32)
            clear = rc.compute_distance(o3d.core.Tensor(at)).numpy()
            assert clear.min() >= scene.agent_radius - 0.07, (seed, scene.lights is None, clear.min())


def test_free_lights_change_grey_levels_across_a_room_and_with_the_viewpoint():
    """A free scene's brightness factor at one hit differs when seen from elsewhere (specular) and
    from a hit nearer a light (fall-off); a boxes scene has no point lights (Lambertian under a
    directional light: one colour per surface point from anywhere)."""
    assert Renderer(generate_scene(SEEDS[1]), CameraSpec(width=64, height=36))._lights is None
    scene = free_scene(SEEDS[1])
    r = Renderer(scene, CameraSpec(width=64, height=36))
    cells = np.argwhere(scene.navigable)
    x, y = scene.cell_to_world(*cells[len(cells) // 2])
    hit = r.cast(camera_pose_from_agent(float(x), float(y), 0.0, 0.88))
    seen = np.flatnonzero(np.isfinite(hit.t))
    points = hit.origin[:, None] + hit.t[seen] * hit.dirs[:, seen]
    tri = hit.tri[seen]
    here = r._lights.factor(hit.origin, points, hit.dirs[:, seen], tri)
    elsewhere = hit.origin + np.array([0.6, -0.4, 0.0], np.float32)
    there = r._lights.factor(elsewhere, points, (points - elsewhere[:, None]).astype(np.float32), tri)
    assert np.all(here > 0) and np.max(np.abs(there / here - 1)) > 0.05
    assert np.ptp(here) / np.median(here) > 0.3  # across the view


def test_episodes_run_in_the_free_family_with_keys_apart_and_the_boxes_keys_unchanged():
    boxes, free = EpisodeSpec(max_steps=20), EpisodeSpec(max_steps=20, family="free")
    assert "family" not in boxes.record() and free.record()["family"] == "free"
    assert boxes.key() != free.key()
    motion = rollout(free)
    assert len(motion.actions) > 0
    with pytest.raises(ValueError, match=r"family: expected one of boxes, free, got 'blobs'"):
        EpisodeSpec(family="blobs")


def test_compare_runs_in_the_free_family_and_refuses_it_beside_mesh_files(tmp_path, capsys):
    import csv

    from odolab.cli import run_cli
    from odolab.cli.compare import main
    from tests.helpers import refused

    argv = ["--scene-family", "free", "--odometers", "ground-truth,action-prior", "--episodes", "1"]
    argv += ["--max-steps", "8", "--serial", "--quiet", "--no-cache", "--out", str(tmp_path / "o")]
    assert run_cli(main, "python -m odolab.compare", argv) == 0
    with open(tmp_path / "o" / "table.csv") as f:
        assert [r["odometer"] for r in csv.DictReader(f)] == ["ground-truth", "action-prior"]
    assert "--scene-family free" in (tmp_path / "o" / "report.html").read_text()
    capsys.readouterr()
    (tmp_path / "room.ply").write_text("x")
    line = refused(capsys, "compare", ["--scenes", str(tmp_path / "room.ply"), "--scene-family", "free"])
    assert "--scene-family free is for procedural scenes" in line
