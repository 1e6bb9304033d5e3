"""odolab/sim/mesh_scenes.py: scenes from mesh files. A procedural scene written as GLB (Y-up, its
colours in a texture) or PLY (Z-up, vertex colours) and read back is the same scene: the same
depth bit for bit, the same RGB as the procedural renderer shows with flat texture tiles, and the
same free cells but for at most 0.5 % of them, each within half a cell (2.5 cm) of a surface: a
cylinder's facets (a 16-sided prism in the mesh, a circle in the procedural map) or the faces of
solids that touch, where the inside test is undecided. Bad files are one line naming the file."""

from __future__ import annotations

import numpy as np
import pytest

from odolab.core.geometry import camera_pose_from_agent
from odolab.sim.camera import CameraSpec, Renderer
from odolab.sim.mesh_scenes import MeshError, export_scene, mesh_scene, read_mesh
from odolab.sim.scenes import generate_scene, scene_seed
from odolab.sim.textures import make_tiles

CAMERA = CameraSpec(width=96, height=54)


@pytest.fixture(scope="module")
def scene():
    return generate_scene(scene_seed("test", 0))


def _near_a_surface(scene, cells: np.ndarray) -> np.ndarray:
    """Distance (m) from each cell's centre, 0.5 m above the floor, to the scene's nearest surface."""
    import open3d as o3d

    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.core.Tensor(scene.vertices), o3d.core.Tensor(scene.triangles.astype(np.uint32)))
    x, y = scene.cell_to_world(cells[:, 0], cells[:, 1])
    return rc.compute_distance(o3d.core.Tensor(np.stack([x, y, np.full_like(x, 0.5)], 1).astype(np.float32))).numpy()


def _window(mesh, scene):
    """The mesh scene's free cells over the procedural scene's grid (the grids line up)."""
    dr, dc = (round((scene.origin[k] - mesh.origin[k]) / scene.resolution) for k in (1, 0))
    rows, cols = scene.free.shape
    assert mesh.free[:dr].sum() + mesh.free[dr + rows :].sum() + mesh.free[:, :dc].sum() == 0
    return mesh.free[dr : dr + rows, dc : dc + cols]


@pytest.mark.parametrize("name,up", [("scene.glb", "y"), ("scene.ply", "z")])
def test_a_procedural_scene_written_and_read_back_is_the_same_scene(tmp_path, scene, name, up):

    mesh = mesh_scene(read_mesh(export_scene(scene, tmp_path / name, up=up), up=up))
    ours, theirs = Renderer(mesh, CAMERA), Renderer(scene, CAMERA, tiles=np.full_like(make_tiles(), 0.6))
    rng = np.random.default_rng(0)
    cells = np.argwhere(scene.navigable)
    for k in rng.integers(len(cells), size=6):
        x, y = scene.cell_to_world(*cells[k])
        pose = camera_pose_from_agent(float(x), float(y), float(rng.uniform(-np.pi, np.pi)), 0.88)
        (rgb, depth), (rgb_p, depth_p) = ours.render(pose), theirs.render(pose)
        assert np.array_equal(depth, depth_p) and (depth > 0).mean() > 0.5
        assert np.array_equal(rgb, rgb_p)
    free = _window(mesh, scene)
    differ = np.argwhere(free != scene.free)
    assert len(differ) <= 0.005 * scene.free.sum()
    assert (_near_a_surface(scene, differ) <= 0.026).all()


def test_touching_solids_and_cylinders_are_the_only_differences_in_another_scene(tmp_path):
    scene = generate_scene(scene_seed("val", 6))  # outer walls touching inner ones: the hardest seen
    mesh = mesh_scene(read_mesh(export_scene(scene, tmp_path / "scene.ply", up="z"), up="z"))
    differ = np.argwhere(_window(mesh, scene) != scene.free)
    assert len(differ) <= 0.005 * scene.free.sum() and (_near_a_surface(scene, differ) <= 0.026).all()


