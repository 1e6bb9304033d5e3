"""Pose-graph fusion (odolab.fusion): the graph's arithmetic, the robust kernel, calibration, the
fused odometer's fallback and its name in the registry, an oracle input marked, and the calibration
command's --out and step-count checks."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")  # a declared dependency; skip only where it is truly absent

from odolab.api import Action, Estimate, Odometer, planar_to_transform, register_odometer
from odolab.cli import run_cli
from odolab.fusion.calibration import CHI2_6_95, Calibration, InputCalibration, debiased, ellipsoid_share, fit_input
from odolab.fusion.graph import (
    Measurement,
    OnlineGraph,
    check_measurement,
    left_covariance,
    residual,
    right_covariance,
    smooth,
)
from odolab.io.inputs import MAX_INPUT_BYTES
from odolab.odometry.action_prior import ActionPrior
from odolab.odometry.odometer import REGISTRY, split_odometer_names, standalone_odometers, unknown_odometer
from odolab.running import runner
from tests.helpers import Steps, refused


def _pose(dx, dz, dyaw):
    return planar_to_transform(dx, dz, dyaw)


def test_two_inputs_fuse_to_the_information_weighted_mean():
    a, b = _pose(0.0, 0.20, 0.50), _pose(0.0, 0.30, 0.50)
    ca, cb = np.diag([1e-4] * 3 + [1e-4] * 3), np.diag([1e-4] * 3 + [4e-4] * 3)
    g = OnlineGraph(kernel="none")
    g.add_pose([], np.eye(4))
    T = g.add_pose([Measurement(0, 1, a, ca), Measurement(0, 1, b, cb)], a)
    # translation weights 1/1e-4 : 1/4e-4 = 4 : 1 along the motion's own axis
    assert np.allclose(T[:3, :3], a[:3, :3], atol=1e-6)
    assert np.isclose(np.linalg.norm(T[:3, 3]), 0.8 * 0.20 + 0.2 * 0.30, atol=1e-4)


def test_a_wild_input_is_down_weighted_by_the_robust_kernel():
    good, wild = _pose(0.0, 0.25, 0.0), _pose(0.4, -0.3, 0.6)
    cov = np.diag([1e-4] * 3 + [1e-4] * 3)
    ms = [
        Measurement(0, 1, good, cov, "a"),
        Measurement(0, 1, good @ _pose(0.005, 0, 0), cov, "b"),
        Measurement(0, 1, wild, cov, "c"),
    ]
    out = {}
    for kernel in ("none", "huber", "cauchy"):
        g = OnlineGraph(kernel=kernel, iterations=5)
        g.add_pose([], np.eye(4))
        out[kernel] = g.add_pose(ms, good)
    err = {k: np.linalg.norm(T[:3, 3] - good[:3, 3]) for k, T in out.items()}
    assert err["none"] > 0.1  # least squares is pulled a third of the way
    assert err["huber"] < 0.5 * err["none"] and err["cauchy"] < 0.02


def test_isam2_and_the_batch_smoother_agree_on_a_chain():
    rng = np.random.default_rng(0)
    steps = [_pose(*rng.normal([0, 0.25, 0], [0.02, 0.02, 0.1])) for _ in range(12)]
    ms = [Measurement(j, j + 1, T, np.diag(rng.uniform(1e-5, 1e-3, 6))) for j, T in enumerate(steps)]
    ms += [Measurement(j, j + 1, T @ _pose(0.01, 0.0, 0.01), np.diag([1e-3] * 6)) for j, T in enumerate(steps)]
    g = OnlineGraph(kernel="none")
    g.add_pose([], np.eye(4))
    online = [g.add_pose([m for m in ms if m.j == j], steps[j - 1]) for j in range(1, 13)]
    batch = smooth(13, ms, kernel="none")
    for j in range(1, 13):
        assert np.allclose(np.linalg.inv(batch[j - 1]) @ batch[j], online[j - 1], atol=1e-5)
    assert np.allclose(g.poses(), batch, atol=1e-4)
    with pytest.raises(ValueError, match="outside poses"):
        smooth(3, [Measurement(0, 5, steps[0], np.eye(6))])


def test_an_indeterminate_system_restarts_the_graph_at_the_previous_pose(monkeypatch):
    """iSAM2 refused a step once on a long navigation episode; the graph restarts and goes on."""
    step = _pose(0.0, 0.25, 0.1)
    g = OnlineGraph(kernel="none")
    g.add_pose([], np.eye(4))
    calls = {"n": 0}
    solve = OnlineGraph._solve

    def flaky(self, graph, values):
        calls["n"] += 1
        if calls["n"] == 4:  # pose 3's first attempt
            raise RuntimeError("Indeterminant linear system detected")
        return solve(self, graph, values)

    monkeypatch.setattr(OnlineGraph, "_solve", flaky)
    out = []
    for j in range(1, 7):
        ms = [Measurement(j - 1, j, step, np.diag([1e-4] * 6))]
        if j >= 3:  # a span factor, which after the restart reaches a pose no longer in the graph
            ms.append(Measurement(j - 2, j, step @ step, np.diag([1e-4] * 6)))
        out.append(g.add_pose(ms, np.eye(4)))
    assert g.restarts == 1 and g.n == 7
    assert all(np.allclose(T, step, atol=1e-6) for T in out)
    poses = g.poses()
    assert len(poses) == 7 and np.allclose(np.linalg.inv(poses[5]) @ poses[6], step, atol=1e-6)


def test_a_loop_factor_revises_the_chain():
    """A factor from pose 0 to pose 3 (the 'span' factors) pulls the chain it closes."""
    step = _pose(0.0, 0.25, 0.0)
    ms = [Measurement(j, j + 1, step, np.diag([1e-4] * 6)) for j in range(3)]
    loop = Measurement(0, 3, _pose(0.0, 0.60, 0.0), np.diag([1e-6] * 6))
    poses = smooth(4, ms + [loop], kernel="none")
    assert np.isclose(poses[3][2, 3], 0.60, atol=0.01) and poses[3][2, 3] < 0.75


def test_covariance_frames_and_residuals():
    T = _pose(0.1, 0.3, 0.4)
    cov = np.diag([1e-3, 2e-3, 3e-3, 4e-3, 5e-3, 6e-3])
    assert np.allclose(left_covariance(T, right_covariance(T, cov)), cov)
    assert np.allclose(residual(T, T), 0.0)
    # a small left perturbation exp(delta) T shows up as xi = Ad(T^-1) delta
    delta = np.array([0.0, 0.01, 0.0, 0.02, 0.0, -0.01])
    perturbed = gtsam.Pose3.Expmap(delta).matrix() @ T
    ad = gtsam.Pose3(T).inverse().AdjointMap()
    assert np.allclose(residual(T, perturbed), ad @ delta, atol=1e-5)


def test_calibration_puts_95_percent_inside_the_95_percent_ellipsoid(tmp_path):
    rng = np.random.default_rng(1)
    sigma = np.array([0.001, 0.02, 0.001, 0.03, 0.001, 0.02])
    n = 4000
    spread = rng.uniform(0.3, 3.0, n)  # some steps are surer than others, and the odometer knows which
    xi = rng.normal(0.0, sigma, (n, 6)) * spread[:, None]
    actions = np.full(n, Action.TURN_LEFT.value)
    own = [np.diag((0.1 * sigma * k) ** 2) for k in spread]  # but is ten times too sure of itself
    cal = fit_input(xi, actions, own)
    assert np.isclose(cal.own_scale["turn_left"], 100.0, rtol=0.15)  # 10^2
    fresh = rng.normal(0.0, sigma, (n, 6)) * spread[:, None]
    share = ellipsoid_share(fresh, np.stack([cal.covariance(Action.TURN_LEFT, c) for c in own]))
    assert 0.93 < share < 0.97
    # own covariances that say nothing about the step are not used: the fixed one fits better
    blind = fit_input(xi, actions, [np.diag((0.1 * sigma * k) ** 2) for k in rng.permutation(spread)])
    assert blind.own_scale["turn_left"] is None
    indefinite = np.diag([1e-4] * 5 + [-1e-4])  # not a covariance: never adopted
    assert fit_input(xi, actions, [indefinite] * n).own_scale["turn_left"] is None
    plain = fit_input(xi / spread[:, None], actions, [None] * n)
    assert np.allclose(plain.fixed["turn_left"], sigma, rtol=0.15)
    assert 0.93 < ellipsoid_share(fresh / spread[:, None], plain.covariance(Action.TURN_LEFT, None)) < 0.97
    assert "move_forward" not in cal.fixed  # no forward steps: nothing claimed
    path = tmp_path / "cal.json"
    Calibration({"x": cal}, source="test").save(path)
    back = Calibration.load(path).for_input("x")
    assert back.fixed == cal.fixed and back.own_scale == cal.own_scale
    with pytest.raises(ValueError, match="no calibration for odometer 'y'"):
        Calibration.load(path).for_input("y")
    assert CHI2_6_95 > 12


def test_calibration_finds_a_bias_and_a_correlation_and_fusion_removes_the_bias(tmp_path):
    rng = np.random.default_rng(2)
    n = 3000
    bias = np.array([0.0, 0.01, 0.0, -0.02, 0.0, 0.005])  # a turn overestimated by 0.01 rad, slid 2 cm
    yaw = rng.normal(0.0, 0.015, n)
    noise = np.zeros((n, 6))
    noise[:, 1], noise[:, 3] = yaw, -2.0 * yaw + rng.normal(0.0, 0.01, n)  # dx error = -2 m x yaw error + noise
    noise[:, 5] = rng.normal(0.0, 0.01, n)
    noise[:, [0, 2, 4]] = rng.normal(0.0, 1e-4, (n, 3))
    xi = np.array([gtsam.Pose3.Logmap(gtsam.Pose3.Expmap(bias).compose(gtsam.Pose3.Expmap(e))) for e in noise])
    xi[:60] += rng.normal(0.0, 1.0, (60, 6))  # 2 % wild steps must not set the bias
    cal = fit_input(xi, np.full(n, Action.TURN_LEFT.value), [None] * n)
    assert np.allclose(cal.bias["turn_left"], bias, atol=2e-3)
    corr = np.array(cal.correlation["turn_left"])
    assert corr[1, 3] < -0.8 and abs(corr[1, 5]) < 0.1 and corr[0, 3] == 0.0  # floored components stay uncorrelated
    # a fresh step T_true = T @ exp(xi): the corrected measurement's residual is the debiased one
    T_true = _pose(0.01, 0.02, 0.52)
    T = T_true @ np.linalg.inv(gtsam.Pose3.Expmap(bias).matrix())
    assert np.allclose(residual(cal.corrected(Action.TURN_LEFT, T), T_true), 0.0, atol=3e-3)
    assert np.allclose(cal.corrected(Action.MOVE_FORWARD, T), T)  # no bias for an uncalibrated action
    assert np.allclose(debiased(bias[None], bias), 0.0, atol=1e-12)
    # fresh steps fall inside the 95 % ellipsoid 95 % of the time; the correlated covariance explains
    # them better (higher likelihood) than the diagonal one with the same sigmas
    fresh = noise[60:]
    full = cal.covariance(Action.TURN_LEFT, None)
    diag = np.diag(np.diag(full))
    assert 0.92 < ellipsoid_share(fresh, full) < 0.98

    def loglik(cov):
        from odolab.fusion.calibration import mahalanobis2

        return -0.5 * (mahalanobis2(fresh, cov).mean() + np.linalg.slogdet(cov)[1])

    assert loglik(full) > loglik(diag) + 0.5
    path = tmp_path / "cal.json"
    Calibration({"x": cal}).save(path)
    back = Calibration.load(path).for_input("x")
    assert back.bias == cal.bias and back.correlation == cal.correlation
    old = InputCalibration(cal.fixed, cal.own_scale, cal.steps)  # a file from before bias and correlation
    assert np.allclose(old.covariance(Action.TURN_LEFT, None), np.diag(np.square(cal.fixed["turn_left"])))
    assert np.allclose(old.corrected(Action.TURN_LEFT, T), T)


def test_near_views_get_their_own_entries_and_fusion_picks_them_by_depth(tmp_path):
    from odolab.fusion.calibration import view_is_near

    rng = np.random.default_rng(5)
    n = 600
    near = np.arange(n) < 200  # a third of the steps face a wall, where this input is 5x less precise
    xi = rng.normal(0.0, 0.01, (n, 6)) * np.where(near, 5.0, 1.0)[:, None]
    xi[near, 1] += 0.02  # and overestimates the turn there
    actions = np.full(n, Action.TURN_LEFT.value)
    cal = fit_input(xi, actions, [None] * n, near)
    assert cal.steps == {"turn_left@near": 200, "turn_left": 400}
    assert np.allclose(cal.fixed["turn_left@near"], 5 * np.asarray(cal.fixed["turn_left"]), rtol=0.25)
    assert abs(cal.bias["turn_left@near"][1] - 0.02) < 0.01 and abs(cal.bias["turn_left"][1]) < 0.003
    assert cal.label(Action.TURN_LEFT, True) == "turn_left@near" and cal.label(Action.TURN_LEFT, False) == "turn_left"
    assert cal.label(Action.TURN_RIGHT, True) is None  # not calibrated at all
    wide, narrow = cal.covariance(Action.TURN_LEFT, None, True), cal.covariance(Action.TURN_LEFT, None)
    assert np.all(np.diag(wide) > 10 * np.diag(narrow))
    # fewer than 10 near steps of an action: one entry for every step of it
    few = fit_input(xi[195:], actions[195:], [None] * (n - 195), near[195:])
    assert few.steps == {"turn_left": n - 195} and few.label(Action.TURN_LEFT, True) == "turn_left"
    path = tmp_path / "near.json"
    Calibration({"x": cal}, near_depth=1.0).save(path)
    back = Calibration.load(path)
    assert back.near_depth == 1.0 and back.for_input("x").fixed == cal.fixed
    doc = json.loads(path.read_text())
    for bad in (-1, "1", True, 1e9):
        doc["near_depth"] = bad
        path.write_text(json.dumps(doc))
        with pytest.raises(ValueError, match=r"near_depth must be a number of metres in \[0, 100\]"):
            Calibration.load(path)
    doc["near_depth"] = 1.0
    lone = json.loads(json.dumps(doc))
    for key in ("fixed", "own_scale", "steps", "inside95", "bias", "correlation"):
        lone["inputs"]["x"][key].pop("turn_left", None)
    path.write_text(json.dumps(lone))
    with pytest.raises(ValueError, match="'turn_left@near' without 'turn_left'"):
        Calibration.load(path)
    doc.pop("near_depth")
    path.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="near-view entries .* near_depth is 0 or absent"):
        Calibration.load(path)
    wall = np.full((4, 4), 0.6, np.float32)
    assert view_is_near(wall, 1.0) and not view_is_near(wall + 1.0, 1.0) and not view_is_near(wall, 0.0)
    assert not view_is_near(np.zeros((4, 4)), 1.0)  # no reading: nothing to say it is near


def test_bad_calibration_files_are_named(tmp_path):
    def one(fixed, scale="{}", more=""):
        return f'{{"format": 1, "inputs": {{"x": {{"fixed": {fixed}, "own_scale": {scale}, "steps": {{}}{more}}}}}}}'

    ok = '{"turn_left": [1, 1, 1, 1, 1, 1]}'
    eye = [[float(i == j) for j in range(6)] for i in range(6)]

    def corr(m):
        return one(ok, more=f', "correlation": {{"turn_left": {m}}}')

    near_singular = [row[:] for row in eye]
    near_singular[1][3] = near_singular[3][1] = 1 - 2e-9
    lopsided = [row[:] for row in eye]
    lopsided[0][1] = 0.5
    for text, words in [
        ("{", "not a valid calibration file"),
        ('{"format": 1, "format": 1, "inputs": {}}', "key 'format' appears twice"),
        (one(ok, '{"turn_left": 1, "turn_left": 2}'), "key 'turn_left' appears twice"),
        ('{"format": 9, "inputs": {}}', "format 1"),
        ('{"format": true, "inputs": {}}', "format 1"),
        ('{"format": 1, "inputs": {}}', "calibrates no"),
        ('{"format": 1, "inputs": {"x": 1}, "extra": 2}', "unknown key 'extra'"),
        ('{"format": 1, "source": 3, "inputs": {"x": 1}}', "source must be a string"),
        ('{"format": 1, "inputs": {"x": 1}}', "input 'x': expected an object"),
        ('{"format": 1, "inputs": {"x": {"fixed": {}, "steps": {}}}}', "no 'own_scale'"),
        (one(ok, more=', "biases": {}'), "unknown key 'biases'"),
        (one('{"turn_left": [1, 2]}'), r"fixed.turn_left: expected a list of 6 numbers, got \[1, 2\]"),
        (one('{"turn_left": [1e-300, 1, 1, 1, 1, 1]}'), "fixed.turn_left: expected 6 sigmas in"),
        (one('{"fly": [1, 1, 1, 1, 1, 1]}'), "fixed: unknown action 'fly'"),
        (one("{}"), "fixed gives no action"),
        (one(ok, '{"turn_left": 0}'), "own_scale.turn_left: expected null or a number"),
        (one(ok, '{"turn_left": -5}'), "own_scale.turn_left: expected null or a number"),
        (one(ok, more=', "bias": {"turn_left": [0, 0]}'), "bias.turn_left: expected a list of 6"),
        (one(ok, more=', "bias": {"turn_left": "abcdef"}'), "bias.turn_left: expected a list of 6"),
        (one(ok, more=', "bias": {"turn_left": [0, 3, 0, 0, 0, 0]}'), "bias.turn_left: expected rotations within"),
        (one(ok, more=', "bias": {"turn_left": [0, 0, 0, 99, 0, 0]}'), "translations within"),
        (one(ok, more=', "bias": {"turn_left": [0, 0, 0, 1%s, 0, 0]}' % ("0" * 400)), "bias.turn_left: int too large"),
        (one(ok, more=', "bias": {"turn_right": [0, 0, 0, 0, 0, 0]}'), "no fixed sigmas"),
        (one(ok, more=', "bias": {"stop": [0, 0, 0, 0, 0, 0]}'), "bias: unknown action 'stop'"),
        (one(ok, more=', "bias": null'), "bias must map actions"),
        (one(ok, more=', "bias": 3'), "bias must map actions"),
        (corr("[[1]]"), "correlation.turn_left: expected 6 rows of 6 numbers"),
        (corr(str([[1.0] * 6] * 6)), "correlation.turn_left: expected a positive definite"),
        (corr(str(near_singular)), "its smallest is"),
        (corr(str(lopsided)), "correlation.turn_left: expected a symmetric matrix"),
        (corr(str([[2.0 * v for v in row] for row in eye])), "expected ones on the diagonal"),
    ]:
        p = tmp_path / "c.json"
        p.write_text(text)
        with pytest.raises(ValueError, match=words):
            Calibration.load(p)
    with pytest.raises(ValueError, match="no such calibration file"):
        Calibration.load(tmp_path / "missing.json")
    with pytest.raises(ValueError, match="is a folder"):
        Calibration.load(tmp_path)
    huge = tmp_path / "huge.json"
    with open(huge, "wb") as f:  # sparse: takes no room
        f.truncate(MAX_INPUT_BYTES + 1)
    with pytest.raises(ValueError, match="too large to be read as the calibration file"):
        Calibration.load(huge)
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)  # would block a reader forever
    with pytest.raises(ValueError, match="is a pipe, device or socket; the calibration file must be a regular file"):
        Calibration.load(fifo)
    # a fitted-looking file with an identity correlation and a small bias loads
    p.write_text(
        one(ok, more=f', "bias": {{"turn_left": [0, 0.01, 0, -0.02, 0, 0]}}, "correlation": {{"turn_left": {eye}}}')
    )
    assert Calibration.load(p).for_input("x").bias["turn_left"][1] == 0.01


def test_a_fitted_calibration_is_never_refused_by_the_loader(tmp_path):
    rng = np.random.default_rng(3)
    xi = rng.normal(0.0, 0.01, (300, 6))
    xi[:, 3] = -0.999 * xi[:, 1]  # all but perfectly correlated: the fit's shrink keeps it loadable
    xi[:, [0, 2]] = 0.0  # and components exactly zero (at the floor)
    cal = fit_input(xi, np.full(300, Action.MOVE_FORWARD.value), [None] * 300)
    Calibration({"x": cal}).save(tmp_path / "c.json")
    assert Calibration.load(tmp_path / "c.json").for_input("x").correlation == cal.correlation


# --- the fused odometer --------------------------------------------------------------------------


class _Never(Odometer):
    def step(self, prev, cur, action):
        return Estimate.invalid()


class _Fixed(Odometer):
    def __init__(self, dz: float = 0.25) -> None:
        self.dz = dz

    def step(self, prev, cur, action):
        return Estimate.from_planar(0.0, self.dz, 0.0)


@pytest.fixture()
def calibration(tmp_path):
    fixed = {a: [0.01, 0.01, 0.01, 0.02, 0.02, 0.02] for a in ("move_forward", "turn_left", "turn_right")}
    one = InputCalibration(fixed, {a: None for a in fixed}, {a: 100 for a in fixed})
    path = tmp_path / "cal.json"
    Calibration({"action-prior": one, "test-never": one, "test-fixed": one, "test-far": one}).save(path)
    register_odometer("test-never", _Never)
    register_odometer("test-fixed", _Fixed)
    register_odometer("test-far", lambda: _Fixed(0.29))
    return str(path)


def _frames():
    from odolab.api import Frame

    f = Frame(rgb=np.zeros((4, 4, 3), np.uint8), depth=np.ones((4, 4), np.float32), timestamp=0.0)
    return f, f


def test_when_every_input_fails_the_step_is_the_action_prior_and_invalid(calibration):
    from odolab.api import Intrinsics
    from odolab.odometry.action_prior import ActionPrior

    odo = REGISTRY.load("fused(test-never)", calibration=calibration)
    odo.reset(Intrinsics.from_hfov(4, 4, 79.0))
    est = odo.step(*_frames(), Action.TURN_LEFT)
    assert not est.valid
    assert np.allclose(est.transform, planar_to_transform(*ActionPrior.shipped().motion(Action.TURN_LEFT)))


def test_fused_inputs_that_answer_are_averaged_and_the_failures_ignored(calibration):
    from odolab.api import Intrinsics

    odo = REGISTRY.load("fused(test-never,test-fixed,test-far)", calibration=calibration, kernel="none")
    odo.reset(Intrinsics.from_hfov(4, 4, 79.0))
    for _ in range(3):
        est = odo.step(*_frames(), Action.MOVE_FORWARD)
        assert est.valid and np.isclose(est.transform[2, 3], 0.27, atol=1e-4)  # equal weights
        assert est.covariance.shape == (6, 6) and est.covariance[5, 5] < 0.02**2  # two answers beat one
    assert odo.fused_steps == 3 and odo.fusion_seconds > 0
    smoothed = odo.smoothed_trajectory()  # a chain: the batch solution is the online one
    assert smoothed.shape == (4, 4, 4) and np.allclose(smoothed[-1][2, 3], 3 * 0.27, atol=1e-3)


class _BadCovariance(Odometer):
    def step(self, prev, cur, action):
        return Estimate(planar_to_transform(0.0, 0.40, 0.0), covariance=-np.eye(6))


def test_an_answer_whose_covariance_is_not_one_is_no_answer(calibration, tmp_path):
    """An input's own covariance that is not positive definite would break every step of the graph."""
    from odolab.api import Intrinsics

    cal = Calibration.load(calibration)
    fixed = {a: [0.01, 0.01, 0.01, 0.02, 0.02, 0.02] for a in ("move_forward", "turn_left", "turn_right")}
    own = InputCalibration(fixed, {a: 1.0 for a in fixed}, {a: 100 for a in fixed})  # its own covariance used
    Calibration({**{n: cal.for_input(n) for n in ("action-prior", "test-fixed")}, "test-badcov": own}).save(
        tmp_path / "c.json"
    )
    register_odometer("test-badcov", _BadCovariance)
    odo = REGISTRY.load("fused(test-badcov,test-fixed)", calibration=str(tmp_path / "c.json"))
    odo.reset(Intrinsics.from_hfov(4, 4, 79.0))
    est = odo.step(*_frames(), Action.MOVE_FORWARD)
    assert est.valid and np.isclose(est.transform[2, 3], 0.25, atol=1e-6)  # test-fixed's answer alone


