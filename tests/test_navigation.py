"""Closed-loop navigation: the goal update of eq. 1, and an agent with true odometry reaching the goal."""
from __future__ import annotations

import numpy as np

from odolab.api import Action, invert, load_odometer
from odolab.episodes import EpisodeSpec, render_episode, rollout
from odolab.navigation.agent import MapPlanAgent
from odolab.navigation.episode import _start_frame_goal, navigate


def test_the_goal_follows_the_true_relative_goal_when_the_odometry_is_true():
    spec = EpisodeSpec(split="test", index=3, seed=0, max_steps=40)
    motion = rollout(spec)
    ep = render_episode(spec, motion)
    start = motion.states[0]
    agent = MapPlanAgent(_start_frame_goal(start, motion.goal), ep.intrinsics, spec.camera.mount_height)
    for t in range(len(ep.actions)):
        agent.update(invert(ep.poses[t]) @ ep.poses[t + 1])
        s = motion.states[t + 1]
        dx, dy = motion.goal[0] - s.x, motion.goal[1] - s.y
        truth = np.array([np.cos(s.yaw) * dx + np.sin(s.yaw) * dy, -np.sin(s.yaw) * dx + np.cos(s.yaw) * dy])
        assert np.allclose(agent.relative_goal(), truth, atol=1e-6)
    assert any(Action(int(a)) is not Action.MOVE_FORWARD for a in ep.actions)  # turns were checked too


def test_an_agent_with_true_odometry_stops_at_the_goal():
    run = navigate(EpisodeSpec(split="test", index=1, seed=0, max_steps=100), load_odometer("ground-truth"))
    o = run.outcome
    assert o.stopped and o.success == 1.0 and 0.5 < o.spl <= 1.0 and run.failed_steps == 0
    assert np.allclose(run.true_xy, run.believed_xy, atol=1e-6)
    again = navigate(EpisodeSpec(split="test", index=1, seed=0, max_steps=100), load_odometer("ground-truth"))
    assert np.array_equal(again.true_xy, run.true_xy)  # same seed, same run


def test_an_agent_with_the_action_prior_believes_a_different_path():
    run = navigate(EpisodeSpec(split="test", index=1, seed=0, max_steps=60), load_odometer("action-prior"))
    assert np.abs(run.true_xy - run.believed_xy).max() > 0.05
