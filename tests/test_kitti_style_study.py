"""studies.kitti_style and the touring routes it runs on (odolab.sim.routes): a route is its seed's and
ends at its length; the default scenes are unchanged by the floor plan's scale; the ci scale reports
every odometer with KITTI's errors and writes its KITTI and TUM files, resumes from its saved units
and redraws from them alone; and ``odolab.evaluate`` scores a written pair as evo does."""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from evo.core import lie_algebra as lie
from evo.core import metrics, sync
from evo.tools import file_interface

from odolab.cli import evaluate
from odolab.cli.study import study
from odolab.core.metrics import KITTI_LENGTHS, path_lengths
from odolab.sim.camera import CameraSpec
from odolab.sim.routes import RouteFrames, RouteSpec, tour
from odolab.sim.scenes import generate_scene, scene_seed
from studies import framework, kitti_style

SHORT = RouteSpec(length=12.0, scene_scale=1.0, min_leg=2.0, max_leg=8.0, camera=CameraSpec(width=32, height=18))
CI = framework.load_study("kitti_style").at("ci")


def test_a_route_is_its_seeds_and_ends_at_its_length():
    a, b = tour(SHORT), tour(SHORT)
    assert (a.states, a.actions, a.collisions, a.goals) == (b.states, b.actions, b.collisions, b.goals)
    length = path_lengths(a.camera_poses(0.88)[:, :3, 3])[-1]
    assert length == pytest.approx(a.length)
    assert SHORT.length <= length < SHORT.length + 0.35  # it stops at the first step past its length
    assert len(a.goals) >= 2 and a.reached >= 1 and len(a.actions) == len(a.states) - 1
    for other in (dataclasses.replace(SHORT, index=1), dataclasses.replace(SHORT, seed=1)):
        assert tour(other).states != a.states
    again = RouteSpec.from_dict(dataclasses.asdict(SHORT))
    assert again == SHORT and again.key() == SHORT.key()
    assert dataclasses.replace(SHORT, length=13.0).key() != SHORT.key()


@pytest.mark.slow
def test_a_route_through_a_building_goes_somewhere_and_a_plans_route_keeps_its_key():
    """building > 0: a long building crossed from its first end with every goal ahead, so a 100 m
    segment's ends lie far apart (end_to_end_ratio >= 0.5); a floor plan's route keeps its old key."""
    spec = RouteSpec(length=105.0, building=120.0, scene_scale=1.0, min_leg=3.0, max_leg=20.0)
    route = tour(spec)
    xy = route.camera_poses(0.88)[:, :2, 3]
    assert all(b[0] > a[0] for a, b in zip(route.goals, route.goals[1:]))  # each goal ahead of the last
    assert xy[-1, 0] - xy[0, 0] > 60 and kitti_style.end_to_end_ratio(xy.tolist()) >= 0.5
    assert dataclasses.replace(spec, building=0.0).key() == dataclasses.replace(spec, building=0.0).key() != spec.key()
    for bad in ({"building": 10.0}, {"length": 300.0}):  # too short for a route's legs, or for its length
        with pytest.raises(ValueError, match=r"building: expected 0 \(a floor plan\) or a length in \[20, 2000\] m"):
            dataclasses.replace(spec, **bad)
    # the frames are rendered in the building the route crossed (noiseless depth: no noise stream to follow)
    from odolab.sim.environment import Sensors
    from odolab.sim.routes import route_scene

    small = dataclasses.replace(spec, camera=CameraSpec(width=32, height=18))
    frames = RouteFrames(small, tour(small))
    _, _, rgb_rng, depth_rng = small.streams()
    sensors = Sensors(
        route_scene(small, frames.route.scene_seed),
        small.camera,
        small.noise.rgb,
        small.noise.depth,
        rgb_rng,
        depth_rng,
    )
    last = len(frames) - 1  # far along the building, where no floor plan of its seed reaches
    assert np.array_equal(frames[last].clean_depth, sensors.read(frames.gt_pose(last)).clean_depth)
    # a loop folds back: its 100 m segments' ends lie close together
    loop = [[10 * np.cos(t), 10 * np.sin(t)] for t in np.linspace(0, 4 * np.pi, 400)]
    assert kitti_style.end_to_end_ratio(loop) < 0.3 and math.isnan(kitti_style.end_to_end_ratio(loop[:100]))


