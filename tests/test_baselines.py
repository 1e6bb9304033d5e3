"""The classical odometers of ``baselines/`` on real TUM frames and on views with known motion; open3d-rgbd's
out-of-range options in one line and its settings' digest; baselines.measure_tum's rows."""

from __future__ import annotations

import dataclasses
import inspect
import itertools
from pathlib import Path

import numpy as np
import pytest

from baselines.covariance import point_to_point_covariance
from baselines.depth_geometry import DepthRange, normal_constraint
from baselines.measure_tum import relative_pose_error
from baselines.motion_search import planar_search
from baselines.pose_solvers import planar_procrustes, pnp, translation_given_rotation
from baselines.verification import VerifyConfig, first_verified
from odolab.api import (
    Action,
    Frame,
    Intrinsics,
    describe,
    invert,
    load_odometer,
    load_tum_sequence,
    planar_to_transform,
    transform_to_planar,
)
from odolab.core.parallel import SERIAL
from tests.helpers import refused_option

TUM = Path(__file__).parent / "data" / "tum_fr1_xyz_10"
ODOMETERS = ["feature-essential", "icp", "open3d-rgbd"]
#: Odometers for a ground robot: the synthetic views below move in the plane, so they apply too.
PLANAR_ODOMETERS = ["planar-depth"]
#: docs/reference-facts.md section 6: Open3D's hybrid RGB-D odometry scores 4.43 mm here; the issue's bound is 2x.
MAX_MEAN_TRANSLATION_MM = 8.8
MAX_MEAN_ROTATION_DEG = 0.5


@pytest.fixture(scope="module")
def tum() -> tuple[list[Frame], Intrinsics]:
    seq = load_tum_sequence(TUM)
    return [seq[i] for i in range(len(seq))], seq.intrinsics


def render_view(frame: Frame, intr: Intrinsics, T_prev_cur: np.ndarray) -> Frame:
    """What a camera at ``T_prev_cur`` sees of ``frame``'s coloured point cloud (z-buffered).

    Each point is splatted on 2x2 pixels so that a forward motion leaves no cracks; pixels
    nothing lands on get depth 0 and black colour. ``gt_pose`` moves along.
    """
    h, w = frame.depth.shape
    v, u = np.nonzero(frame.depth > 0)
    z = frame.depth[v, u].astype(np.float64)
    X = np.stack([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z], axis=1)
    T = invert(T_prev_cur)
    Y = X @ T[:3, :3].T + T[:3, 3]
    colour = frame.rgb[v, u]
    front = Y[:, 2] > 0.05
    Y, colour = Y[front], colour[front]
    pu = np.floor(intr.fx * Y[:, 0] / Y[:, 2] + intr.cx).astype(int)
    pv = np.floor(intr.fy * Y[:, 1] / Y[:, 2] + intr.cy).astype(int)
    depth = np.full(h * w, np.inf)
    rgb = np.zeros((h * w, 3), np.uint8)
    far_first = np.argsort(-Y[:, 2])
    for du in (0, 1):
        for dv in (0, 1):
            x, y = pu[far_first] + du, pv[far_first] + dv
            inside = (x >= 0) & (x < w) & (y >= 0) & (y < h)
            idx, src = y[inside] * w + x[inside], far_first[inside]
            cand = np.full(h * w, np.inf)
            who = np.zeros(h * w, dtype=int)
            cand[idx], who[idx] = Y[src, 2], src  # later (nearer) writes win
            nearer = cand < depth
            depth[nearer], rgb[nearer] = cand[nearer], colour[who[nearer]]
    depth[~np.isfinite(depth)] = 0.0
    return dataclasses.replace(
        frame,
        rgb=rgb.reshape(h, w, 3),
        depth=depth.reshape(h, w).astype(np.float32),
        gt_pose=frame.gt_pose @ T_prev_cur,
    )


def run_pairs(name: str, frames: list[Frame], intr: Intrinsics) -> np.ndarray:
    """(N, 2): translation (mm) and rotation (deg) error of each consecutive pair."""
    odo = load_odometer(name)
    odo.reset(intr)
    errors = []
    for prev, cur in itertools.pairwise(frames):
        est = odo.step(prev, cur, None)
        assert est.valid
        assert est.transform.shape == (4, 4)
        t, r = relative_pose_error(est.transform, invert(prev.gt_pose) @ cur.gt_pose)
        errors.append((1000.0 * t, np.degrees(r)))
    return np.array(errors)