def test_graph_inputs_that_are_not_poses_or_covariances_are_named():
    good = Measurement(0, 1, _pose(0.0, 0.25, 0.0), np.eye(6) * 1e-4, "good")
    nan = Measurement(0, 1, np.full((4, 4), np.nan), np.eye(6) * 1e-4, "nan")
    check_measurement(good)
    with pytest.raises(ValueError, match=r"measurement \(nan\): T_ij is not a rigid transform: non-finite"):
        check_measurement(nan)
    with pytest.raises(ValueError, match="not a rigid transform"):
        check_measurement(Measurement(0, 1, 2 * np.eye(4), np.eye(6), "x"))
    with pytest.raises(ValueError, match="symmetric positive definite"):
        check_measurement(Measurement(0, 1, np.eye(4), np.zeros((6, 6)), "x"))
    with pytest.raises(ValueError, match="finite 6x6"):
        check_measurement(Measurement(0, 1, np.eye(4), np.eye(3), "x"))
    for bad in ({"k": 0.0}, {"k": float("nan")}, {"iterations": 0}, {"iterations": 2.5}):
        with pytest.raises(ValueError, match="k must be|iterations must be"):
            OnlineGraph(**bad)
    g = OnlineGraph()
    g.add_pose([], np.eye(4))
    with pytest.raises(ValueError, match=r"measurement 1 for pose 1 \(nan\)"):
        g.add_pose([good, nan], np.eye(4))
    assert np.allclose(g.add_pose([good], np.eye(4)), good.T_ij, atol=1e-6)  # the graph goes on
    for key, value in (("kernel_width", "abc"), ("span", 2.7), ("span", True), ("calibration", 123)):
        with pytest.raises(ValueError, match=key):
            REGISTRY.load("fused(icp)", **{key: value})