def test_route_frames_are_rendered_in_order_and_again_from_the_start():
    route = tour(SHORT)
    frames = RouteFrames(SHORT, route)
    assert len(frames) == len(route.states) and frames.name == "test-s0-r000"
    third, first = frames[3], frames[0]  # backwards: rendered again from the first frame
    assert np.array_equal(frames[3].rgb, third.rgb) and np.array_equal(frames[3].depth, third.depth)
    fresh = RouteFrames(SHORT, route)
    assert np.array_equal(fresh[0].rgb, first.rgb) and np.array_equal(fresh[3].depth, third.depth)
    assert third.timestamp == 3.0 and np.array_equal(third.gt_pose, frames.gt_pose(3))
    assert frames.action(0) == route.actions[0] and frames.collisions.shape == (len(route.actions),)
    with pytest.raises(IndexError):
        frames[len(frames)]


def _digest(scene) -> str:
    h = hashlib.sha256()
    for a in (scene.vertices, scene.triangles, scene.triangle_material, scene.free, scene.navigable):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


def test_the_default_scenes_are_those_before_the_scale():
    # digests of the scenes generate_scene made before it had a scale (the episode cache and reports hold them)
    assert _digest(generate_scene(scene_seed("test", 0))) == "892d7fbd5633d5aa"
    assert _digest(generate_scene(scene_seed("train", 1), scale=1.0)) == "2691cc1606958ba6"
    small, large = generate_scene(scene_seed("test", 1)), generate_scene(scene_seed("test", 1), scale=2.5)
    assert large.scale == 2.5 and large.free.size > 5 * small.free.size and len(large.triangles) > len(small.triangles)
    with pytest.raises(ValueError, match=r"scale: expected a number in \[1, 10\], got 0.5"):
        generate_scene(1, scale=0.5)


def test_a_bad_scale_value_names_the_file_and_field(tmp_path: Path):
    text = (framework.HERE / "kitti_style.toml").read_text().replace("max_leg = 20.0", "max_leg = 2.0", 1)
    (tmp_path / "kitti_style.toml").write_text(text)
    config = framework.load_study("kitti_style", tmp_path)
    said = r"kitti_style.toml: scales.ci: max_leg: expected .* above min_leg \(3\), got 2.0"
    with pytest.raises(ValueError, match=said):
        framework.scale_params(config, "ci", kitti_style.Scale)
    for scale in framework.SCALES:  # the shipped definition is valid at every scale
        framework.scale_params(framework.load_study("kitti_style"), scale, kitti_style.Scale)


