"""baselines/manhattan: the walls' direction from depth, and an odometer whose heading they hold (an
oracle when its input is one)."""

from __future__ import annotations

import numpy as np
import pytest

from baselines.manhattan import ManhattanConfig, ManhattanOdometer, anchor_direction, wall_direction, wrap_quarter
from odolab.api import (
    Action,
    Estimate,
    Frame,
    Intrinsics,
    Odometer,
    describe,
    invert,
    load_odometer,
    planar_to_transform,
    register_odometer,
)
from odolab.sim.episodes import EpisodeSpec, NoiseConfig, render_episode

K = Intrinsics.from_hfov(160, 90, 79.0)


def wall_depth(angle: float, distance: float = 2.0) -> np.ndarray:
    """Depth image of an infinite vertical wall whose normal points at ``angle`` (rad) in the
    camera's x-z plane, ``distance`` m from the camera."""
    _v, u = np.mgrid[0 : K.height, 0 : K.width].astype(np.float64)
    ray_x, ray_z = (u - K.cx) / K.fx, np.ones_like(u)
    n = np.array([np.sin(angle), np.cos(angle)])  # wall points p with n . p = distance
    t = distance / (n[0] * ray_x + n[1] * ray_z)
    return np.where(t > 0, t, 0.0).astype(np.float32)


@pytest.mark.parametrize("degrees", [0.0, 12.0, -30.0, 50.0])
def test_a_walls_direction_is_read_modulo_90_degrees(degrees):
    wall = wall_direction(wall_depth(np.radians(degrees)), K)
    assert wall is not None and wall.support > 0.9
    assert abs(np.degrees(wrap_quarter(wall.angle - np.radians(degrees)))) < 0.2


def test_no_wall_no_direction():
    assert wall_direction(np.zeros((90, 160), np.float32), K) is None


@pytest.fixture(scope="module")
def episode():
    return render_episode(
        EpisodeSpec(split="val", index=3, seed=0, max_steps=100, noise=NoiseConfig(rgb=1.0, depth=1.0, actuation=0.5))
    )


def _heading(T_world_cam: np.ndarray) -> float:
    return float(np.arctan2(T_world_cam[1, 2], T_world_cam[0, 2]))  # world z up, camera z forward


def test_the_walls_seen_from_every_pose_imply_one_world_direction(episode):
    """Noisy depth of a simulator episode: the view's wall direction minus the true heading is the
    same modulo 90 degrees from every pose (to a degree at the median)."""
    implied = []
    for i in range(len(episode.poses)):
        wall = wall_direction(episode.depth[i], episode.intrinsics)
        if wall is not None and wall.support > 0.3:
            implied.append(wrap_quarter(wall.angle - (_heading(episode.poses[i]) - _heading(episode.poses[0]))))
    implied = np.array(implied)
    assert len(implied) > 0.7 * len(episode.poses)
    centre = np.angle(np.mean(np.exp(4j * implied))) / 4
    spread = np.degrees(np.abs([wrap_quarter(a - centre) for a in implied]))
    assert np.median(spread) < 1.0


class NoisyTruth(Odometer):
    """The true motion with a seeded random yaw error of 0.5 degrees RMS on every step (a heading
    that random-walks, as a real odometer's does)."""

    oracle = True
    seed = 0

    def reset(self, intrinsics: Intrinsics) -> None:
        super().reset(intrinsics)
        self.rng = np.random.default_rng(self.seed)

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate:
        yaw = np.radians(self.rng.normal(0.0, 0.5))
        return Estimate(invert(prev.gt_pose) @ cur.gt_pose @ planar_to_transform(0.0, 0.0, yaw))


def _final_heading_error(odo: Odometer, episode) -> float:
    odo.reset(episode.intrinsics)
    heading = 0.0
    for i in range(len(episode) - 1):
        heading += odo.step(episode[i], episode[i + 1], episode.action(i)).planar[2]
    truth = _heading(episode.poses[-1]) - _heading(episode.poses[0])
    return abs(np.degrees(np.angle(np.exp(1j * (heading - truth)))))


def test_the_walls_hold_a_random_walking_heading(episode):
    """Over six noise draws the heading's final error shrinks to well under half (measured: 4.3
    degrees on average without the walls, 0.9 with them), and never stays above 2 degrees."""
    plain, held = [], []
    for seed in range(6):
        register_odometer("noisy-truth", type("Noisy", (NoisyTruth,), {"seed": seed}))
        plain.append(_final_heading_error(load_odometer("noisy-truth"), episode))
        odo = load_odometer("manhattan(noisy-truth)")
        held.append(_final_heading_error(odo, episode))
        assert _final_heading_error(odo, episode) == pytest.approx(held[-1], abs=1e-12)  # reset clears it
    assert odo.oracle and odo.identity_digest
    assert np.mean(held) < 0.35 * np.mean(plain) and max(held) < 2.0