def test_the_fused_options_are_a_config_that_says_what_each_takes(calibration):
    """The constructor's options besides its inputs are :class:`FusionConfig`'s fields (kept as
    ``config``), whose ranges and choices :func:`odolab.config.describe` lists."""
    from typing import get_args

    from odolab.config import describe
    from odolab.fusion.graph import KERNELS
    from odolab.fusion.odometer import FusionConfig, Kernel

    assert get_args(Kernel) == KERNELS
    assert [(r.name, r.range) for r in describe(FusionConfig)] == [
        ("calibration", ""),
        ("kernel", "one of 'huber', 'cauchy', 'none'"),
        ("kernel_width", "[0.1, 100]"),
        ("span", "[1, 10]"),
        ("span_inputs", ""),
        ("options_file", ""),
    ]
    assert all(r.doc for r in describe(FusionConfig()))
    odo = REGISTRY.load("fused(test-fixed)", calibration=calibration, kernel_width=2)
    assert odo.config == FusionConfig(calibration=calibration, kernel_width=2.0) and odo.kernel_width == 2.0
    for bad, said in (
        ({"kernel_width": 200}, "kernel_width must be in [0.1, 100], got 200"),
        ({"span": 2.7}, "span must be a whole number in [1, 10], got 2.7"),
        ({"kernel": "tukey"}, "kernel must be one of 'huber', 'cauchy', 'none', got 'tukey'"),
        ({"span_inputs": "test-fixed"}, "span_inputs needs span >= 2 (factors over more than one step), got span 1"),
    ):
        with pytest.raises(ValueError) as info:
            FusionConfig(**bad)
        assert str(info.value) == said