@pytest.mark.slow
@pytest.mark.parametrize("name", ODOMETERS)
def test_accuracy_on_real_tum_frames(name, tum):
    frames, intr = tum
    errors = run_pairs(name, frames, intr)
    t_mm, r_deg = errors.mean(axis=0)
    print(f"{name}: mean translation error {t_mm:.2f} mm, rotation error {r_deg:.3f} deg")
    assert t_mm < MAX_MEAN_TRANSLATION_MM
    assert r_deg < MAX_MEAN_ROTATION_DEG


def test_oracle_rotation_uses_ground_truth(tum):
    frames, intr = tum
    errors = run_pairs("feature-essential-oracle-rot", frames[:4], intr)
    assert errors[:, 1].max() < 1e-3
    assert errors[:, 0].mean() < MAX_MEAN_TRANSLATION_MM


def test_oracle_rotation_without_ground_truth_raises(tum):
    frames, intr = tum
    odo = load_odometer("feature-essential-oracle-rot")
    assert odo.oracle and not load_odometer("feature-essential").oracle
    odo.reset(intr)
    with pytest.raises(ValueError, match="ground-truth"):
        odo.step(frames[0], dataclasses.replace(frames[1], gt_pose=None), None)


KNOWN_MOTIONS = [
    pytest.param(Action.MOVE_FORWARD, planar_to_transform(0.03, 0.25, np.radians(4.0)), id="forward"),
    pytest.param(Action.TURN_LEFT, planar_to_transform(0.01, 0.0, np.radians(30.0)), id="turn_left_30"),
    pytest.param(Action.TURN_RIGHT, planar_to_transform(0.0, -0.01, np.radians(-33.0)), id="turn_right_33"),
    pytest.param(None, planar_to_transform(-0.02, 0.03, np.radians(-3.0)), id="small_no_action"),
]


@pytest.fixture(scope="module")
def known_views(tum):
    frames, intr = tum
    return {id(T): render_view(frames[0], intr, T) for _, T in (p.values for p in KNOWN_MOTIONS)}


@pytest.mark.slow
@pytest.mark.parametrize("name", ODOMETERS + PLANAR_ODOMETERS)
@pytest.mark.parametrize("action,T_true", KNOWN_MOTIONS)
def test_convention_on_views_with_known_motion(name, action, T_true, tum, known_views):
    """T_prev_cur, camera axes, turn signs: a synthetic view of frame 0 from a known pose."""
    frames, intr = tum
    odo = load_odometer(name)
    odo.reset(intr)
    est = odo.step(frames[0], known_views[id(T_true)], action)
    if name in PLANAR_ODOMETERS and action is None:
        assert odo.needs_action and not est.valid  # no action: no prior, and hand-held data need not be planar
        return
    assert est.valid
    t, r = relative_pose_error(est.transform, T_true)
    assert t < 0.01 and np.degrees(r) < 0.5, (t, np.degrees(r), est.planar)
    assert np.sign(est.planar[2]) == np.sign(T_true_yaw := np.arctan2(-T_true[0, 2], T_true[2, 2]))
    assert abs(est.planar[2] - T_true_yaw) < np.radians(0.5)
    assert est.covariance is not None  # every classical odometer reports one
    assert est.covariance.shape == (6, 6)
    assert np.allclose(est.covariance, est.covariance.T)
    assert np.all(np.linalg.eigvalsh(est.covariance) > 0)


def test_open3d_fallback_schedule_runs_only_when_the_first_finds_nothing(tum, known_views):
    """One iteration from no motion cannot find a 3-degree view; the fallback schedule then does,
    and an answer the first schedule finds is the fallback's business no longer."""
    frames, intr = tum
    T_true = KNOWN_MOTIONS[3].values[1]
    view = known_views[id(T_true)]
    results = {}
    for fallback in [(), (20, 5)]:
        odo = load_odometer("open3d-rgbd", iterations=[1], fallback_iterations=list(fallback))
        odo.reset(intr)
        results[fallback] = odo.step(frames[0], view, None)
    assert not results[()].valid
    assert results[(20, 5)].valid and relative_pose_error(results[(20, 5)].transform, T_true)[0] < 0.002
    calls = []
    odo = load_odometer("open3d-rgbd", fallback_iterations=[1])
    align = odo._align
    odo._align = lambda *a: calls.append(a[-1]) or align(*a)
    odo.reset(intr)
    assert odo.step(frames[0], view, None).valid and set(calls) == {(20, 5)}