@pytest.mark.parametrize(
    "options, field",
    [
        ({"step_sigma_deg": 0}, "step_sigma_deg"),
        ({"wall_sigma_deg": float("nan")}, "wall_sigma_deg"),
        ({"anchor_steps": 2.5}, "anchor_steps"),
        ({"min_support": "high"}, "min_support"),
        ({"relock_support": 1.5}, "relock_support"),
    ],
)
def test_bad_options_are_named(options, field):
    with pytest.raises(ValueError, match=field):
        ManhattanOdometer("ground-truth", **options)
    with pytest.raises(ValueError, match="one inner odometer"):
        ManhattanOdometer("")


def test_the_filter_settings_are_a_config_that_says_what_each_takes():
    """The constructor's numeric options are :class:`ManhattanConfig`'s fields (kept as ``config``),
    whose ranges :func:`odolab.api.describe` lists and whose errors name the field in one line."""
    assert [(r.name, r.range) for r in describe(ManhattanConfig)] == [
        ("step_sigma_deg", "[0.001, 45]"),
        ("prior_sigma_deg", "[0.001, 45]"),
        ("wall_sigma_deg", "[0.001, 45]"),
        ("anchor_steps", "[1, 1000]"),
        ("relock_views", "[0, 1000]"),
        ("relock_spread_deg", "[0, 45]"),
        ("relock_support", "[0, 1]"),
        ("min_support", "[0, 1]"),
        ("max_depth", "[0.5, 20]"),
    ]
    assert all(r.doc for r in describe(ManhattanConfig()))
    odo = ManhattanOdometer("ground-truth", wall_sigma_deg=2, relock_views=0)
    assert odo.config == ManhattanConfig(wall_sigma_deg=2.0, relock_views=0)
    assert odo.identity_digest != ManhattanOdometer("ground-truth").identity_digest
    assert odo.identity_digest == ManhattanOdometer("ground-truth", wall_sigma_deg=2.0, relock_views=0).identity_digest
    for bad, said in (
        ({"step_sigma_deg": 0}, "manhattan: step_sigma_deg must be in [0.001, 45], got 0"),
        ({"anchor_steps": 2.5}, "ManhattanConfig: option anchor_steps must be int, got 2.5"),  # as every odometer's
    ):
        with pytest.raises(ValueError) as info:
            ManhattanOdometer("ground-truth", **bad)
        assert str(info.value) == said


class Misbehaving(Odometer):
    """The true motion, but step ``bad`` answers NaN (``mode="nan"``) or raises (``"raise"``)."""

    oracle = True
    bad, mode = 3, "nan"

    def reset(self, intrinsics: Intrinsics) -> None:
        super().reset(intrinsics)
        self.t = 0

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate:
        self.t += 1
        if self.t == self.bad + 1:
            if self.mode == "raise":
                raise RuntimeError("inner odometer broke")
            return Estimate(np.full((4, 4), np.nan))
        return Estimate(invert(prev.gt_pose) @ cur.gt_pose)


@pytest.mark.parametrize("mode", ["nan", "raise"])
def test_a_failed_inner_step_moves_the_heading_as_the_runner_does(episode, mode):
    """A non-finite answer or an exception is a failed step: the heading follows the action prior
    there (as the runner's substitute does), stays finite, and the later answers stay usable."""
    register_odometer("misbehaving", type("M", (Misbehaving,), {"mode": mode}))
    odo = load_odometer("manhattan(misbehaving)")
    odo.reset(episode.intrinsics)
    prior = load_odometer("action-prior")
    expected = 0.0
    for i in range(8):
        if i == Misbehaving.bad:
            if mode == "raise":
                with pytest.raises(RuntimeError):
                    odo.step(episode[i], episode[i + 1], episode.action(i))
            else:
                assert not np.all(np.isfinite(odo.step(episode[i], episode[i + 1], episode.action(i)).transform))
            expected += prior.step(episode[i], episode[i + 1], episode.action(i)).planar[2]
        else:
            est = odo.step(episode[i], episode[i + 1], episode.action(i))
            assert np.all(np.isfinite(est.transform))
            expected += est.planar[2]
    assert np.isfinite(odo.heading) and odo.heading == pytest.approx(expected, abs=1e-9)