def test_a_fused_odometer_digest_changes_with_its_calibration(calibration, tmp_path):
    first = REGISTRY.load("fused(test-fixed)", calibration=calibration).identity_digest
    assert first == REGISTRY.load("fused(test-fixed)", calibration=calibration).identity_digest
    cal = Calibration.load(calibration)
    other = tmp_path / "other.json"
    Calibration(cal.inputs, source="recalibrated").save(other)  # same numbers, another file: rerun to be sure
    assert REGISTRY.load("fused(test-fixed)", calibration=str(other)).identity_digest != first


def test_span_factors_tie_steps_across_the_graph(calibration):
    from odolab.api import Intrinsics

    odo = REGISTRY.load(
        "fused(test-fixed,test-far)", calibration=calibration, kernel="none", span=3, span_inputs="test-fixed"
    )
    odo.reset(Intrinsics.from_hfov(4, 4, 79.0))
    for _ in range(4):
        est = odo.step(*_frames(), Action.MOVE_FORWARD)
    # besides the two consecutive factors per step: spans of 2 and 3 steps from the spanning input
    spans = [m for m in odo._measurements if m.j - m.i > 1]
    assert spans and all(m.source == "test-fixed" and m.j - m.i <= 3 for m in spans)
    # a span that says 0.25 m over several steps pulls the fused step below the plain mean of 0.27
    assert est.valid and est.transform[2, 3] < 0.27