@pytest.mark.parametrize(
    "T_true,path",
    [
        pytest.param(planar_to_transform(0.03, 0.25, np.radians(4.0)), "essential", id="forward_0.25m"),
        pytest.param(planar_to_transform(0.01, 0.0, np.radians(30.0)), "pnp", id="turn_in_place"),
    ],
)
def test_feature_essential_uses_the_essential_matrix_only_with_parallax(T_true, path, tum, known_views):
    frames, intr = tum
    odo = load_odometer("feature-essential")
    odo.reset(intr)
    view = known_views.get(id(T_true)) or render_view(frames[0], intr, T_true)
    est = odo.step(frames[0], view, None)
    assert est.valid and odo.last_path == path
    assert relative_pose_error(est.transform, T_true)[0] < 0.01
    odo.step(frames[0], frames[1], None)
    assert odo.last_path == "pnp"  # ~1.5 cm baseline at 1-2 m


def degenerate_frames(frame: Frame) -> dict[str, tuple[Frame, Frame]]:
    """Pairs no odometer can estimate from."""
    no_depth = dataclasses.replace(frame, depth=np.zeros_like(frame.depth))
    blank = dataclasses.replace(frame, rgb=np.full_like(frame.rgb, 128), depth=np.full_like(frame.depth, 2.0))
    far = dataclasses.replace(frame, depth=np.full_like(frame.depth, 9.0))  # all beyond max_depth
    nan_depth = dataclasses.replace(frame, depth=np.full_like(frame.depth, np.nan))
    return {
        "no depth": (frame, no_depth),
        "both without depth": (no_depth, no_depth),
        "blank wall": (blank, blank),
        "all depth beyond range": (far, frame),
        "NaN depth": (frame, nan_depth),
    }


@pytest.mark.parametrize("name", [*ODOMETERS, "feature-essential-oracle-rot"])
def test_degenerate_frames_are_invalid_not_errors(name, tum):
    frames, intr = tum
    odo = load_odometer(name)
    odo.reset(intr)
    for what, (prev, cur) in degenerate_frames(frames[0]).items():
        for action in (None, Action.MOVE_FORWARD):
            est = odo.step(prev, cur, action)
            assert not est.valid, f"{name} accepted {what}"
            assert np.all(np.isfinite(est.transform))


@pytest.mark.parametrize("name", ["icp", "open3d-rgbd"])
def test_unrelated_view_is_invalid(name, tum):
    """Open3D reports success on frames that do not overlap (docs/reference-facts.md section 8); we do not."""
    frames, intr = tum
    odo = load_odometer(name)
    odo.reset(intr)
    flipped = dataclasses.replace(
        frames[0], rgb=frames[0].rgb[::-1, ::-1].copy(), depth=frames[0].depth[::-1, ::-1].copy()
    )
    assert not odo.step(frames[0], flipped, None).valid


def test_a_failed_turn_from_the_wrong_prior_is_invalid(tum):
    """Told 'turn left' for a right turn of 30 degrees, ICP cannot converge and must say so."""
    frames, intr = tum
    odo = load_odometer("icp")
    odo.reset(intr)
    view = render_view(frames[0], intr, planar_to_transform(0.0, 0.0, np.radians(-30.0)))
    assert not odo.step(frames[0], view, Action.TURN_LEFT).valid


