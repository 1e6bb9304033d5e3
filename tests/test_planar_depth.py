"""planar-depth: the yaw of near-wall turns from the depth alone, and a covariance that says which
directions the depth leaves to the prior."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import studies.turns_by_depth as study
from baselines.depth_geometry import backproject
from baselines.planar_depth import PlanarDepthOdometer, _surface
from odolab.api import invert, load_odometer, planar_to_transform, transform_to_planar
from odolab.sim.episodes import EpisodeSpec


@pytest.fixture(scope="module")
def near_wall_turns():
    """The first six turns of the study's pairs whose view's median depth is below 1 m."""
    pairs = (p for p in study.turn_pairs("val", 7, 20, 20) if p[1] < 1.0)
    return [p for _, p in zip(range(6), pairs)]


def _yaw_error_deg(est, prev, cur):
    true = transform_to_planar(invert(prev.gt_pose) @ cur.gt_pose)[2]
    return abs(np.degrees(np.angle(np.exp(1j * (est.planar[2] - true)))))


def test_near_wall_turns_come_out_within_degrees_and_the_slide_along_the_wall_stays_uncertain(near_wall_turns):
    odo = load_odometer("planar-depth")
    bare = load_odometer("planar-depth", translation_floor=0.0)  # the fit's own covariance, no model error added
    for o in (odo, bare):
        o.reset(EpisodeSpec().camera.intrinsics)
    prior = load_odometer("action-prior")
    errors, prior_errors, spread = [], [], []
    for _, depth, action, prev, cur, _ in near_wall_turns:
        est = odo.step(prev, cur, action)
        prior_errors.append(_yaw_error_deg(prior.step(prev, cur, action), prev, cur))
        if not est.valid:
            continue
        errors.append(_yaw_error_deg(est, prev, cur))
        cov = est.covariance
        assert cov.shape == (6, 6) and np.all(np.linalg.eigvalsh(cov) > 0)
        t = np.linalg.eigvalsh(bare.step(prev, cur, action).covariance[np.ix_([3, 5], [3, 5])])
        spread.append(np.sqrt(t[1] / t[0]))
        assert np.all(np.diag(cov)[[3, 5]] >= odo.config.translation_floor**2)
        assert np.sqrt(cov[1, 1]) < np.radians(2.0)  # the yaw is pinned by the planes' normals
    assert len(errors) >= 5
    assert max(errors) < 2.5 and np.mean(errors) < 0.5 * np.mean(prior_errors), (errors, prior_errors)
    # One wall fixes the distance to it, not the slide along it: that sigma stays near the prior's.
    assert max(spread) > 5.0, spread


def test_a_start_off_by_degrees_converges_to_the_same_answer(near_wall_turns):
    _, _, _action, prev, cur, _ = near_wall_turns[0]
    odo = PlanarDepthOdometer()
    odo.reset(EpisodeSpec().camera.intrinsics)
    X, _ = backproject(cur.depth, odo.intrinsics, odo.config.depth, odo.config.pixel_stride)
    surf = _surface(prev.depth, odo.intrinsics, odo.config.depth, odo.config.normal_step)
    true = transform_to_planar(invert(prev.gt_pose) @ cur.gt_pose)
    prior = np.zeros(2)
    ends = [
        odo._fit(X, surf, planar_to_transform(true[0], true[1], true[2] + np.radians(d)), prior) for d in (-4, 0, 4)
    ]
    yaws = [transform_to_planar(f.T_prev_cur)[2] for f in ends]
    assert np.ptp(np.degrees(yaws)) < 0.05 and abs(np.degrees(yaws[1] - true[2])) < 1.5


def test_the_same_pair_gives_the_same_bits(near_wall_turns):
    _, _, action, prev, cur, _ = near_wall_turns[1]
    runs = []
    for _ in range(2):
        odo = load_odometer("planar-depth")
        odo.reset(EpisodeSpec().camera.intrinsics)
        runs.append(odo.step(prev, cur, action))
    assert (runs[0].transform == runs[1].transform).all() and (runs[0].covariance == runs[1].covariance).all()


def test_blank_depth_and_bad_options_are_refused(near_wall_turns):
    _, _, action, prev, cur, _ = near_wall_turns[0]
    odo = load_odometer("planar-depth")
    odo.reset(EpisodeSpec().camera.intrinsics)
    assert not odo.step(prev, dataclasses.replace(cur, depth=np.zeros_like(cur.depth)), action).valid
    assert not odo.step(dataclasses.replace(prev, depth=np.zeros_like(prev.depth)), cur, action).valid
    for key, value, said in (
        ("pixel_stride", 0, r"pixel_stride must be in \[1, 64\], got 0"),
        ("prior_sigma", float("nan"), "prior_sigma"),
        ("tukey", True, "tukey"),
        ("max_median_depth", 0.05, "must exceed min_depth"),
        ("noise_floor", 0.0, "noise_floor > 0"),
        ("min_ncc", float("nan"), r"min_ncc must be a number in \[-1, 1\]"),
        ("forward_range", [0.0, "a"], "forward_range"),
    ):
        with pytest.raises((TypeError, ValueError), match=said):
            load_odometer("planar-depth", **{key: value})


def _wall_frames(slide: float, noise: float, seed: int = 0):
    """A fronto-parallel wall 0.8 m ahead, then after a 0.25 m step towards it with ``slide`` m to
    the right (invisible: the wall looks the same), each depth with ``noise`` relative noise."""
    from odolab.core.types import Frame

    cam = EpisodeSpec().camera
    rng = np.random.default_rng(seed)
    rgb = rng.integers(0, 255, (cam.height, cam.width, 3), dtype=np.uint8)
    frames = [
        Frame(
            rgb=rgb,
            depth=(z * (1 + noise * rng.standard_normal((cam.height, cam.width)))).astype(np.float32),
            timestamp=float(i),
        )
        for i, z in enumerate((0.8, 0.55))
    ]
    return cam.intrinsics, frames


def test_one_wall_leaves_the_slide_along_it_to_the_prior():
    from odolab.core.types import Action

    intr, (prev, cur) = _wall_frames(slide=0.15, noise=0.002)
    sigmas = {}
    for ratio in (0.05, 0.0):  # 0 (the default): the switch off, the normals' noise taken for information
        odo = load_odometer("planar-depth", one_plane_ratio=ratio)
        odo.reset(intr)
        est = odo.step(prev, cur, Action.MOVE_FORWARD)
        assert est.valid
        dx, dz, dyaw = est.planar
        assert abs(dz - 0.25) < 0.01 and abs(np.degrees(dyaw)) < 0.3  # the distance to the wall is seen
        sigmas[ratio] = np.sqrt(est.covariance[3, 3])
    # the slide (0.15 m true, 0 by the prior) keeps the prior's 0.1 m sigma; without the switch it did not
    assert sigmas[0.05] > 0.095 and abs(0.15 - dx) < 2 * sigmas[0.05], sigmas
    assert sigmas[0.0] < 0.5 * sigmas[0.05], sigmas