def test_fused_names_and_bad_options(calibration):
    assert split_odometer_names("icp, fused(icp,open3d-rgbd) ,robust-vo") == [
        "icp",
        "fused(icp,open3d-rgbd)",
        "robust-vo",
    ]
    with pytest.raises(ValueError, match="unbalanced"):
        split_odometer_names("fused(icp")
    assert unknown_odometer("fused(icp,nope)") == "nope" and unknown_odometer("fused(icp)") is None
    assert unknown_odometer("fused()") is None and "fused" not in standalone_odometers()
    with pytest.raises(ValueError, match="needs its inputs"):
        REGISTRY.load("fused()", calibration=calibration)
    with pytest.raises(ValueError, match="inputs are in its name"):
        REGISTRY.load("fused(test-fixed)", calibration=calibration, inputs="test-never")
    with pytest.raises(ValueError, match="span_inputs needs span >= 2"):
        REGISTRY.load("fused(test-fixed)", calibration=calibration, span_inputs="test-fixed")
    with pytest.raises(ValueError, match="needs its inputs"):
        REGISTRY.load("fused", calibration=calibration)
    with pytest.raises(ValueError, match="span_inputs"):
        REGISTRY.load("fused(test-fixed)", calibration=calibration, span=2, span_inputs="icp")
    with pytest.raises(ValueError, match="no calibration for odometer 'icp'"):
        REGISTRY.load("fused(icp)", calibration=calibration)