@pytest.fixture(scope="module")
def ci_run(tmp_path_factory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("kitti") / "out"
    assert study("kitti-style", ["--scale", "ci", "--out", str(out), "--serial", "--quiet"]) == 0
    return out, (out / "table.csv").read_text()


def _route(out: Path) -> Path:
    (folder,) = (out / "trajectories").iterdir()
    return folder


@pytest.mark.slow
def test_the_ci_scale_reports_kitti_errors_of_every_odometer(ci_run):
    out, table = ci_run
    assert {"index.html", "table.csv", "table.md", "kitti-errors.png", "manifest.txt", "results"} <= {
        p.name for p in out.iterdir()
    }
    assert len(list(out.glob("route-*.png"))) == CI["routes"] == len(list((out / "trajectories").iterdir()))
    rows = list(csv.DictReader(table.splitlines()))
    assert [r["odometer"] for r in rows if r["route"] == "all"] == CI["odometers"]
    for r in rows:
        for column in ("t_rel", "r_rel", "t_rel_100m", "ate_m", "ate_se3_m", "drift_per_100m", "dz"):
            assert math.isfinite(float(r[column])) and float(r[column]) >= 0, (r["odometer"], column)
        assert float(r["length_m"]) >= CI["length"] and int(r["segments"]) >= 1
        for c in ("dx", "dz", "dyaw"):  # the bias is signed, and never larger than the absolute error
            assert abs(float(r[f"{c}_bias"])) <= float(r[c]) + 1e-9, (r["odometer"], c)
    names = {p.name for p in _route(out).iterdir()}
    assert names == {f"{n}.{f}" for n in ["groundtruth", *CI["odometers"]] for f in ("tum", "kitti")}
    html = (out / "index.html").read_text()
    assert "has no KITTI-style table" in html and "Segment lengths held (m): 100," in html
    for r in rows:  # the ci route crosses a 120 m building: its 100 m segments' ends lie far apart
        assert float(r["end_to_end_ratio"]) >= 0.5, r["odometer"]
    pooled = [r for r in rows if r["route"] == "all"]
    assert all(r["t_rel_ci"] == "" for r in pooled)  # one route: no interval over routes
    assert len(list((out / "results").glob("*.json"))) == CI["routes"] * (1 + len(CI["odometers"]))


@pytest.mark.slow
def test_a_second_run_reuses_every_saved_unit(ci_run, capsys):
    out, table = ci_run
    files = {p: p.stat().st_mtime_ns for p in (out / "trajectories").rglob("*.*")}
    assert study("kitti-style", ["--scale", "ci", "--out", str(out), "--serial", "--quiet"]) == 0
    assert "0 units computed" in capsys.readouterr().out
    assert {p: p.stat().st_mtime_ns for p in (out / "trajectories").rglob("*.*")} == files
    assert (out / "table.csv").read_text() == table


@pytest.mark.slow
def test_a_missing_trajectory_file_computes_its_unit_again(ci_run, capsys):
    out, table = ci_run
    lost = _route(out) / "action-prior.tum"
    text = lost.read_text()
    lost.unlink()
    assert study("kitti-style", ["--scale", "ci", "--out", str(out), "--serial", "--quiet"]) == 0
    assert "1 unit computed" in capsys.readouterr().out
    assert lost.read_text() == text and (out / "table.csv").read_text() == table


@pytest.mark.slow
def test_redraw_needs_only_the_saved_results(ci_run, tmp_path: Path, capsys):
    out, table = ci_run
    copy = tmp_path / "copy"
    shutil.copytree(out / "results", copy / "results")
    shutil.copy(out / "manifest.txt", copy / "manifest.txt")  # no trajectory files
    assert study("kitti-style", ["--scale", "ci", "--out", str(copy), "--redraw", "--quiet"]) == 0
    assert "0 units computed" in capsys.readouterr().out
    assert (copy / "table.csv").read_text() == table and (copy / "kitti-errors.png").is_file()
    assert len(list(copy.glob("route-*.png"))) == CI["routes"]


def _evaluate(capsys, gt: Path, est: Path, *extra: str) -> dict:
    assert evaluate.main([str(gt), str(est), "--json", *extra]) == 0
    return json.loads(capsys.readouterr().out)["estimates"][0]


def _devkit(ref, est) -> tuple[float, float]:
    """KITTI's devkit rule (segments of 100..800 m from every 10th frame) on evo's poses and path length."""
    dist = ref.distances
    t, r = [], []
    for first in range(0, ref.num_poses, 10):
        for length in KITTI_LENGTHS:
            last = next((i for i in range(first, ref.num_poses) if dist[i] > dist[first] + length), None)
            if last is None:
                continue
            dg = lie.relative_se3(ref.poses_se3[first], ref.poses_se3[last])
            dp = lie.relative_se3(est.poses_se3[first], est.poses_se3[last])
            E = lie.relative_se3(dp, dg)
            t.append(np.linalg.norm(E[:3, 3]) / length)
            r.append(lie.so3_log_angle(E[:3, :3]) / length)
    return 100 * float(np.mean(t)), float(np.degrees(np.mean(r))) * 100


def _evo_ape(ref, est) -> float:
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    return ape.get_statistic(metrics.StatisticsType.rmse)


@pytest.mark.slow
def test_evaluate_scores_a_written_pair_as_evo_does(ci_run, capsys):
    out, table = ci_run
    folder = _route(out)
    row = next(r for r in csv.DictReader(table.splitlines()) if r["odometer"] == "icp" and r["route"] != "all")
    kitti = _evaluate(capsys, folder / "groundtruth.kitti", folder / "icp.kitti", "--align", "none")
    ref, est = (file_interface.read_kitti_poses_file(folder / f) for f in ("groundtruth.kitti", "icp.kitti"))
    t_rel, r_rel = _devkit(ref, est)
    assert kitti["t_rel"] == pytest.approx(t_rel, rel=1e-9) and kitti["r_rel"] == pytest.approx(r_rel, rel=1e-6)
    assert kitti["ate"] == pytest.approx(_evo_ape(ref, est), rel=1e-9)
    assert (kitti["t_rel"], kitti["r_rel"], kitti["ate"]) == pytest.approx(
        (float(row["t_rel"]), float(row["r_rel"]), float(row["ate_m"])), rel=1e-9
    )
    tum = _evaluate(capsys, folder / "groundtruth.tum", folder / "icp.tum")  # aligned (SE(3)), by timestamp
    ref, est = sync.associate_trajectories(
        *(file_interface.read_tum_trajectory_file(folder / f) for f in ("groundtruth.tum", "icp.tum")), max_diff=0.01
    )
    assert ref.num_poses == len(ref.positions_xyz) == int(row["steps"]) + 1
    est.align(ref)
    assert tum["ate"] == pytest.approx(_evo_ape(ref, est), rel=1e-9)
    assert tum["ate"] == pytest.approx(float(row["ate_se3_m"]), rel=1e-6)
    assert tum["t_rel"] == pytest.approx(kitti["t_rel"], rel=1e-6)