def test_a_y_up_and_a_z_up_file_of_one_room_give_the_same_scene(tmp_path, scene):
    y = mesh_scene(read_mesh(export_scene(scene, tmp_path / "y.ply", up="y"), up="y"))
    z = mesh_scene(read_mesh(export_scene(scene, tmp_path / "z.ply", up="z"), up="z"))
    assert np.array_equal(y.vertices, z.vertices) and np.array_equal(y.navigable, z.navigable)
    assert y.origin == z.origin and y.navigable.any()


def _ply(path, vertices, faces):
    import trimesh

    trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces), process=False).export(path)
    return path


def test_a_mesh_that_cannot_be_a_scene_is_one_line_naming_the_file(tmp_path, monkeypatch):
    from odolab.sim import mesh_scenes

    wall = _ply(tmp_path / "wall.ply", [[0, 0, 0], [4, 0, 0], [4, 0, 2], [0, 0, 2]], [[0, 1, 2], [0, 2, 3]])
    floor = [[0, 0, 0], [4, 0, 0], [4, 4, 0], [0, 4, 0]]
    covered = _ply(
        tmp_path / "covered.ply",
        [*floor, *[[x, y, 0.5] for x, y, _ in floor]],
        [[0, 1, 2], [0, 2, 3], [6, 5, 4], [7, 6, 4]],
    )
    tiny = _ply(tmp_path / "tiny.ply", [[0, 0, 0], [0.6, 0, 0], [0.6, 0.6, 0], [0, 0.6, 0]], [[0, 1, 2], [0, 2, 3]])
    (tmp_path / "empty.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 0\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n"
    )
    (tmp_path / "junk.glb").write_bytes(b"not a mesh at all")
    (tmp_path / "scene.stl").write_bytes(b"solid x\nendsolid x\n")
    cases = [
        (wall, "z", "no up-facing surface: no floor to stand on"),
        (covered, "z", "no free floor"),
        (tiny, "z", "its largest navigable floor is 0.29 m across; an episode's start and goal are at least 1 m apart"),
        (tmp_path / "empty.ply", "z", "holds no triangles"),
        (tmp_path / "junk.glb", "y", "not a readable GLB mesh"),
        (tmp_path / "scene.stl", "y", "unknown mesh type '.stl'"),
        (tmp_path / "missing.ply", "y", "no such file"),
        (wall, "x", "up: expected 'y' or 'z'"),
    ]
    for path, up, said in cases:
        with pytest.raises(MeshError) as exc:
            mesh_scene(read_mesh(path, up=up), name=str(path))
        assert str(exc.value).startswith(str(path)) and said in str(exc.value) and "\n" not in str(exc.value), exc.value
    monkeypatch.setattr(mesh_scenes, "MAX_FILE_BYTES", 100)
    with pytest.raises(MeshError, match=r"wall.ply: .* GB, above the .* GB a scene may be"):
        read_mesh(wall, up="z")


def test_floor_span_is_the_largest_distance_across_the_largest_region(tmp_path):
    """A 4 m square room's navigable floor spans its diagonal less the agent's clearance; a line of cells
    (no hull) is measured end to end."""
    import dataclasses

    from odolab.sim.mesh_scenes import floor_span

    room = _ply(tmp_path / "room.ply", [[0, 0, 0], [4, 0, 0], [4, 4, 0], [0, 4, 0]], [[0, 1, 2], [0, 2, 3]])
    scene = mesh_scene(read_mesh(room, up="z"), name="room")
    side = 4.0 - 2 * scene.agent_radius
    assert side * np.sqrt(2) - 0.2 < floor_span(scene) <= side * np.sqrt(2)
    line = np.zeros_like(scene.navigable)
    line[5, 3:23] = True
    assert floor_span(dataclasses.replace(scene, navigable=line)) == pytest.approx(19 * scene.resolution)