def test_a_fused_oracle_input_answers_and_the_fused_row_is_marked_oracle(oracle_calibration):
    fused = REGISTRY.load("fused(test-truth)", calibration=oracle_calibration)
    assert fused.oracle
    result = runner.run_sequence(fused, Steps(), "fused(test-truth)", ActionPrior.shipped())
    assert result.oracle and result.failures == 0
    assert np.allclose(result.poses[-1][:3, 3], Steps().gt_pose(4)[:3, 3], atol=1e-6)  # not the action prior's


# --- the command lines ------------------------------------------------------------------------------


def _calibrate(argv):
    from odolab.cli import run_cli
    from odolab.cli.calibrate_fusion import main

    return run_cli(main, "python -m odolab.fusion.calibrate", argv)


@pytest.mark.slow
def test_calibrate_writes_a_file_that_check_reads(tmp_path, capsys):
    out = tmp_path / "sub" / "cal.json"
    base = ["--episodes", "2", "--max-steps", "40", "--serial", "--cache", str(tmp_path / "cache")]
    assert _calibrate(["--odometers", "action-prior", "--out", str(out)] + base) == 0
    cal = Calibration.load(out)
    assert "action-prior" in cal.inputs and "python -m odolab.fusion.calibrate" in cal.source
    assert min(min(v) for v in cal.inputs["action-prior"].fixed.values()) >= 1e-3  # the floor holds
    assert _calibrate(["--check", str(out), "--split", "test"] + base) == 0
    said = capsys.readouterr().out
    assert "inside the 95 % ellipsoid" in said and "move_forward" in said


