"""Trajectory metrics: cross-checked against evo's Python API, the KITTI devkit rules and the
reference figures of evo's shipped test data (tests/data/evo/README.md); errors near 1e300 m give
finite statistics."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from evo.core import metrics as evo_metrics
from evo.core.geometry import umeyama_alignment as evo_umeyama
from evo.core.trajectory import PosePath3D
from evo.core.units import Unit

from odolab.core import metrics
from odolab.core import metrics as M
from odolab.core.geometry import integrate, rotation_angle
from odolab.io.kitti import read_kitti_poses
from odolab.io.tum import associate, quaternion_to_matrix, read_tum_trajectory

DATA = Path(__file__).parent / "data" / "evo"


# ----------------------------------------------------------------------------- generated data


def rot(axis: str, a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def se3(R: np.ndarray, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def make_pair(
    seed: int, n: int = 300, step: float = 0.5, scale: float = 1.0, noise: float = 0.01, yaw_drift: float = 0.002
) -> tuple[np.ndarray, np.ndarray]:
    """A ground-truth path that turns through +-180 deg many times, and an estimate of it with
    per-step noise, yaw drift, a scale factor and an arbitrary starting frame."""
    rng = np.random.default_rng(seed)
    yaw = rng.normal(0.35, 0.3, n - 1)  # about 20 deg per step: many half turns
    rel_gt = np.array(
        [
            se3(rot("z", y) @ rot("x", rng.normal(0, 0.05)), [step, rng.normal(0, 0.05), rng.normal(0, 0.05)])
            for y in yaw
        ]
    )
    gt = integrate(rel_gt, start=se3(rot("y", 0.3), [1.0, -2.0, 0.5]))
    rel_est = np.array(
        [
            T
            @ se3(rot("z", yaw_drift + rng.normal(0, noise)) @ rot("x", rng.normal(0, noise)), rng.normal(0, noise, 3))
            for T in rel_gt
        ]
    )
    rel_est[:, :3, 3] *= scale
    est = integrate(rel_est, start=se3(rot("x", 2.0) @ rot("z", -2.5), [5.0, 1.0, -3.0]))
    return gt, est


def evo_path(poses: np.ndarray) -> PosePath3D:
    return PosePath3D(poses_se3=list(np.array(poses)))


def evo_ape(gt, est, align: str) -> tuple[float, np.ndarray, float]:
    ref, e = evo_path(gt), evo_path(est)
    s = 1.0
    if align != "none":
        _, _, s = e.align(ref, correct_scale=(align == "sim3"))
    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((ref, e))
    return ape.get_statistic(evo_metrics.StatisticsType.rmse), ape.error, s


def evo_rpe(gt, est, delta, unit, all_pairs=False, relation="trans_part") -> tuple[np.ndarray, list[int]]:
    pr = {
        "trans_part": evo_metrics.PoseRelation.translation_part,
        "angle_deg": evo_metrics.PoseRelation.rotation_angle_deg,
    }[relation]
    r = evo_metrics.RPE(pr, delta, {"f": Unit.frames, "m": Unit.meters}[unit], 0.1, all_pairs)
    r.process_data((evo_path(gt), evo_path(est)))
    return r.error, r.delta_ids


# ----------------------------------------------------------------------------- building blocks


def test_per_step_abs_error_unchanged():
    e = M.per_step_abs_error(np.array([[0.1, 0.2, 3.1]]), np.array([[0.0, 0.25, -3.1]]))
    np.testing.assert_allclose(e, [[0.1, 0.05, 2 * np.pi - 6.2]])


@pytest.mark.parametrize("with_scale", [False, True])
def test_umeyama_matches_evo(with_scale):
    rng = np.random.default_rng(0)
    src = rng.normal(size=(200, 3)) * [5, 2, 1]
    R_true = quaternion_to_matrix(rng.normal(size=4))[0]
    dst = 1.7 * src @ R_true.T + [1, 2, 3] + rng.normal(0, 0.05, src.shape)
    R, t, s = M.umeyama_alignment(src, dst, with_scale)
    R2, t2, s2 = evo_umeyama(src.T, dst.T, with_scale)
    np.testing.assert_allclose(R, R2, atol=1e-12)
    np.testing.assert_allclose(t, t2, atol=1e-10)
    assert s == pytest.approx(s2, rel=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_umeyama_rejects_degenerate_points():
    line = np.c_[np.arange(10.0), np.zeros((10, 2))]
    with pytest.raises(ValueError, match="degenerate"):
        M.umeyama_alignment(line, line + 1, False)


def test_rotation_angle_small_and_half_turn():
    for a in (0.0, 1e-9, 1e-5, 0.3, np.pi / 2, np.pi - 1e-7, np.pi):
        R = quaternion_to_matrix(np.array([np.sin(a / 2) * 0.6, np.sin(a / 2) * 0.8, 0.0, np.cos(a / 2)]))[0]
        assert rotation_angle(R) == pytest.approx(a, abs=1e-12, rel=1e-7)


# ----------------------------------------------------------------------------- ATE, RPE vs evo


CASES = [
    {"seed": 1},
    {"seed": 2, "noise": 0.05, "yaw_drift": 0.01},
    {"seed": 3, "scale": 0.37},
    {"seed": 4, "scale": 2.5, "noise": 0.0, "yaw_drift": 0.0},
]


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("align", M.ALIGNMENTS)
def test_ate_matches_evo(case, align):
    gt, est = make_pair(**case)
    ours = M.ate(gt, est, align)
    rmse, errors, scale = evo_ape(gt, est, align)
    assert ours.rmse == pytest.approx(rmse, rel=1e-9)
    np.testing.assert_allclose(ours.errors, errors, rtol=1e-9, atol=1e-12)
    assert ours.scale == pytest.approx(scale, rel=1e-9)
    if case.get("noise") == 0.0 and align == "sim3":  # exact similarity: perfect fit
        assert ours.rmse < 1e-9 and ours.scale == pytest.approx(1 / case["scale"])


@pytest.mark.parametrize("case", CASES[:3])
@pytest.mark.parametrize(
    "delta,unit,all_pairs", [(1, "f", False), (7, "f", False), (7, "f", True), (3.0, "m", False), (3.0, "m", True)]
)
def test_rpe_matches_evo(case, delta, unit, all_pairs):
    gt, est = make_pair(**case)
    ours = M.rpe(gt, est, delta, unit, all_pairs=all_pairs)
    trans, ids = evo_rpe(gt, est, delta, unit, all_pairs)
    rot_deg, _ = evo_rpe(gt, est, delta, unit, all_pairs, "angle_deg")
    np.testing.assert_array_equal(ours.pairs[:, 1], ids)
    np.testing.assert_allclose(ours.trans_errors, trans, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(ours.rot_errors, rot_deg, rtol=1e-7, atol=1e-9)
    assert ours.trans.rmse == pytest.approx(np.sqrt(np.mean(trans**2)), rel=1e-9)


def test_rpe_pairs_follow_evo_defaults():
    poses = np.tile(np.eye(4), (10, 1, 1))
    assert M.rpe_pairs(poses, 3).tolist() == [[0, 3], [3, 6], [6, 9]]
    assert M.rpe_pairs(poses, 3, all_pairs=True).tolist() == [[i, i + 3] for i in range(7)]
    with pytest.raises(ValueError):
        M.rpe(poses, poses, 20)


def test_relative_motion_errors_is_rpe_of_consecutive_frames():
    gt, est = make_pair(5, n=50)
    trans, rot_deg = M.relative_motion_errors(gt, est)
    r = M.rpe(gt, est, 1, "f")
    assert trans.shape == (49,)
    np.testing.assert_array_equal(trans, r.trans_errors)
    np.testing.assert_array_equal(rot_deg, r.rot_errors)


def test_rigid_alignment_leaves_relative_errors_unchanged():
    gt, est = make_pair(6)
    a = M.ate(gt, est, "se3")
    moved = M.apply_alignment(est, a.rotation, a.translation, a.scale)
    np.testing.assert_allclose(M.rpe(gt, moved).trans_errors, M.rpe(gt, est).trans_errors, atol=1e-9)
    k1, k2 = M.kitti_relative_errors(gt, moved), M.kitti_relative_errors(gt, est)
    assert k1.t_rel == pytest.approx(k2.t_rel, rel=1e-9)


# ----------------------------------------------------------------------------- KITTI devkit


def kitti_devkit_loop(gt: np.ndarray, est: np.ndarray) -> list[tuple[int, int, float, float, float]]:
    """Straight transcription of the devkit's calcSequenceErrors rules (slow, for checking)."""
    dist = [0.0]
    for i in range(1, len(gt)):
        dist.append(dist[-1] + float(np.linalg.norm(gt[i - 1, :3, 3] - gt[i, :3, 3])))
    out = []
    for first in range(0, len(gt), 10):
        for length in M.KITTI_LENGTHS:
            last = next((i for i in range(first, len(gt)) if dist[i] > dist[first] + length), -1)
            if last == -1:
                continue
            E = np.linalg.inv(np.linalg.inv(est[first]) @ est[last]) @ (np.linalg.inv(gt[first]) @ gt[last])
            r = np.arccos(max(min((np.trace(E[:3, :3]) - 1) / 2, 1.0), -1.0))
            out.append((first, last, length, np.linalg.norm(E[:3, 3]) / length, r / length))
    return out