def test_options_are_checked():
    with pytest.raises(ValueError, match="variant"):
        load_odometer("icp", variant="spline")
    with pytest.raises(ValueError, match="term"):
        load_odometer("open3d-rgbd", term="magic")
    with pytest.raises(ValueError, match="max_depth"):
        load_odometer("feature-essential", max_depth=0.05)
    with pytest.raises(TypeError, match="'voxels'"):
        load_odometer("icp", voxels=0.05)
    with pytest.raises(TypeError, match="'min_ncc'"):  # no verification, so nothing to set there
        load_odometer("feature-essential", verify=None, min_ncc=0.9)
    with pytest.raises(TypeError, match="voxel must be float, got 'big'"):
        load_odometer("icp", voxel="big")
    with pytest.raises(TypeError, match="min_inliers must be int, got True"):
        load_odometer("feature-essential", min_inliers=True)
    assert load_odometer("feature-essential", n_features=None, max_depth=3).config.depth.max_depth == 3


def test_a_depth_range_says_what_each_field_takes():
    """Its ranges come from the fields, for errors and :func:`odolab.api.describe` alike; the two
    depths together are checked after them."""
    assert [(r.name, r.range) for r in describe(DepthRange)] == [
        ("min_depth", "[0, 1000)"),
        ("max_depth", "(0, 1000]"),
        ("noise_floor", "[0, 1]"),
        ("noise_growth", "[0, 1]"),
    ]
    assert all(r.doc for r in describe(DepthRange()))
    for bad, said in (
        ({"max_depth": float("inf")}, "max_depth must be in (0, 1000], got inf"),
        ({"min_depth": -0.5}, "min_depth must be in [0, 1000), got -0.5"),
        ({"noise_growth": "x"}, "noise_growth must be a number in [0, 1], got 'x'"),
        ({"noise_floor": 2}, "noise_floor must be in [0, 1], got 2"),
        ({"min_depth": 4, "max_depth": 4}, "need min_depth < max_depth, got min_depth 4, max_depth 4"),
    ):
        with pytest.raises(ValueError) as info:
            DepthRange(**bad)
        assert str(info.value) == said
    assert dataclasses.asdict(DepthRange(max_depth=6.0)) == {
        "min_depth": 0.1,
        "max_depth": 6.0,
        "noise_floor": 0.01,
        "noise_growth": 0.01,
    }


@pytest.mark.parametrize("name", [*ODOMETERS, "feature-essential-oracle-rot"])
def test_config_is_a_frozen_dataclass_with_nested_keyword_overrides(name):
    default = load_odometer(name).config
    odo = load_odometer(name, max_depth=3.0, min_ncc=0.9, max_height=0.05)
    cfg = odo.config
    assert (cfg.depth.max_depth, cfg.verify.min_ncc, cfg.verify.bounds.max_height) == (3.0, 0.9, 0.05)
    assert dataclasses.replace(cfg, depth=default.depth, verify=default.verify) == default  # nothing else moved
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.depth = None
    written = dataclasses.asdict(cfg)
    assert written["depth"]["max_depth"] == 3.0 and written["verify"]["bounds"]["max_height"] == 0.05
    assert type(load_odometer(name, config=cfg).config) is type(cfg)
    options = inspect.signature(type(odo)).parameters  # what option checkers (and help) see
    assert options["max_depth"].default == default.depth.max_depth and options["max_depth"].annotation == "float"
    assert set(options) == {"config", *(f.name for f in _all_fields(default))}


def _all_fields(config):
    for f in dataclasses.fields(config):
        yield f
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value):
            yield from _all_fields(value)


@pytest.mark.parametrize("name", ODOMETERS)
def test_the_config_reaches_the_odometer(name, tum):
    """The first TUM pair (depth 0.9-3.7 m) is solved by default, and invalid with a 0.5 m depth cut."""
    frames, intr = tum
    results = []
    for options in ({}, {"max_depth": 0.5}):
        odo = load_odometer(name, **options)
        odo.reset(intr)
        results.append(odo.step(frames[0], frames[1], None).valid)
    assert results == [True, False]


def test_first_verified_returns_the_first_guess_the_images_confirm(tum):
    frames, intr = tum
    T_true = planar_to_transform(0.02, 0.05, np.radians(3.0))
    view = render_view(frames[0], intr, T_true)
    wrong = planar_to_transform(0.0, 0.0, np.radians(-20.0))
    tried = []

    def register(T):  # a solver that stays where it starts
        tried.append(len(tried))
        return T, len(tried) - 1

    found = first_verified([wrong, T_true, wrong], register, frames[0], view, None, intr, DepthRange(), VerifyConfig())
    assert found is not None and found.detail == 1 and tried == [0, 1]
    assert found.check.depth.fraction > 0.8 and found.check.ncc > 0.85
    refined = []
    assert first_verified([wrong], register, frames[0], view, None, intr, DepthRange(), VerifyConfig(), refined) is None
    assert len(refined) == 1 and np.array_equal(refined[0], wrong)  # what a refusing odometer keeps as unverified