def test_the_inner_odometer_gets_its_options_from_a_file_and_names_are_checked(tmp_path):
    f = tmp_path / "o.toml"
    f.write_text('[odometers."icp"]\nvoxel = 0.05\n')
    odo = ManhattanOdometer("icp", options_file=str(f))
    assert odo.inner.config.voxel == 0.05
    assert (
        odo.identity_digest != ManhattanOdometer("icp").identity_digest
    )  # another inner configuration, another digest
    f.write_text('[odometers."icp"]\nvoxel = -1.0\n')
    with pytest.raises(ValueError, match="o.toml"):
        ManhattanOdometer("icp", options_file=str(f))
    with pytest.raises(ValueError, match="one inner odometer.*got 2"):
        load_odometer("manhattan(icp,open3d-rgbd)")
    with pytest.raises(ValueError, match="twice"):
        load_odometer("manhattan(manhattan(icp))")
    assert load_odometer("manhattan( icp )").inner.name == "icp"


def test_options_for_a_row_that_is_also_an_inner_odometer_are_refused():
    """``--odometer-option deepvo.x`` with both ``deepvo`` and ``manhattan(deepvo)`` listed would
    leave the inner deepvo at its defaults without a word: refused, naming the way that works."""
    from odolab.reporting.pipeline import ComparisonError, load_odometers

    with pytest.raises(ComparisonError, match="options_file"):
        load_odometers(["icp", "manhattan(icp)"], {"icp": {"voxel": 0.05}})
    with pytest.raises(ComparisonError, match="options_file"):
        load_odometers(["icp", "fused(icp,open3d-rgbd)"], {"icp": {"voxel": 0.05}})
    assert set(load_odometers(["icp", "manhattan(open3d-rgbd)"], {"icp": {"voxel": 0.05}})) == {
        "icp",
        "manhattan(open3d-rgbd)",
    }


class JumpingTruth(Odometer):
    """The true motion, with one answer 15 degrees off (step 20)."""

    oracle = True

    def reset(self, intrinsics: Intrinsics) -> None:
        super().reset(intrinsics)
        self.t = 0

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate:
        self.t += 1
        extra = np.radians(15.0) if self.t == 21 else 0.0
        return Estimate(invert(prev.gt_pose) @ cur.gt_pose @ planar_to_transform(0.0, 0.0, extra))


def test_a_jump_of_the_inner_odometer_is_undone_by_the_relock(episode):
    """15 degrees in one step is beyond the filter's gate: views that agree on the walls undo it
    (the default); with ``relock_views=0``, or a support threshold no view meets, it stays."""
    register_odometer("jumping-truth", JumpingTruth)
    undone = _final_heading_error(load_odometer("manhattan(jumping-truth)"), episode)
    stays = _final_heading_error(ManhattanOdometer("jumping-truth", relock_views=0), episode)
    strict = _final_heading_error(ManhattanOdometer("jumping-truth", relock_support=1.0), episode)
    assert undone < 2.0 and stays > 10.0 and strict > 10.0


@pytest.mark.parametrize(
    "views, expected",
    [
        ([(-29.2, 524), (-28.1, 445), (-1.9, 37), (-28.6, 300), (-22.7, 88)], -28.7),  # val 3's first views, one stray
        ([(44.0, 100), (-44.5, 100), (20.0, 500)], -45.25),  # agreeing across the +-45 degree seam
        ([(10.0, 100)], 10.0),
    ],
)
def test_the_anchor_is_the_largest_agreeing_group(views, expected):
    """A stray anchor view (clutter, 26 degrees off the walls) does not pull the world's direction;
    angles are compared modulo 90 degrees; the group's mean is weighted by samples."""
    got = np.degrees(anchor_direction([(np.radians(a), n) for a, n in views]))
    assert abs(wrap_quarter(np.radians(got - expected))) < np.radians(0.1)


@pytest.mark.parametrize("views", [[], [(float("nan"), 100)], [(0.1, 0)], [(0.1, -5), (0.2, 50)]])
def test_the_anchor_refuses_views_it_cannot_weigh(views):
    with pytest.raises(ValueError, match="finite angles and positive sample counts"):
        anchor_direction(views)


def test_an_options_file_that_is_not_a_path_is_named():
    """``options_file=5`` from a TOML value would open file descriptor 5; it is refused instead."""
    with pytest.raises(ValueError, match="options_file must be a path"):
        ManhattanOdometer("ground-truth", options_file=5)


def test_options_for_an_input_alone_point_to_the_options_file():
    """Options for ``icp`` when only ``manhattan(icp)`` runs would be lost; the refusal says where they go."""
    from odolab.reporting.pipeline import ComparisonError, load_odometers

    with pytest.raises(ComparisonError, match=r"input of 'manhattan\(icp\)'.*options_file=FILE"):
        load_odometers(["manhattan(icp)"], {"icp": {"voxel": 0.05}})


def test_manhattan_passes_its_inputs_oracle_on():
    assert load_odometer("manhattan(ground-truth)").oracle