def test_kitti_vectorised_equals_devkit_loop():
    gt, est = make_pair(7, n=400, step=4.0, noise=0.005)  # ~1.6 km
    ours = M.kitti_relative_errors(gt, est)
    ref = kitti_devkit_loop(gt, est)
    assert ours.n_segments == len(ref) > 100
    np.testing.assert_array_equal(ours.first, [r[0] for r in ref])
    np.testing.assert_array_equal(ours.last, [r[1] for r in ref])
    np.testing.assert_allclose(ours.t_err, [r[3] for r in ref], rtol=1e-9)
    np.testing.assert_allclose(ours.r_err, [r[4] for r in ref], rtol=1e-6, atol=1e-12)
    t = 100 * np.mean([r[3] for r in ref])
    assert ours.t_rel == pytest.approx(t, rel=1e-9)
    assert sum(s.n for s in ours.per_length) == ours.n_segments


def test_kitti_short_trajectory_has_no_segments():
    gt, est = make_pair(8, n=20, step=1.0)
    k = M.kitti_relative_errors(gt, est)
    assert k.n_segments == 0 and np.isnan(k.t_rel) and np.isnan(k.r_rel) and k.per_length == ()


def test_inputs_must_pair():
    gt, est = make_pair(9, n=20)
    with pytest.raises(ValueError, match="pair them first"):
        M.ate(gt, est[:-1])
    with pytest.raises(ValueError, match="align"):
        M.ate(gt, est, "affine")