def test_calibrate_and_bench_refuse_mistakes_in_one_line(tmp_path, capsys):
    from odolab.cli import run_cli
    from odolab.cli.bench import main as bench_main

    (tmp_path / "file").write_text("x")
    cases = [
        (["--odometers", ""], "--odometers is empty"),
        (["--odometers", "action-prior,icp,icp"], "twice"),
        (["--odometers", "action-prior,fused(action-prior,icp)"], "not an input of fusion"),
        (["--odometers", "icp"], "must include action-prior"),
        (["--episodes", "1", "--max-steps", "5"], "too few to calibrate"),
        (["--cache", str(tmp_path / "file")], "--cache"),
        (["--out", str(tmp_path / "cal.txt")], "unknown file type '.txt'"),
        (["--check", str(tmp_path / "missing.json")], "no such calibration file"),
        (["--check", str(tmp_path / "old.json"), "--out", str(tmp_path / "x.json")], "--check only prints"),
        (["--check", str(tmp_path / "old.json")], "a calibration of format 0, this odolab reads format"),
    ]
    (tmp_path / "old.json").write_text('{"format": 0, "inputs": {}}')
    import json

    shipped = json.loads((Path(__file__).parents[1] / "odolab/data/fusion/calibration.json").read_text())
    shipped["inputs"] = {k: v for k, v in shipped["inputs"].items() if k in ("action-prior", "icp")}
    (tmp_path / "two.json").write_text(json.dumps(shipped))
    cases.append(
        (
            ["--check", str(tmp_path / "two.json"), "--odometers", "action-prior,icp,open3d-rgbd,robust-vo"],
            "no calibration for 'open3d-rgbd'",
        )
    )  # the default list typed out is still a list given
    shipped["inputs"]["bogus"] = shipped["inputs"]["icp"]
    (tmp_path / "bogus.json").write_text(json.dumps(shipped))
    cases.append(
        (["--check", str(tmp_path / "bogus.json")], f"{tmp_path / 'bogus.json'}: input 'bogus' is not a registered")
    )
    icp = shipped["inputs"]["icp"]
    for i, (where, value, words) in enumerate(
        [
            ("fixed", {"move_forward": ["0.06"] * 6}, "expected a number, got '0.06'"),
            ("fixed", {"move_forward": "111111"}, "a list of 6 numbers"),
            ("steps", {"move_forward": -5}, "whole number of steps >= 0, got -5"),
            ("steps", {"move_forward": 3.7}, "got 3.7"),
            ("steps", {"jump": 3}, "unknown action 'jump'"),
            ("inside95", {"move_forward": 7.0}, "share in [0, 1], got 7.0"),
        ]
    ):
        loose = json.loads(json.dumps(icp))
        loose[where] = {**loose.get(where, {}), **value}
        (tmp_path / f"t{i}.json").write_text(json.dumps({**shipped, "inputs": {"icp": loose}}))
        cases.append((["--check", str(tmp_path / f"t{i}.json")], words))
    (tmp_path / "digits.json").write_text('{"format": ' + "9" * 5000 + "}")
    cases.append(
        (["--check", str(tmp_path / "digits.json")], f"{tmp_path / 'digits.json'}: not a valid calibration file")
    )
    for i, stranger in enumerate(("this:Zen", "fused(action-prior,icp)")):  # never imported nor built from a file
        shipped["inputs"] = {stranger: icp}
        (tmp_path / f"s{i}.json").write_text(json.dumps(shipped))
        cases.append((["--check", str(tmp_path / f"s{i}.json")], f"input {stranger!r} is not a registered odometer"))
    for argv, words in cases:
        assert _calibrate(argv + ["--serial"]) == 2, argv
        err = capsys.readouterr().err
        assert words in err and "Traceback" not in err, (argv, err)
    for argv, words in [
        (
            [
                "--odometers",
                "fused(action-prior,icp)",
                "--odometer-option",
                f"fused(action-prior,icp).calibration={tmp_path / 'missing.json'}",
            ],
            "no such calibration file",
        ),
        (["--odometers", "fused(icp,icp)"], "named twice"),
        (["--odometers", "icp", "--odometer-option", "icp.bogus=1"], "no option 'bogus'"),
    ]:
        assert run_cli(bench_main, "python -m odolab.bench", ["--only", "odometers"] + argv) == 2
        err = capsys.readouterr().err
        assert words in err and "Traceback" not in err, (argv, err)