def test_compare_runs_in_a_mesh_file_keyed_by_its_content(tmp_path, scene, capsys):
    """compare --scenes: episodes in the file's scene, the same on a rerun and for a copy of the file
    elsewhere (the cache is keyed by the content), and a bad file refused in one line."""
    import csv
    import shutil

    from odolab.cli import run_cli
    from odolab.cli.compare import main
    from odolab.sim.mesh_scenes import scene_files
    from tests.helpers import refused

    room = export_scene(scene, tmp_path / "room.glb", up="y")
    (tmp_path / "copy").mkdir()
    copy = shutil.copy(room, tmp_path / "copy" / "same.glb")
    assert scene_files(room, "test").digests == scene_files(copy, "val").digests  # one file: every split's scene
    tables = []
    for k, path in enumerate([room, room, copy]):
        argv = ["--scenes", str(path), "--odometers", "ground-truth,action-prior", "--episodes", "2"]
        argv += [
            "--max-steps",
            "8",
            "--serial",
            "--quiet",
            "--cache",
            str(tmp_path / "cache"),
            "--out",
            str(tmp_path / f"o{k}"),
        ]
        assert run_cli(main, "python -m odolab.compare", argv) == 0
        with open(tmp_path / f"o{k}" / "table.csv") as f:
            tables.append([{c: r[c] for c in ("odometer", "dx", "dz", "dyaw", "steps")} for r in csv.DictReader(f)])
    assert tables[0] == tables[1] == tables[2] and tables[0][0]["steps"] != "0"
    assert len(list((tmp_path / "cache").glob("*.npz"))) == 2  # the copy reused the same two episodes
    capsys.readouterr()
    (tmp_path / "bad.ply").write_text("not a mesh")
    line = refused(capsys, "compare", ["--scenes", str(tmp_path / "bad.ply"), "--out", str(tmp_path / "x")])
    assert "--scenes" in line and "bad.ply: not a readable PLY mesh" in line and not (tmp_path / "x").exists()


def test_navigate_runs_in_a_mesh_file(tmp_path, scene):
    """navigate --scenes: the same episode as compare's in that file, driven closed loop, saved, and
    kept apart from the procedural scenes' episodes by its key."""
    import json

    from odolab.cli import run_cli
    from odolab.navigate import main

    room = export_scene(scene, tmp_path / "room.ply", up="z")
    argv = ["--scenes", str(room), "--scene-up", "z", "--odometers", "ground-truth", "--episodes", "1"]
    argv += ["--max-steps", "40", "--serial", "--quiet", "--out", str(tmp_path / "nav")]
    assert run_cli(main, "python -m odolab.navigate", argv) == 0
    config = json.loads((tmp_path / "nav" / "config.json").read_text())
    assert config["episodes"][0]["scenes"]["digests"] == [read_mesh(room, up="z").digest]
    (saved,) = (tmp_path / "nav" / "episodes" / "ground-truth").glob("*.json")
    assert json.loads(saved.read_text())["steps"] > 0


def test_a_scan_in_the_wrong_unit_or_up_axis_and_scene_options_alone_are_refused(tmp_path, scene, capsys):
    from tests.helpers import refused

    room = export_scene(scene, tmp_path / "room.glb", up="y")
    with pytest.raises(MeshError, match=r"room.glb: spans .* m, above the 200 m a scene may; .* \(--scene-unit\)"):
        read_mesh(room, up="y", unit=1000.0)  # millimetres read as metres
    with pytest.raises(
        MeshError, match=r"room.glb: .* m tall above its floor and .* m across at most: is its up axis the one given"
    ):
        mesh_scene(read_mesh(room, up="z"), name=str(room))
    for name in ("compare", "navigate"):
        line = refused(capsys, name, ["--scene-up", "z", "--out", str(tmp_path / "o")])
        assert "--scene-up is for --scenes" in line


def test_obj_materials_and_a_gltf_with_its_buffer_beside_it_are_read(tmp_path):
    """An OBJ's material colour (its .mtl beside it) and a .gltf whose buffer is a file of its own."""
    import trimesh

    (tmp_path / "obj").mkdir()
    floor = trimesh.Trimesh([[0, 0, 0], [4, 0, 0], [4, 4, 0], [0, 4, 0]], [[0, 1, 2], [0, 2, 3]], process=False)
    floor.visual = trimesh.visual.TextureVisuals(
        material=trimesh.visual.material.SimpleMaterial(diffuse=[255, 0, 0, 255])
    )
    floor.export(tmp_path / "obj" / "floor.obj")
    assert (read_mesh(tmp_path / "obj" / "floor.obj", up="z").appearance.corner_colors == [255, 0, 0]).all()
    (tmp_path / "gltf").mkdir()
    files = floor.export(file_type="gltf")  # {"model.gltf": ..., "gltf_buffer_....bin": ...}
    for name, data in files.items():
        (tmp_path / "gltf" / name).write_bytes(data)
    data = read_mesh(tmp_path / "gltf" / "model.gltf", up="z")
    assert len(data.triangles) == 2
    bin_file = next(p for p in (tmp_path / "gltf").iterdir() if p.suffix == ".bin")
    bin_file.write_bytes(bin_file.read_bytes())  # the same bytes: the same digest
    assert read_mesh(tmp_path / "gltf" / "model.gltf", up="z").digest == data.digest