# ----------------------------------------------------------------------------- reference figures


@pytest.fixture(scope="module")
def kitti00():
    return read_kitti_poses(DATA / "KITTI_00_gt.txt").poses, read_kitti_poses(DATA / "KITTI_00_ORB.txt").poses


def test_kitti00_reference_figures(kitti00):
    gt, est = kitti00
    a = M.ate(gt, est, "se3")  # evo_ape kitti KITTI_00_gt.txt KITTI_00_ORB.txt -a -> rmse 1.303450
    k = M.kitti_relative_errors(gt, est)
    assert abs(a.rmse - 1.3035) < 1e-4 and a.rmse == pytest.approx(1.303450, abs=5e-7)
    assert round(k.t_rel, 4) == 0.6997
    assert round(k.r_rel, 4) == 0.2533
    assert k.n_segments == 3283


def test_kitti00_matches_evo(kitti00):
    gt, est = kitti00
    rmse, errors, _ = evo_ape(gt, est, "se3")
    ours = M.ate(gt, est, "se3")
    assert ours.rmse == pytest.approx(rmse, rel=1e-10)
    np.testing.assert_allclose(ours.errors, errors, rtol=1e-9, atol=1e-12)
    r = M.rpe(gt, est)
    trans, _ = evo_rpe(gt, est, 1, "f")
    np.testing.assert_allclose(r.trans_errors, trans, rtol=1e-9, atol=1e-12)
    assert r.trans.rmse == pytest.approx(0.028120, abs=5e-7)  # evo_rpe kitti gt est
    assert r.rot.rmse == pytest.approx(0.114974, abs=5e-6)  # ... --pose_relation angle_deg