@pytest.mark.parametrize("name", ["icp", "open3d-rgbd", "feature-essential"])
def test_a_refused_step_keeps_the_motion_it_computed_as_unverified(name, tum):
    """A checker no motion can pass (every depth point must land in view and agree, NCC 1): each
    classical odometer refuses the pair but keeps its unverified estimate, close to the truth, for the
    paper's protocol."""
    frames, intr = tum
    T_true = planar_to_transform(0.02, 0.05, np.radians(3.0))
    view = render_view(frames[0], intr, T_true)
    strict = VerifyConfig(min_points_in_view=10**9, min_agreement=1.0, min_ncc=1.0)
    odo = load_odometer(name, verify=strict)
    odo.reset(intr)
    est = odo.step(frames[0], view, None)
    assert not est.valid and est.unverified is not None
    assert np.abs(transform_to_planar(est.unverified) - transform_to_planar(T_true)).max() < 0.03


def test_pose_solvers_recover_a_known_motion(tum):
    """PnP, translation given the rotation, and the planar fit on exact synthetic correspondences."""
    _, intr = tum
    rng = np.random.default_rng(1)
    T = planar_to_transform(0.1, 0.2, np.radians(10.0))
    X_cur = rng.uniform([-1.0, -0.5, 1.0], [1.0, 0.5, 3.0], (60, 3))
    P_prev = X_cur @ T[:3, :3].T + T[:3, 3]
    uv_prev = P_prev @ intr.matrix.T
    uv_prev = uv_prev[:, :2] / uv_prev[:, 2:]
    T_pnp, inl = pnp(X_cur, uv_prev, intr.matrix, px=1.0, iterations=100)
    assert inl.all() and np.allclose(T_pnp, T, atol=1e-6)
    T_t, inl = translation_given_rotation(X_cur, uv_prev, T[:3, :3], intr, px=1.0)
    assert inl.all() and np.allclose(T_t, T, atol=1e-9)
    outliers = P_prev.copy()
    outliers[:5] += 0.5
    planar = planar_procrustes(outliers, X_cur, T)
    assert np.allclose(planar, transform_to_planar(T), atol=1e-9)


def test_normal_constraint_flags_a_plane_and_accepts_a_room(tum):
    frames, intr = tum
    rng = DepthRange()
    assert normal_constraint(np.full((480, 640), 2.0, np.float32), intr, rng) < 1e-6
    assert normal_constraint(frames[0].depth, intr, rng) > 0.05


@pytest.mark.parametrize("action,T_true", KNOWN_MOTIONS[:3])
def test_planar_search_lands_near_the_true_motion(action, T_true, tum, known_views):
    """The dense solvers' start: within 2 degrees and 6 cm of the truth (their convergence basin)."""
    frames, intr = tum
    best = planar_search(frames[0], known_views[id(T_true)], action, intr, DepthRange())[0]
    err = np.abs(transform_to_planar(best) - transform_to_planar(T_true))
    assert err[2] < np.radians(2.0) and max(err[0], err[1]) < 0.06, err


def test_point_to_point_covariance_matches_open3d_information():
    """Same ordering (rx, ry, rz, tx, ty, tz) and frame as Open3D's information matrix."""
    import open3d as o3d

    rng = np.random.default_rng(0)
    points = rng.uniform(-1, 1, (500, 3)) + [0, 0, 3]
    residuals = rng.normal(size=(500, 3))
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    info = o3d.pipelines.registration.get_information_matrix_from_point_clouds(cloud, cloud, 0.01, np.eye(4))
    sigma2 = (residuals**2).sum() / (3 * 500 - 6)
    assert np.allclose(np.linalg.inv(point_to_point_covariance(points, residuals)) * sigma2, info)


