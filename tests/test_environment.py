"""The step-wise environment sees what the episode generator stored (both go through it)."""

from __future__ import annotations

import numpy as np
import pytest

from odolab.api import Action
from odolab.sim.camera import CameraSpec
from odolab.sim.episodes import EpisodeSpec, render_episode, start_environment


def test_driving_the_environment_as_the_generator_does_sees_the_episodes_frames():
    """The follower's look-ahead draws from the actuation stream too, so it drives here as well."""
    from odolab.sim.planner import ShortestPathFollower, geodesic_field

    spec = EpisodeSpec(split="test", index=1, seed=0, max_steps=15, camera=CameraSpec(width=64, height=36))
    ep = render_episode(spec)
    env, begin = start_environment(spec)
    follower = ShortestPathFollower(
        geodesic_field(env.scene, *begin.goal),
        goal_radius=spec.goal_radius,
        noise=env.actuation,
        rng=env.act_rng,
        stop_at_contact=spec.stop_at_contact,
    )
    assert np.allclose(env.camera_pose(), ep.poses[0]) and begin.goal == tuple(ep.info["goal"])
    first = env.observe()
    assert np.array_equal(first.rgb, ep.rgb[0]) and np.array_equal(first.depth, ep.depth[0])
    for t, a in enumerate(ep.actions):
        assert follower.next_action(env.state) is Action(int(a))
        collided = env.step(Action(int(a)))
        frame = env.observe(timestamp=t + 1.0)
        assert collided == bool(ep.collisions[t])
        assert np.array_equal(frame.rgb, ep.rgb[t + 1]) and np.array_equal(frame.depth, ep.depth[t + 1])
        assert np.array_equal(frame.gt_pose, ep.poses[t + 1])
    assert env.steps == len(ep.actions) and env.collisions == int(ep.collisions.sum())
    with pytest.raises(ValueError, match="motion action"):
        env.step(Action.STOP)
    blind, _ = start_environment(spec, sensors=False)
    with pytest.raises(RuntimeError, match="no sensors"):
        blind.observe()


def test_sensors_give_the_same_frames_with_the_depth_path_in_a_second_thread():
    """The two-thread reading is an optimisation only: bit for bit the one-thread frames, in order."""
    from odolab.core.geometry import camera_pose_from_agent
    from odolab.sim.environment import Sensors
    from odolab.sim.scenes import generate_scene, scene_seed

    scene = generate_scene(scene_seed("test", 0))
    cam = CameraSpec(width=96, height=54)
    cells = np.argwhere(scene.navigable)[::97][:6]
    poses = [camera_pose_from_agent(*scene.cell_to_world(*c), 0.7 * k, cam.mount_height) for k, c in enumerate(cells)]
    one, two = (
        Sensors(scene, cam, 1.0, 1.0, np.random.default_rng(3), np.random.default_rng(4), threads=n) for n in (1, 2)
    )
    for p in poses:
        a, b = one.read(p), two.read(p)
        for field in ("clean_rgb", "clean_depth", "rgb", "depth"):
            assert np.array_equal(getattr(a, field), getattr(b, field)), field
    assert (a.depth > 0).any() and a.rgb.std() > 0  # real frames, not empty ones
    import multiprocessing

    child = multiprocessing.get_context("fork").Process(target=two.read, args=(poses[0],))
    child.start()  # a forked child has no copy of the depth thread: it must make its own, not hang
    child.join(60)
    if child.is_alive():
        child.kill()
    assert child.exitcode == 0
    two.close()
    two.close()  # twice is harmless
    assert np.array_equal(two.read(poses[0]).depth, one.read(poses[0]).depth)  # after close: one thread
    for bad in (3, True, 2.0):
        with pytest.raises(ValueError, match="threads must be the integer 1 or 2"):
            Sensors(scene, cam, 1.0, 1.0, np.random.default_rng(3), np.random.default_rng(4), threads=bad)