def test_an_options_file_value_its_input_refuses_names_the_file_and_the_input(tmp_path):
    f = tmp_path / "o.toml"
    f.write_text('[odometers."planar-depth"]\none_plane_ratio = nan\n')
    with pytest.raises(
        ValueError, match=r'o.toml: \[odometers."planar-depth"\] one_plane_ratio must be a number in \[0, 0.5\]'
    ):
        REGISTRY.load("fused(planar-depth)", options_file=str(f))


def test_calibrate_fusion_out_naming_a_folder_says_so(tmp_path, capsys):
    from odolab.cli.calibrate_fusion import main

    argv = ["--episodes", "1", "--max-steps", "100", "--out", str(tmp_path), "--serial"]
    assert run_cli(main, "python -m odolab.fusion.calibrate", argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"--out {tmp_path}: is a folder, not a file" in err


SHIPPED_CALIBRATION = Path(__file__).parents[1] / "odolab" / "data" / "fusion" / "calibration.json"


@pytest.mark.parametrize(
    "content, words",
    [
        (json.dumps({"format": 1, "options": {}, "episodes": [], "policy": {}}), "not a fusion calibration (keys"),
        ("my notes, not JSON", "not a fusion calibration (not a JSON document"),
        ("[1, 2]", "not a fusion calibration (not a JSON object"),
        (json.dumps({"format": 1, "source": "by hand", "inputs": {}}), "a calibration that python -m odolab.fusion"),
    ],
)
def test_calibrate_replaces_only_a_calibration_it_wrote(tmp_path, capsys, content, words):
    """--out some/existing.json replaced any file: a navigation config.json, a user's file."""
    out = tmp_path / "config.json"
    out.write_text(content)
    argv = ["--odometers", "action-prior", "--episodes", "1", "--max-steps", "30", "--serial", "--out", str(out)]
    err = refused(capsys, "calibrate", argv + ["--cache", str(tmp_path / "cache")])
    assert f"--out {out}: expected a new file or a calibration this command wrote, found" in err and words in err
    assert out.read_text() == content and not (tmp_path / "cache").exists()


def test_a_calibration_this_command_wrote_may_be_replaced(tmp_path):
    from odolab.fusion.calibration import what_file

    assert what_file(SHIPPED_CALIBRATION) is None
    old = tmp_path / "old.json"  # an older format of this command's: a new calibration replaces it
    old.write_text(json.dumps({"format": 0, "source": "python -m odolab.fusion.calibrate --out x.json", "inputs": {}}))
    assert what_file(old) is None


def test_calibrate_says_how_few_steps_it_was_given(capsys):
    err = refused(capsys, "calibrate", ["--episodes", "1", "--max-steps", "5", "--serial"])
    assert "--episodes 1 x --max-steps 5 = 5 steps: too few to calibrate, at least 30" in err, err


@pytest.mark.slow
def test_the_calibration_command_names_an_oracle_input(tmp_path, capsys, oracle_calibration):
    from odolab.cli import calibrate_fusion as calibrate

    calibrate.main(
        [
            "--odometers",
            "action-prior,test-truth",
            "--episodes",
            "1",
            "--max-steps",
            "30",
            "--serial",
            "--quiet",
            "--split",
            "val",
            "--cache",
            str(tmp_path / "cache"),
            "--out",
            str(tmp_path / "c.json"),
        ]
    )
    assert "test-truth (an oracle" in capsys.readouterr().out