@pytest.fixture(scope="module")
def short_sim_episodes():
    """Four 25-step validation episodes at the challenge's 341 x 192 (about 1.5 s to render)."""
    from odolab.sim.episodes import EpisodeSpec, load_episodes

    specs = [EpisodeSpec(split="val", index=i, max_steps=25) for i in (2, 4, 5, 6)]
    return load_episodes(specs, execution=SERIAL)


@pytest.mark.slow
@pytest.mark.parametrize("name", ODOMETERS)
def test_beats_the_action_prior_on_the_simulator(name, short_sim_episodes):
    """Pooled per-step error (failed steps replaced by the prior and scored) below 0.8 x the prior's
    on each of dx, dz, dyaw (measured: ratios 0.25-0.7)."""
    from odolab.running import runner, summary

    rows = summary.summarize(
        runner.run(
            {"action-prior": load_odometer("action-prior"), name: load_odometer(name)},
            short_sim_episodes,
        )
    )
    prior, odo = (np.array([r.dx, r.dz, r.dyaw]) for r in rows)
    assert np.all(odo < 0.8 * prior), (name, odo, prior)


def test_measure_tum_runs_reference_rows_and_names_an_unknown_odometer(capsys):
    from odolab.cli.measure_tum import command as measure_main

    assert measure_main([str(TUM), "--odometers", "ground-truth", "action-prior", "no-motion", "--repeat", "1"]) == 0
    out = capsys.readouterr().out
    rows = {
        line.split("|")[1].strip(): line.split("|")[2].strip() for line in out.splitlines() if line.startswith("| ")
    }
    assert rows["ground-truth"] == "0.00" and float(rows["no-motion"]) > 5 and rows["action-prior"] == rows["no-motion"]
    assert measure_main([str(TUM), "--odometers", "nope"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown odometer 'nope'" in err[0]


@pytest.mark.parametrize(
    "value",
    ["[]", "[0]", "[1000000]", '"123"', "[1.5]", "[true]", "[2147483648]", "[5,5,5,5,5,5,5,5]", "20", "[[20,5]]"],
)
def test_open3d_iterations_out_of_range_are_one_line(tmp_path, value):
    """0 iterations would quietly return the starting guess, a million would never end, 8 pyramid
    levels leave a 2 x 1 pixel image, a string would be read digit by digit."""
    refused_option(
        tmp_path,
        "open3d-rgbd",
        f"open3d-rgbd.iterations={value}",
        words="iterations: expected a list of 1-6 whole numbers",
    )


@pytest.mark.parametrize("value", ["[0]", "[1000000]", '"123"', "[5,5,5,5,5,5,5]"])
def test_open3d_fallback_iterations_out_of_range_are_one_line(tmp_path, value):
    """The fallback schedule is checked as the first one is (but may be empty: no fallback)."""
    refused_option(
        tmp_path,
        "open3d-rgbd",
        f"open3d-rgbd.fallback_iterations={value}",
        words="fallback_iterations: expected a list of 0-6 whole numbers",
    )


@pytest.mark.parametrize(
    "option,value,words",
    [
        ("fallback_iterations", "[" * 3000 + "]" * 3000, "open3d-rgbd.fallback_iterations: value nested too deeply"),
        ("max_depth", "inf", "max_depth must be in (0, 1000], got inf"),
        ("max_depth", "1e300", "max_depth must be in (0, 1000], got 1e+300"),
    ],
)
def test_open3d_depth_and_nesting_are_one_line(tmp_path, option, value, words):
    """A depth cut of infinity ran (and wrote Infinity into navigate's JSON); [[[...]]] 3000 deep
    was a RecursionError traceback."""
    refused_option(tmp_path, "open3d-rgbd", f"open3d-rgbd.{option}={value}", words=words)


def test_equal_settings_give_equal_digests():
    """6 and 6.0 set the same depth cut: a rerun with either reuses the other's episodes."""
    from odolab.odometry.odometer import load_odometer

    assert load_odometer("open3d-rgbd", max_depth=6).identity_digest == load_odometer("open3d-rgbd").identity_digest
    assert load_odometer("open3d-rgbd", max_depth=5).identity_digest != load_odometer("open3d-rgbd").identity_digest