def test_tum_fr1_xyz_reference_figure():
    gt = read_tum_trajectory(DATA / "freiburg1_xyz-groundtruth.txt")
    est = read_tum_trajectory(DATA / "freiburg1_xyz-rgbdslam.txt")
    i, j = associate(gt.timestamps, est.timestamps, 0.01)
    a = M.ate(gt.poses[i], est.poses[j], "se3")  # evo_ape tum gt est -a -> rmse 0.013470
    assert round(a.rmse, 4) == 0.0135 and a.rmse == pytest.approx(0.013470, abs=5e-7)
    assert M.ate(gt.poses[i], est.poses[j], "none").rmse == pytest.approx(0.020079, abs=5e-7)


def test_huge_errors_give_finite_statistics():
    stats = metrics.ErrorStats.of(np.array([1e300, 2e300, 3.0]))
    assert stats.rmse == pytest.approx(np.sqrt(5 / 3) * 1e300) and stats.mean == pytest.approx(1e300)
    assert stats.std == pytest.approx(np.sqrt(2 / 3) * 1e300) and stats.max == 2e300


def test_usual_errors_are_computed_as_before():
    e = np.random.default_rng(0).random(50)
    stats = metrics.ErrorStats.of(e)
    assert stats.rmse == float(np.sqrt(np.mean(e * e))) and stats.std == float(np.std(e))
    assert np.isinf(metrics.ErrorStats.of(np.array([1.0, np.inf])).rmse)  # a non-finite error stays so


def test_ate_and_rpe_of_a_trajectory_gone_to_1e300_are_finite():
    gt = np.tile(np.eye(4), (4, 1, 1))
    est = gt.copy()
    est[2:, 0, 3] = 1e300
    assert metrics.ate(gt, est).rmse == pytest.approx(np.sqrt(0.5) * 1e300)
    assert np.isfinite(metrics.rpe(gt, est, 1).trans.rmse)
    v = np.array([[3.0, 4.0, 0.0], [3e300, 4e300, 0.0], [np.nan, 0.0, 0.0]])
    norms = metrics.row_norms(v)
    assert norms[0] == 5.0 and norms[1] == pytest.approx(5e300) and np.isnan(norms[2])


def test_alignment_of_positions_near_1e308_returns_the_rotation_instead_of_hanging():
    """Sums of such coordinates overflow (LAPACK's SVD of an inf never returns): each set is scaled
    first, so the same points align by the identity; a non-finite position is one ValueError."""
    pts = np.array([[1e308, 1e308, 0.0], [-1e308, 0.0, 0.0], [1e308, 0.0, 5e307]])
    R, t, s = metrics.umeyama_alignment(pts, pts, with_scale=True)
    assert np.allclose(R, np.eye(3)) and np.isclose(s, 1.0) and np.all(np.isfinite(t))
    with pytest.raises(ValueError, match="not a finite number"):
        metrics.umeyama_alignment(np.array([[np.inf, 0, 0], [0, 1, 0], [1, 0, 0]]), pts, with_scale=False)