def test_training_data_runs_in_a_mesh_file_and_its_folder_keeps_to_those_scenes(tmp_path, scene, capsys):
    """training_data --scenes: shards of episodes in the file's scene (their true poses those of the
    same episodes rendered directly), the manifest keyed by the file's digest, not its path; the
    folder refuses procedural episodes and a record that is not one of digests."""
    import dataclasses
    import json

    from odolab.cli import run_cli
    from odolab.cli.training_data import main
    from odolab.sim.episodes import rollout
    from odolab.sim.mesh_scenes import SceneFiles, scene_files
    from odolab.sim.training_data import DataConfig, TrainingData, make_training_data
    from tests.helpers import refused

    room = export_scene(scene, tmp_path / "room.ply", up="z")
    argv = ["--scenes", str(room), "--scene-up", "z", "--split", "val", "--episodes", "2", "--max-steps", "6"]
    argv += ["--width", "48", "--height", "27", "--serial", "--out", str(tmp_path / "d")]
    assert run_cli(main, "python -m odolab.training_data", argv) == 0
    data = TrainingData(tmp_path / "d")
    files = scene_files(room, "val", up="z")
    assert data.scenes == dataclasses.replace(files, files=()) and len(data) > 0
    spec = data.config.episode_specs(files)[1]
    assert np.allclose(data.poses[data.episode == spec.index], rollout(spec).camera_poses(spec.camera.mount_height))
    manifest = json.loads((tmp_path / "d" / "dataset.json").read_text())
    assert manifest["scenes"] == files.identity() and str(tmp_path) not in json.dumps(manifest)
    capsys.readouterr()
    with pytest.raises(
        ValueError, match=r"made in mesh scenes of digests .* not in procedural scenes of the boxes family as asked"
    ):
        make_training_data(DataConfig(split="val", episodes=2, max_steps=6, width=48, height=27), tmp_path / "d")
    line = refused(capsys, "training_data", ["--out", str(tmp_path / "e"), "--scene-unit", "0.01"])
    assert "--scene-unit is for --scenes" in line and not (tmp_path / "e").exists()
    with pytest.raises(MeshError, match=r"m.json: field scenes.digests: expected SHA-256 hex digests"):
        SceneFiles.recorded({"digests": ["../x"], "up": "y", "unit": 1.0}, "m.json")
    with pytest.raises(MeshError, match="known by their digests only"):
        data.scenes.scene(0)


@pytest.mark.parametrize("parallel", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_a_mesh_file_changed_after_it_was_read_is_one_line(tmp_path, scene, capsys, monkeypatch, parallel):
    """compare --scenes: the file changes between its reading and its episodes (in this process or
    in a Ray task): one line naming it, as a serial run says it."""
    from odolab.cli import compare
    from odolab.sim import mesh_scenes
    from tests.helpers import refused

    room = export_scene(scene, tmp_path / "room.ply", up="z")
    read = compare.scenes_of

    def then_changed(args, argv):
        files = read(args, argv)
        export_scene(generate_scene(scene_seed("test", 2)), room, up="z")  # another scene in its place
        mesh_scenes._mesh_scene_of.cache_clear()
        return files

    monkeypatch.setattr(compare, "scenes_of", then_changed)
    argv = ["--scenes", str(room), "--scene-up", "z", "--odometers", "ground-truth", "--episodes", "2"]
    argv += ["--max-steps", "5", "--no-cache", "--quiet", "--out", str(tmp_path / "o")]
    line = refused(capsys, "compare", argv if parallel else [*argv, "--serial"])
    assert "room.ply: changed since the episodes were specified" in line and "ray::" not in line
