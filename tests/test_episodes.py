"""Episodes: determinism by seed, the Sequence contract, and the on-disk cache."""

import dataclasses

import numpy as np
import pytest

from odolab.core.geometry import invert, transform_to_planar
from odolab.core.parallel import SERIAL, Execution
from odolab.core.types import Action, Sequence
from odolab.sim import episodes
from odolab.sim.episodes import EpisodeCache, EpisodeSpec, NoiseConfig, load_episodes, render_episode, rollout


def test_same_spec_same_episode_bit_for_bit(small_spec):
    a, b = render_episode(small_spec), render_episode(small_spec)
    for f in ("rgb", "depth", "poses", "actions", "collisions"):
        assert np.array_equal(getattr(a, f), getattr(b, f)), f


def test_other_seed_or_index_gives_another_episode(small_spec):
    a = render_episode(small_spec)
    b = render_episode(dataclasses.replace(small_spec, seed=1))
    c = render_episode(dataclasses.replace(small_spec, index=1))
    assert a.poses.shape != b.poses.shape or not np.allclose(a.poses, b.poses)
    assert a.poses.shape != c.poses.shape or not np.allclose(a.poses, c.poses)


def test_sensor_noise_does_not_change_the_path(small_spec):
    quiet = dataclasses.replace(small_spec, noise=NoiseConfig(rgb=0.0, depth=0.0))
    a, b = render_episode(small_spec), render_episode(quiet)
    assert np.array_equal(a.poses, b.poses)
    assert not np.array_equal(a.rgb, b.rgb)


def test_episode_is_a_sequence(small_spec):
    ep = render_episode(small_spec)
    assert isinstance(ep, Sequence)
    n = len(ep)
    assert n == len(ep.actions) + 1 == len(ep.poses) and n >= 2
    f = ep[1]
    assert f.rgb.shape == (54, 96, 3) and f.rgb.dtype == np.uint8
    assert f.depth.dtype == np.float32 and f.depth.max() <= 10.0
    assert np.array_equal(f.gt_pose, ep.gt_pose(1))
    assert isinstance(ep.action(0), Action) and ep.action(0) != Action.STOP
    assert ep.intrinsics.width == 96


def test_true_motion_matches_actions():
    r = rollout(EpisodeSpec(split="train", index=3, max_steps=80))
    poses = r.camera_poses(0.88)
    for a, T, hit in zip(r.actions, invert(poses[:-1]) @ poses[1:], r.collisions):
        _dx, dz, dyaw = transform_to_planar(T)
        if a == Action.MOVE_FORWARD and not hit:
            assert 0.11 < dz < 0.39 and abs(dyaw) < 0.5  # 0.25 + 0.5 (0.017 +- 3 sqrt(0.007))
        elif a == Action.MOVE_FORWARD:
            assert -1e-9 <= dz < 0.39 and abs(dyaw) < 0.5  # blocked: stopped at contact (see test_sim)
        elif a == Action.TURN_LEFT:
            assert 0.25 < dyaw < 0.8
        else:
            assert -0.8 < dyaw < -0.25


def test_noiseless_rollouts_reach_the_goal_almost_without_collisions():
    steps = hits = 0
    for i in range(5):
        r = rollout(EpisodeSpec(split="val", index=i, max_steps=400, noise=NoiseConfig(actuation=0.0)))
        assert r.reached_goal
        steps, hits = steps + len(r.actions), hits + sum(r.collisions)
    assert hits <= 0.02 * steps  # habitat's greedy follower may graze a corner (cost 0.25, not inf)


def test_cache_round_trip_and_atomic_files(tmp_path, small_spec):
    cache = EpisodeCache(tmp_path)
    assert cache.get(small_spec) is None and not cache.has(small_spec)
    ep = render_episode(small_spec)
    path = cache.put(ep)
    assert cache.has(small_spec) and cache.steps(small_spec) == len(ep.actions)
    assert path.exists() and not list(tmp_path.glob("*.tmp"))
    back = cache.get(small_spec)
    assert np.array_equal(back.rgb, ep.rgb) and back.info == ep.info
    path.write_bytes(b"garbage")  # a damaged file is treated as missing, not an error
    assert cache.get(small_spec) is None and not cache.has(small_spec)


def test_load_episodes_uses_the_cache(tmp_path, small_spec, monkeypatch):
    specs = [small_spec, dataclasses.replace(small_spec, index=1)]
    cache = EpisodeCache(tmp_path)
    first = load_episodes(specs, cache, execution=SERIAL)
    assert len(list(tmp_path.glob("*.npz"))) == 2

    def no_second_generation(*args, **kwargs):
        raise AssertionError("episode rendered again although it is cached")

    # generation is deterministic, so equal episodes alone would not show the cache was read
    monkeypatch.setattr(episodes, "render_episode", no_second_generation)
    again = load_episodes(specs, cache, execution=SERIAL)
    assert all(np.array_equal(a.rgb, b.rgb) for a, b in zip(first, again))


@pytest.mark.slow
def test_ray_tasks_give_the_same_episodes(tmp_path, small_spec, ray_cluster):
    specs = [small_spec, dataclasses.replace(small_spec, index=1)]
    serial = load_episodes(specs, None, execution=SERIAL)
    ray_tasks = Execution(ray_address=ray_cluster, progress=False)
    parallel = load_episodes(specs, EpisodeCache(tmp_path), execution=ray_tasks)
    assert all(np.array_equal(a.depth, b.depth) for a, b in zip(serial, parallel))


def test_bad_spec_is_refused():
    with pytest.raises(ValueError, match="split"):
        EpisodeSpec(split="dev")
    with pytest.raises(ValueError, match="max_steps"):
        EpisodeSpec(max_steps=0)


def test_sample_start_goal_names_a_scene_with_no_episode_in_one_line_that_survives_pickling():
    """A scene where no start and goal lie the spec's distance apart: a NoEpisodeError (an input
    error, one line for the commands) naming the scene, the same after pickling (a Ray task's)."""
    import pickle

    from odolab.sim.scenes import generate_scene, scene_seed

    scene = generate_scene(scene_seed("test", 0))
    spec = EpisodeSpec(min_goal_distance=900.0, max_goal_distance=1000.0)
    with pytest.raises(episodes.NoEpisodeError) as caught:
        episodes.sample_start_goal(spec, scene, np.random.default_rng(0), max_tries=2)
    said = str(caught.value)
    assert said.startswith(f"scene {scene.seed}: no start and goal 900-1000 m apart") and "\n" not in said
    assert str(pickle.loads(pickle.dumps(caught.value))) == said
