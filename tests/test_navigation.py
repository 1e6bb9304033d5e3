"""Closed-loop navigation: the goal update of eq. 1, and an agent with true odometry reaching the goal;
the navigate command's checks of a folder's config.json, failed steps on its console, the policy's
numbers and the metrics figure's legend."""

from __future__ import annotations

import dataclasses
import html
import json
import os
from pathlib import Path

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg

from odolab.api import Action, invert, load_odometer, register_odometer
from odolab.cli import run_cli
from odolab.core.parallel import SERIAL
from odolab.navigation.agent import MapPlanAgent, OccupancyMap, in_agent_frame
from odolab.navigation.episode import navigate
from odolab.sim.camera import CameraSpec
from odolab.sim.episodes import EpisodeSpec, render_episode, rollout
from tests.helpers import Never, captured_figures, command_argv, outside_folder, refused, stderr_line


def test_the_goal_follows_the_true_relative_goal_when_the_odometry_is_true():
    spec = EpisodeSpec(split="test", index=3, seed=0, max_steps=40)
    motion = rollout(spec)
    ep = render_episode(spec, motion)
    start = motion.states[0]
    agent = MapPlanAgent(
        tuple(in_agent_frame(motion.goal, start.x, start.y, start.yaw)), ep.intrinsics, spec.camera.mount_height
    )
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


@pytest.mark.slow
def test_an_agent_with_the_action_prior_believes_a_different_path():
    run = navigate(EpisodeSpec(split="test", index=1, seed=0, max_steps=60), load_odometer("action-prior"))
    assert np.abs(run.true_xy - run.believed_xy).max() > 0.05


def test_an_odometer_that_hangs_or_cannot_say_if_it_is_an_oracle_fails_its_steps_not_the_episode():
    """navigate asks under the runner's guards: a step past the time limit and an ``oracle`` that
    raises are failed steps (the action prior moves the belief), not a hang or a traceback."""
    import threading

    release = threading.Event()

    class Hanging(Never):
        def step(self, prev, cur, action):
            release.wait(10)

    class NoIdea(Never):
        @property
        def oracle(self):
            raise RuntimeError("cannot tell")

    spec = EpisodeSpec(split="test", index=1, seed=0, max_steps=6, camera=CameraSpec(width=48, height=27))
    prior = navigate(spec, load_odometer("action-prior"))
    try:
        for odometer, said in ((Hanging(), "step 0: timed out after 0.02 s"), (NoIdea(), "reading oracle raised")):
            run = navigate(spec, odometer, step_timeout=0.02)
            assert run.failed_steps == run.outcome.steps == prior.outcome.steps
            assert np.array_equal(run.believed_xy, prior.believed_xy)
            assert said in run.errors[0]  # why, for the command's note
    finally:
        release.set()


def test_a_boxed_in_agent_backs_out_instead_of_pushing_into_the_wall():
    """In a dead-end pocket (walls 0.15 m ahead and to both sides, the goal beyond the end wall)
    every cell around the agent is inside the walls' inflated band, so the planner has no finite
    cost; the agent must take an open heading (back out), not push on towards the goal for ever."""
    from odolab.navigation.agent import PolicyConfig
    from odolab.sim.camera import CameraSpec

    cam = CameraSpec(width=32, height=18)
    agent = MapPlanAgent((2.0, 0.0), cam.intrinsics, cam.mount_height, PolicyConfig())
    xs = np.arange(-1.0, 0.2, 0.02)
    ys = np.arange(-0.17, 0.19, 0.02)
    wall_x = np.concatenate([xs, xs, np.full(ys.shape, 0.17)])
    wall_y = np.concatenate([np.full(xs.shape, 0.17), np.full(xs.shape, -0.17), ys])
    agent.map.vote(wall_x, wall_y, weight=5)
    blind = np.zeros((cam.height, cam.width), np.float32)  # no new readings
    assert agent.act(blind) in (Action.TURN_LEFT, Action.TURN_RIGHT)
    heads = np.radians(np.arange(-180, 180, 10.0))
    open_way = agent._open_headings(0.0, 0.0, heads)
    assert not open_way[heads == 0].any() and open_way[np.isclose(np.abs(heads), np.pi)].all()


def test_a_gap_the_map_narrowed_is_taken_by_the_fallback_plan():
    """A wall across the whole map with one 0.3 m gap, narrower than the agent (0.36 m): the full
    agent has no way to the goal and heads for the goal's direction, into the wall; with
    ``fallback_radius`` it plans as a narrower agent and turns towards the gap."""
    from odolab.navigation.agent import PolicyConfig
    from odolab.sim.camera import CameraSpec

    cam = CameraSpec(width=32, height=18)
    blind = np.zeros((cam.height, cam.width), np.float32)
    ys = np.arange(-6.0, 6.0, 0.02)
    ys = ys[(ys < 0.6) | (ys > 0.9)]
    actions = {}
    for fallback in (0.0, 0.1):
        agent = MapPlanAgent(
            (3.0, 0.0), cam.intrinsics, cam.mount_height, PolicyConfig(extent=2.0, fallback_radius=fallback)
        )
        agent.map.vote(np.full(ys.shape, 1.0), ys, weight=5)
        actions[fallback] = agent.act(blind)
    assert actions == {0.0: Action.MOVE_FORWARD, 0.1: Action.TURN_LEFT}
    with pytest.raises(ValueError, match="need fallback_radius < agent_radius"):
        PolicyConfig(fallback_radius=0.18)


def _full_march(agent, radius):
    """The plain reference for ``_costs``: fast marching over the whole map, nothing cut short."""
    import skfmm
    from scipy.ndimage import distance_transform_edt

    cfg, m = agent.cfg, agent.map
    obstacle = m.obstacles(cfg.votes, cfg.memory)
    clearance = distance_transform_edt(~obstacle) * cfg.cell if obstacle.any() else np.full(obstacle.shape, np.inf)
    blocked = clearance < radius
    speed = np.where(clearance < radius + cfg.margin, cfg.margin_speed, 1.0)
    gr, gc, _ = m.to_cell(*agent.goal)
    k = int(np.ceil((radius + cfg.margin) / cfg.cell))
    blocked[max(gr - k, 0) : gr + k + 1, max(gc - k, 0) : gc + k + 1] = False
    speed[max(gr - k, 0) : gr + k + 1, max(gc - k, 0) : gc + k + 1] = 1.0
    wx, wy = m.to_world(np.arange(m.n), np.arange(m.n))
    phi = np.hypot(wx[None, :] - agent.goal[0], wy[:, None] - agent.goal[1]) - cfg.cell
    return np.ma.filled(
        skfmm.travel_time(np.ma.MaskedArray(phi, mask=blocked), speed, dx=cfg.cell).astype(np.float64), np.inf
    )


@pytest.mark.parametrize("clutter", [60, 0])
def test_the_cut_short_march_gives_the_full_march_times_to_the_bit(clutter):
    """``_costs`` skips unreachable cells, takes obstacle distances in a box round the obstacles
    and stops the march early; on a map with a wall that cuts it in two, a long wall between the
    agent and the goal, and random clutter (or none, so the box is small) its times equal a plain
    full fast march's exactly, including cells only the second, uncut march reaches."""
    from odolab.navigation.agent import PolicyConfig
    from odolab.sim.camera import CameraSpec

    cam = CameraSpec(width=32, height=18)
    cfg = PolicyConfig(extent=2.0)
    agent = MapPlanAgent((2.0, 0.5), cam.intrinsics, cam.mount_height, cfg)
    rng = np.random.default_rng(3)
    m = agent.map
    agent.map.vote(rng.uniform(-m.half, m.half, clutter), rng.uniform(-m.half, m.half, clutter), weight=5)
    ys = np.arange(-m.half, m.half, 0.02)
    agent.map.vote(np.full(ys.shape, -1.0), ys, weight=5)  # cells left of x = -1 have no way to the goal
    hook = np.arange(-3.3, 3.3, 0.02)
    agent.map.vote(np.full(hook.shape, 1.2), hook, weight=5)  # a long wall between the agent and the goal
    r, c = np.mgrid[0 : m.n : 7, 0 : m.n : 7]
    near_r, near_c, _ = m.to_cell(np.full(5, 0.9), np.linspace(0.0, 1.0, 5))  # 1.1 m from the goal, 8 m round
    r, c = np.concatenate([r.ravel(), near_r]), np.concatenate([c.ravel(), near_c])
    for radius in (cfg.agent_radius, 0.1):
        full = _full_march(agent, radius)
        got = agent._costs(0.0, 0.0, None, radius, r, c)
        assert np.array_equal(got, full[r, c])
        finite = np.isfinite(got)
        assert finite.any() and (~finite).any()
        near = agent._costs(0.0, 0.0, None, radius, r[-5:], c[-5:])  # asked alone, their first march stops short
        assert np.array_equal(near, full[r[-5:], c[-5:]])
        for hint in (0.3, 1.5, 50.0):  # a stop short of every cell, of some, of none
            assert np.array_equal(agent._costs(0.0, 0.0, None, radius, r[-5:], c[-5:], hint), near)
            assert np.array_equal(agent._costs(0.0, 0.0, None, radius, r, c, hint), got)
        straight = np.hypot(*(np.array(m.to_world(r[-5:], c[-5:])).T - agent.goal).T)
        assert np.isfinite(near).any() and (near[np.isfinite(near)] > 2 * straight.max() + 2.0).all()
    window = agent._costs(0.0, 0.0, 1.0, cfg.agent_radius, r, c)  # a 1 m window: cells off it are inf
    assert np.isinf(window[(r < m.to_cell(0.0, 0.0)[0] - 25) | (c < m.to_cell(0.0, 0.0)[1] - 25)]).all()


def test_bilinear_reads_whole_positions_exactly_and_skips_infinite_corners():
    from odolab.navigation.agent import _bilinear

    grid = np.array([[0.1, 1.0, np.inf], [2.0, 3.0, 4.0], [np.inf, np.inf, np.inf]])
    whole = _bilinear(grid, np.array([0.0, 1.0, 1.0, 0.0, 2.0]), np.array([0.0, 2.0, 0.0, 2.0, 1.0]))
    assert np.array_equal(whole, [0.1, 4.0, 2.0, np.inf, np.inf])
    mid = _bilinear(grid, np.array([0.5, 0.5, 1.5]), np.array([0.5, 1.5, 0.5]))
    assert mid[0] == pytest.approx((0.1 + 1.0 + 2.0 + 3.0) / 4)
    assert mid[1] == pytest.approx((1.0 + 3.0 + 4.0) / 3)  # the infinite corner's weight dropped
    assert mid[2] == pytest.approx(2.5)  # only the finite upper row


def test_occupancy_map_obstacles_follow_each_vote_and_step():
    m = OccupancyMap(1.0, 0.1)
    assert not m.obstacles(2, 5).any()
    m.vote(np.array([0.05]), np.array([0.05]))
    assert not m.obstacles(2, 5).any()
    m.vote(np.array([0.05]), np.array([0.05]))
    assert m.obstacles(2, 5).sum() == 1 and m.obstacles(1, 5).sum() == 1
    m.step += 6
    assert not m.obstacles(2, 5).any() and m.obstacles(2, 6).sum() == 1
    with pytest.raises(ValueError):
        m.obstacles(2, 5)[0, 0] = True  # shared until the next change: read-only


@pytest.mark.parametrize("step", [2, 4])
def test_map_plan_agent_costs_with_a_coarse_far_field_follow_the_fine_march(step):
    """``plan_step`` > 1: beyond ``fine_radius`` the march runs on blocks, near the agent on every
    cell. Round an agent 5 m from the goal with a wall between, its heading costs are not the fine
    march's to the bit (so the two-level march ran), differ from them by a few blocks at most, and
    pick the same heading; within ``fine_radius`` of the goal the march is the fine one."""
    from odolab.navigation.agent import PolicyConfig

    cam = CameraSpec(width=32, height=18)
    headings = np.radians(np.arange(-180, 180, 10.0))
    costs, near = {}, {}
    for plan_step in (1, step):
        agent = MapPlanAgent(
            (4.0, 0.5), cam.intrinsics, cam.mount_height, PolicyConfig(extent=2.0, plan_step=plan_step)
        )
        wall = np.arange(-1.0, 1.6, 0.02)
        agent.map.vote(np.full(wall.shape, 1.0), wall, weight=5)  # a wall between the agent and the goal
        r, c, _ = agent.map.to_cell(-1.0 + 0.25 * np.cos(headings), 0.25 * np.sin(headings))
        costs[plan_step] = agent._costs(-1.0, 0.0, None, agent.cfg.agent_radius, r, c)
        r, c, _ = agent.map.to_cell(3.0 + 0.25 * np.cos(headings), 0.25 * np.sin(headings))
        near[plan_step] = agent._costs(3.0, 0.0, None, agent.cfg.agent_radius, r, c)
    fine, coarse = costs[1], costs[step]
    assert np.isfinite(fine).all() and np.isfinite(coarse).all() and not np.array_equal(fine, coarse)
    assert np.abs(coarse - fine).max() < 2 * step * 0.05 + 0.05
    assert np.argmin(coarse) == np.argmin(fine)
    assert np.array_equal(near[step], near[1])


def test_map_plan_agent_with_plan_every_marches_every_nth_step_or_when_the_last_field_has_no_time(monkeypatch):
    """``plan_every`` 3: the agent marches on its first step and every third after, reading the last
    field between (its heading costs are that field's times); a field with no time at any open
    heading (the agent moved off its box) makes it march at once."""
    from odolab.navigation import agent as agent_module
    from odolab.navigation.agent import PolicyConfig

    cam = CameraSpec(width=32, height=18)
    marches = []
    costs = agent_module.MapPlanAgent._costs
    monkeypatch.setattr(
        agent_module.MapPlanAgent, "_costs", lambda self, *a: marches.append(self.map.step) or costs(self, *a)
    )
    agent = MapPlanAgent((4.0, 0.5), cam.intrinsics, cam.mount_height, PolicyConfig(extent=2.0, plan_every=3))
    empty = np.zeros((cam.height, cam.width), np.float32)  # sees nothing: the map stays empty
    for _ in range(7):
        agent.act(empty)
    assert marches == [1, 4, 7]
    r, c, _ = agent.map.to_cell(np.array([-0.25]), np.array([0.0]))  # a heading's cell (behind the agent)
    assert agent._field is not None and np.isfinite(agent._field.at(r, c)).all()
    agent.act(empty)
    assert marches == [1, 4, 7]  # read from the last field
    agent._field = agent_module._Field(agent._field.times[:3, :3], (0, 0))  # a box far from the agent
    agent.act(empty)
    assert marches == [1, 4, 7, 9]


def test_a_saved_policy_without_a_parameter_differs_and_gets_no_suggestion():
    from odolab.cli.navigate import SETTING_OPTIONS
    from odolab.navigation.agent import PolicyConfig
    from odolab.navigation.study import _policy_changes, _policy_to_match

    def changes(saved, policy):  # as the command line words them
        return [c.named(SETTING_OPTIONS) for c in _policy_changes(saved, policy)]

    def to_match(saved, policy):
        return " ".join(m.named(SETTING_OPTIONS) for m in _policy_to_match(saved, policy)) or None

    full = dataclasses.asdict(PolicyConfig())
    lacking = {k: v for k, v in full.items() if k != "fallback_radius"}
    assert changes(full, full) == []
    assert changes(lacking, full) == ["--policy fallback_radius (not recorded there, 0.1 now)"]
    assert to_match(lacking, full) is None  # nothing to set: that folder was made by another version
    assert to_match({**full, "cell": 0.1}, full) == "--policy cell=0.1"
    assert to_match({**full, "cell": 5.0}, full) is None  # out of range
    assert to_match({**full, "cell": "0.05"}, full) is None  # not a number
    assert to_match({**full, "nonsense": 1}, full) is None
    for hand_edited, there in (("0.0", "'0.0' there"), (False, "False there"), ("x" * 99, "there")):
        said = changes({**full, "fallback_radius": hand_edited}, full)
        assert len(said) == 1 and there in said[0] and said[0].endswith(", 0.1 now)") and len(said[0]) < 120


def test_a_folder_of_another_format_is_refused_with_how_to_run_it_again(tmp_path, capsys):
    out = tmp_path / "nav"
    out.mkdir()
    (out / "config.json").write_text('{"options": {}, "episodes": [], "policy": {}}')
    code = _navigate(["--odometers", "action-prior", "--episodes", "1", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "with no format number; this odolab writes format 1" in err and "delete the folder" in err
    assert len(err.strip().splitlines()) == 1


def _navigate(argv):
    from odolab.navigate import main

    return run_cli(main, "python -m odolab.navigate", [str(a) for a in argv])


@pytest.mark.slow
def test_the_navigate_command_is_deterministic_and_resumes(tmp_path, capsys):
    args = ["--odometers", "ground-truth,action-prior", "--episodes", "2", "--max-steps", "12", "--serial", "--quiet"]
    assert _navigate(args + ["--out", str(tmp_path / "a")]) == 0
    assert _navigate(args + ["--out", str(tmp_path / "b")]) == 0
    a = (tmp_path / "a" / "nav.csv").read_text()
    assert a == (tmp_path / "b" / "nav.csv").read_text() and a.count("\n") == 3
    assert (tmp_path / "a" / "metrics.png").stat().st_size > 10_000
    assert (
        "<code>fallback_radius</code></td><td>0.1</td>" in (tmp_path / "a" / "report.html").read_text()
    )  # the policy, defaults included
    done = sorted((tmp_path / "a" / "episodes").rglob("*.json"))
    assert len(done) == 4
    done[2].unlink()  # an interrupted run: one episode missing
    done[0].write_text('{"odometer": "act')  # and two files of one odometer damaged
    done[1].write_text("{}")
    assert _navigate(args + ["--out", str(tmp_path / "a")]) == 0
    assert (tmp_path / "a" / "nav.csv").read_text() == a
    notes = [line for line in capsys.readouterr().err.splitlines() if line.startswith("note:")]
    assert len(notes) == 2 and "2 saved episode(s)" in notes[0] and "are damaged" in notes[0]  # one line per odometer
    assert notes[1].endswith("1 of 4 episode(s) were saved in " + str(tmp_path / "a") + " already; running the other 3")
    assert _navigate(args + ["--out", str(tmp_path / "a")]) == 0
    assert (
        "4 of 4 episode(s) were saved in " + str(tmp_path / "a") + " already; nothing to run" in capsys.readouterr().err
    )
    # other episodes into the same folder are refused, naming what differs; so is another policy
    assert _navigate(args[:4] + ["--max-steps", "13", "--serial", "--quiet", "--out", str(tmp_path / "a")]) == 2
    assert "other settings (--max-steps (12 there, 13 now))" in capsys.readouterr().err
    assert _navigate(args + ["--policy", "heading_tolerance=45", "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err
    assert "other settings (--policy heading_tolerance (15.0 there, 45.0 now))" in err
    assert "to add to it, pass --policy heading_tolerance=15.0;" in err  # the way to the folder's policy
    assert _navigate(args + ["--policy", "heading_tolerance=45", "--out", str(tmp_path / "c")]) == 0
    config = json.loads((tmp_path / "c" / "config.json").read_text())
    assert config["policy"]["heading_tolerance"] == 45.0
    # the coarse far field, recorded only where it is on, is compared as any other parameter
    assert _navigate(args + ["--policy", "plan_step=2", "--out", str(tmp_path / "a")]) == 2
    assert "other settings (--policy plan_step (1 there, 2 now)); to add to it, pass --policy plan_step=1;" in (
        capsys.readouterr().err
    )
    far = ["--policy", "plan_step=2", "--policy", "fine_radius=1"]
    assert _navigate(args + far + ["--out", str(tmp_path / "d")]) == 0
    assert _navigate(args + ["--out", str(tmp_path / "d")]) == 2
    assert (
        "(--policy fine_radius (1.0 there, 2.0 now), --policy plan_step (2 there, 1 now)); to add to it, pass "
        "--policy fine_radius=1.0 --policy plan_step=2;" in capsys.readouterr().err
    )
    assert _navigate(args + ["--policy", "fine_radius=3", "--out", str(tmp_path / "e")]) == 2
    assert "fine_radius only matters with plan_step > 1" in capsys.readouterr().err


def test_navigate_keeps_out_of_folders_it_did_not_make(tmp_path, capsys):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "report.html").write_text("precious")
    assert (
        _navigate(
            [
                "--odometers",
                "ground-truth",
                "--episodes",
                "1",
                "--max-steps",
                "5",
                "--serial",
                "--quiet",
                "--out",
                str(tmp_path / "mine"),
            ]
        )
        == 2
    )
    assert "did not write" in capsys.readouterr().err and (tmp_path / "mine" / "report.html").read_text() == "precious"


def test_navigate_refuses_bad_input_in_one_line(tmp_path, capsys):
    for argv, words in [
        (["--odometers", "nope"], "unknown odometer 'nope'"),
        (["--odometers", "icp,icp"], "names 'icp' twice"),
        (["--episodes", "0"], "--episodes"),
        (["--split", "moon"], "not a split"),
        (["--odometers", "fused(icp"], "unbalanced"),
        (["--policy", "nope=1"], "key one of cell, stride"),
        (["--policy", "heading_tolerance"], "expected key=value"),
        (["--policy", "stride=1.5"], "stride takes a whole number in [1, 64]"),
        (["--policy", "stop_distance=nan"], "stop_distance must be in [0.01, 10]"),
        (["--policy", "cell=1e-6"], "cell must be in [0.02, 1]"),
        (["--policy", "votes=99999999999999999999999"], "votes must be in [1, 1000]"),
        (["--policy", "obstacle_gap=50"], "obstacle_gap must be in [0, 0.5]"),
        (["--policy", "stride=" + "1" * 5000], "this value is too long to read"),
        (["--policy", "cell=0.05" + "0" * 40], "cell takes a number in [0.02, 1]; this value is too long"),
        (["--policy", "memory=x"], "memory takes a whole number in [1, 1000000]"),
        (["--policy", "margin_speed=abc"], "margin_speed takes a number in (0, 1]"),
        (["--policy", "cell=0.1", "--policy", "cell=0.2"], "cell is given twice"),
        (["--policy", "heading_tolerance=180"], "heading_tolerance must be in [0, 180)"),
        (["--policy", "votes=\u0663"], "votes takes a whole number in [1, 1000]"),
        (["--policy", "votes=1_0"], "votes takes a whole number in [1, 1000]"),
        (["--policy", "fallback_radius=1"], "fallback_radius must be in [0, 1)"),
        (["--policy", "fallback_radius=0.2"], "need fallback_radius < agent_radius"),
        (
            ["--policy", "agent_radius=0.1"],
            "fallback_radius 0.1 (its default) and agent_radius 0.1: set fallback_radius below 0.1, or to 0",
        ),
    ]:
        assert _navigate(argv + ["--out", str(tmp_path / "x"), "--serial"]) == 2
        err = capsys.readouterr().err
        assert words in err and "Traceback" not in err


@pytest.mark.slow
def test_navigation_runs_unchanged_on_a_two_node_ray_cluster(tmp_path, ray_cluster):
    """A local two-node cluster (ray.cluster_utils): the same command through its address gives the
    same table as a serial run."""
    args = ["--odometers", "ground-truth", "--episodes", "2", "--max-steps", "8", "--quiet"]
    assert _navigate(args + ["--serial", "--out", str(tmp_path / "serial")]) == 0
    assert _navigate(args + ["--ray-address", ray_cluster, "--out", str(tmp_path / "cluster")]) == 0
    assert (tmp_path / "cluster" / "nav.csv").read_text() == (tmp_path / "serial" / "nav.csv").read_text()


def test_a_saved_episode_of_another_model_file_is_run_again(tmp_path, capsys):
    import json

    from odolab.navigation.agent import PolicyConfig
    from odolab.navigation.study import ROW_KEYS, NavTask, read_row

    spec = EpisodeSpec(split="test", index=3, max_steps=1)  # the one step ran out the episode: stopped false
    row = {k: 0 for k in ROW_KEYS} | {
        "odometer": "robust-vo",
        "episode": 3,
        "split": "test",
        "stopped": False,
        "weights": "a" * 64,
        "steps": 1,
        "d0": 1.0,
        "d_end": 1.0,
        "path": 0.25,
        "goal": [1.0, 2.0],
        "true_xy": [[0, 0], [0.25, 0]],
        "believed_xy": [[0, 0], [0.2, 0]],
    }
    path = tmp_path / "0003.json"
    path.write_text(json.dumps(row))
    assert read_row(path, NavTask("robust-vo", {}, spec, PolicyConfig(), "a" * 64)) == row
    rejected = []
    assert read_row(path, NavTask("robust-vo", {}, spec, PolicyConfig(), "b" * 64), rejected) is None  # retrained
    assert rejected == [path]
    for bad in ({"success": float("nan")}, {"spl": 7}, {"true_xy": "x"}, {"steps": 5}, {"d0": -1}):
        path.write_text(json.dumps(row | bad))  # values no run can have: run again, no traceback
        assert read_row(path, NavTask("robust-vo", {}, spec, PolicyConfig(), "a" * 64)) is None
    folder = tmp_path / "0004.json"
    folder.mkdir()  # a folder where a result file belongs: refused by name (no "Is a directory" later)
    with pytest.raises(ValueError, match="0004.json is a folder where an episode's result file belongs"):
        read_row(folder, NavTask("robust-vo", {}, spec, PolicyConfig(), "a" * 64))
    # the odometers say which model file or settings they use; a fused one through its inputs
    assert load_odometer("robust-vo").identity_digest and load_odometer("action-prior").identity_digest is None
    assert (
        load_odometer("icp").identity_digest
        == load_odometer("icp").identity_digest
        != load_odometer("icp", voxel=0.05).identity_digest
    )
    assert load_odometer("fused(icp,robust-vo)").identity_digest not in (
        None,
        load_odometer("robust-vo").identity_digest,
    )
    fused = load_odometer("fused(icp,robust-vo)").identity_digest
    assert load_odometer("fused(icp,robust-vo)", options_file=_icp_options(tmp_path)).identity_digest != fused


def _icp_options(folder) -> str:
    path = folder / "icp.toml"
    path.write_text('[odometers."icp"]\nvoxel = 0.05\n')
    return str(path)


def test_navigate_refuses_a_file_where_its_result_folders_belong(tmp_path):
    """Checked before any episode runs (not when the first result is written, losing the episode);
    a config.json whose options are not an object is not a navigation config."""
    import json

    from odolab.navigation.agent import PolicyConfig
    from odolab.navigation.study import NavTask, config_doc, run_navigation

    spec = EpisodeSpec(split="test", index=0, max_steps=5)
    task = NavTask("ground-truth", {}, spec, PolicyConfig(), None)
    config = config_doc(["ground-truth"], {}, [spec], PolicyConfig())
    for where in ("episodes", "episodes/ground-truth"):
        out = tmp_path / where.replace("/", "-")
        (out / where).parent.mkdir(parents=True, exist_ok=True)
        (out / where).write_text("x")
        (out / "config.json").write_text(json.dumps(config))
        with pytest.raises(ValueError, match=f"{where} is a file where navigate keeps a folder"):
            run_navigation(out, [task], config, execution=SERIAL)
    out = tmp_path / "cfg"
    out.mkdir()
    (out / "config.json").write_text(json.dumps({**config, "options": []}))
    with pytest.raises(ValueError, match="not a navigation config"):
        run_navigation(out, [task], config, execution=SERIAL)
    (out / "config.json").unlink()
    os.mkfifo(out / "config.json")  # read, it would block for ever
    with pytest.raises(ValueError, match="config.json: is a pipe, device or socket"):
        run_navigation(out, [task], config, execution=SERIAL)


def test_a_saved_episode_with_infinities_is_run_again_and_a_pipe_refused(tmp_path, capsys):
    import json

    from odolab.navigation.agent import PolicyConfig
    from odolab.navigation.study import ROW_KEYS, NavTask, read_row

    spec = EpisodeSpec(split="test", index=3, max_steps=1)
    task = NavTask("icp", {}, spec, PolicyConfig(), None)
    row = {k: 0 for k in ROW_KEYS} | {
        "odometer": "icp",
        "episode": 3,
        "split": "test",
        "stopped": False,
        "steps": 1,
        "d0": 1.0,
        "d_end": 1.0,
        "path": 0.25,
        "goal": [1.0, 2.0],
        "true_xy": [[0, 0], [0.25, 0]],
        "believed_xy": [[0, 0], [0.2, 0]],
    }
    path = tmp_path / "0003.json"
    path.write_text(json.dumps(row))
    assert read_row(path, task) == row
    for change in (
        {"believed_xy": [[0, 0], ["0.2", 0]]},
        {"believed_xy": [[0, 0], [True, False]]},
        {"believed_xy": [[0, 0], [1e300, 0]]},
        {"believed_xy": [[0.1, 0], [0.2, 0]]},
        {"stopped": "no"},
        {"episode": True},
        {"episode": 3.0},
        {"split": "val"},
        {"seed": 1},
    ):
        path.write_text(json.dumps(row | change))  # each a value no run of this task writes
        assert read_row(path, task) is None, change
    for key in ("split", "seed"):
        path.write_text(json.dumps({k: v for k, v in row.items() if k != key}))
        assert read_row(path, task) is None, key
    for bad in ('{"d0": 1e400}', '{"path": 1e400}', '{"steps": ' + "9" * 5000 + "}"):
        path.write_text(json.dumps(row)[:-1] + ", " + bad[1:])  # the key again, last: the reader refuses both
        assert read_row(path, task) is None
        path.write_text(json.dumps(row | json.loads(bad)) if len(bad) < 100 else bad)
        assert read_row(path, task) is None
    path.unlink()
    os.mkfifo(path)  # not read (it would block), and refused before any episode runs: no result could replace it
    with pytest.raises(ValueError, match="0003.json is not a regular file"):
        read_row(path, task)
    path.unlink()
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    for target in ("/dev/zero", victim, tmp_path / "nowhere"):  # the rerun's result would be written through it
        path.symlink_to(target)
        with pytest.raises(ValueError, match="0003.json is a symbolic link"):
            read_row(path, task)
        path.unlink()
    assert victim.read_text() == "precious"


def test_the_tables_quote_fused_names():
    import csv
    import io

    from odolab.navigation.report import _csv

    text = _csv([{"odometer": "fused(icp,robust-vo)", "success": 0.5}], ["odometer", "success"])
    assert list(csv.DictReader(io.StringIO(text))) == [{"odometer": "fused(icp,robust-vo)", "success": "0.5000"}]


def test_the_markdown_table_bolds_the_best_non_oracle_row():
    from odolab.navigation.report import markdown_table, summarize

    def row(name, success, failed):
        return {
            "odometer": name,
            "success": success,
            "spl": 0.5 * success,
            "soft_spl": 0.6,
            "d_end": 1.0,
            "belief_error": 0.2,
            "steps": 100,
            "collisions": 3,
            "failed_steps": failed,
            "stopped": True,
            "path": 2.0,
        }

    rows = [
        row("ground-truth", 1, 0),
        row("ground-truth", 1, 0),
        row("a|b", 1, 50),
        row("a|b", 0, 0),
        row("c", 0, 0),
        row("c", 0, 0),
        row("d", 0, 0),
    ]
    lines = markdown_table(summarize(rows, ["ground-truth", "a|b", "c", "d", "none"])).splitlines()
    assert lines[0].startswith("| odometer | episodes | success | SPL | SoftSPL |") and len(lines) == 7
    oracle, ab, c, d, none = lines[2:]
    assert "**" not in oracle  # the oracle is not a contender
    assert ab.startswith("| a\\|b | 2 | **0.50 [") and ab.endswith("| 100 | 3.0 | 50 (25 %) |")
    assert c.split(" | ")[2].startswith("0.00 [") and "**" not in ab.split(" | ")[4]  # a tie of all is no best
    assert d.startswith("| d | 1 | 0.00 [") and " | 0.00 | " in d  # one episode: no Student-t interval
    assert none == "| none | 0 | - | - | - | - | - | - | - | 0 |"
    alone = markdown_table(summarize(rows[:4], ["ground-truth", "a|b"]))
    assert "**" not in alone  # one contender is no best


def test_a_refusal_for_changed_options_names_the_key_and_both_values():
    from odolab.navigation.study import _option_changes

    said = _option_changes("open3d-rgbd", {}, {"max_depth": 5.0})
    assert said == "options of open3d-rgbd (max_depth: default there, 5.0 now)"
    said = _option_changes("icp", {"voxel": 0.04, "x": "a" * 500}, {"voxel": 0.05})
    assert "voxel: 0.04 there, 0.05 now" in said and "x: " in said and len(said) < 200


def test_naming_a_default_option_resumes_a_folder_made_without_it(tmp_path, capsys):
    args = [
        "--odometers",
        "manhattan(action-prior)",
        "--episodes",
        "1",
        "--max-steps",
        "4",
        "--serial",
        "--quiet",
        "--out",
        str(tmp_path),
    ]
    assert _navigate(args) == 0
    assert _navigate([*args, "--odometer-option", "manhattan(action-prior).relock_views=5"]) == 0
    assert _navigate([*args, "--odometer-option", "manhattan(action-prior).relock_views=4"]) == 2
    assert "relock_views: default there, 4 now" in capsys.readouterr().err


def test_navigate_adds_each_part_of_its_time_to_the_given_timings():
    parts = {"steps": 2.0}
    run = navigate(
        EpisodeSpec(split="test", index=1, seed=0, max_steps=5), load_odometer("action-prior"), timings=parts
    )
    assert parts["steps"] == 2 + run.outcome.steps
    assert set(parts) == {"policy", "planning", "sensors", "odometer", "steps"}
    assert 0 < parts["planning"] <= parts["policy"]


def test_policy_values_and_reports_are_checked_and_escaped():
    import numpy as np

    from odolab.navigation.agent import PolicyConfig
    from odolab.navigation.report import _html
    from odolab.navigation.study import _policy_changes

    for bad in ("0.1", True, None, float("nan")):
        with pytest.raises(ValueError, match="cell must be a number in"):
            PolicyConfig(cell=bad)
    with pytest.raises(ValueError, match="stride must be a whole number in"):
        PolicyConfig(stride=4.0)
    cfg = PolicyConfig(cell=np.float32(0.25), margin=-0.0)
    assert type(cfg.cell) is float and str(cfg.margin) == "0.0"
    said = [c.named({"policy": "--policy"}) for c in _policy_changes({"cell": 0.05}, {"cell": 0.05, "new_one": 0.1})]
    assert said == ["--policy new_one (not recorded there, 0.1 now)"]
    page = _html([], [], "python -m odolab.navigate --out 'x<i>y&z'")
    assert "x&lt;i&gt;y&amp;z" in page and "<i>" not in page
    from odolab.config import describe, range_text

    page = _html([], [], "cmd", PolicyConfig(cell=0.1))
    for s in describe(PolicyConfig):  # every parameter, with its range and meaning, from the config itself
        assert f"<code>{s.name}</code>" in page and html.escape(s.doc) in page
    assert f"<td><code>cell</code></td><td>0.1</td><td>{range_text(PolicyConfig, 'cell')}</td>" in page


def test_the_navigation_benchmark_accounts_for_its_time():
    from odolab.benchmarks.speed import bench_navigation

    rows = bench_navigation(("ground-truth",), episodes=1, max_steps=3)
    r = rows[0]
    assert r["odometer"] == "ground-truth" and r["episodes"] == 1 and r["max_steps"] == 3 and 1 <= r["steps"] <= 3
    parts = r["policy_ms_per_step"] + r["sensors_ms_per_step"] + r["odometer_ms_per_step"] + r["rest_ms_per_step"]
    assert abs(parts * r["steps_per_s"] / 1000 - 1) < 1e-6  # the parts add up to the whole time
    assert 0 < r["planning_ms_per_step"] <= r["policy_ms_per_step"] and 0 < r["planning_share"] < 1


@pytest.mark.parametrize(
    "config, words",
    [
        ('{"options": {}, "episodes": [], "policy": {}}', "navigation results with no format number; this odolab"),
        ('{"format": 1, "opt', "delete it or choose another --out"),
        (None, "its config.json is a folder, where odolab keeps a file; remove it or choose another --out"),
        ('{"format": 1}', "not a whole navigation config (no 'episodes' and no 'policy' in it)"),
        (
            '{"format": 1, "options": {}, "episodes": 5, "policy": 5}',
            "other settings (the episodes (5 there, not a list of episodes), the policy (5 there, not a table",
        ),
    ],
)
def test_navigate_says_what_is_wrong_with_a_folders_config(tmp_path, capsys, config, words):
    out = tmp_path / "nav"
    out.mkdir()
    if config is None:
        (out / "config.json").mkdir()
        (out / "nav.csv").write_text("odometer\n")
    else:
        (out / "config.json").write_text(config)
    err = refused(capsys, "navigate", command_argv("navigate", out) + ["--serial"])
    assert words in err, err
    assert (out / "config.json").is_dir() if config is None else (out / "config.json").read_text() == config


def test_a_whole_policy_number_may_be_written_in_e_notation():
    from odolab.navigation.agent import PolicyConfig, PolicyError

    assert PolicyConfig.from_assignments(["memory=1e6"]).memory == 1_000_000
    assert PolicyConfig.from_assignments(["votes=2E1"]).votes == 20
    with pytest.raises(PolicyError, match="memory must be in"):
        PolicyConfig.from_assignments(["memory=2e6"])
    with pytest.raises(PolicyError, match="memory takes a whole number"):
        PolicyConfig.from_assignments(["memory=1.5e0"])


def test_the_navigation_metrics_legend_hides_no_bar(monkeypatch):
    from odolab.navigation import report as nav_report

    table = []
    for k, name in enumerate(["ground-truth", "icp", "manhattan(fused(open3d-rgbd,robust-vo,planar-depth))"]):
        row = {"odometer": name, "episodes": 100}
        for m in ("success", "spl", "soft_spl"):
            value = 0.95 if k == 2 else 0.5
            row.update({m: value, f"{m}_low": value - 0.05, f"{m}_high": min(value + 0.05, 1.0)})
        table.append(row)
    figures = captured_figures(monkeypatch, nav_report)
    nav_report.metrics_figure(table, Path("metrics.png"))
    fig = figures[0]
    (ax,) = fig.axes
    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.draw(renderer)
    legend, frame = ax.get_legend().get_window_extent(renderer), ax.get_window_extent(renderer)
    assert not legend.overlaps(frame)


@pytest.mark.slow
def test_the_navigate_console_counts_failed_steps(tmp_path, capsys):
    from odolab.navigate import main as navigate

    register_odometer("test-never", Never)
    args = [
        "--odometers",
        "test-never,action-prior",
        "--episodes",
        "1",
        "--max-steps",
        "3",
        "--serial",
        "--quiet",
        "--out",
        str(tmp_path),
    ]
    assert run_cli(navigate, "python -m odolab.navigate", args) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "failed steps: every one of 3" in next(ln for ln in lines if "test-never:" in ln)
    assert "no failed steps" in next(ln for ln in lines if "action-prior:" in ln)


def test_navigate_writes_nothing_through_a_link_in_its_folder(tmp_path, capsys):
    """One rule for every file navigate writes: nav.md, config.json and a linked episodes folder
    are refused before any episode, as a linked episode file is."""
    args = ["--odometers", "ground-truth", "--episodes", "1", "--max-steps", "3", "--serial", "--quiet"]
    out = tmp_path / "nav"
    assert _navigate(args + ["--out", out]) == 0
    outside = outside_folder(tmp_path)
    for rel, target in (
        ("nav.md", outside / "victim.tum"),
        ("config.json", outside / "config.json"),
        ("episodes/ground-truth", outside / "episodes"),
    ):
        original = out / rel
        moved = tmp_path / "moved"
        original.rename(moved)
        if moved.is_dir():
            import shutil

            shutil.copytree(moved, target)
        elif rel == "config.json":
            target.write_text(moved.read_text())
        original.symlink_to(target)
        before = {p: p.read_bytes() for p in outside.rglob("*") if p.is_file()}
        assert _navigate(args + ["--out", out]) == 2, rel
        stderr_line(capsys, rel, "found a symbolic link to")
        assert {p: p.read_bytes() for p in outside.rglob("*") if p.is_file()} == before, rel
        original.unlink()
        moved.rename(original)
    assert _navigate(args + ["--out", out]) == 0


def test_policy_config_record_names_the_far_field_and_plan_every_only_where_they_are_on():
    """Saved runs (unit keys, a folder's config.json) made before ``plan_step`` and ``plan_every``
    existed name the default policy: its record leaves out the coarse far field's two parameters at
    plan_step 1 and plan_every at 1, and keeps them when on."""
    from odolab.navigation.agent import PolicyConfig

    default = PolicyConfig().record()
    added = ("plan_step", "fine_radius", "plan_every")
    assert not set(added) & set(default)
    assert default == {k: v for k, v in dataclasses.asdict(PolicyConfig()).items() if k not in added}
    assert PolicyConfig(plan_step=2).record() == {
        k: v for k, v in dataclasses.asdict(PolicyConfig(plan_step=2)).items() if k != "plan_every"
    }
    assert PolicyConfig(plan_every=3).record() == {
        k: v for k, v in dataclasses.asdict(PolicyConfig(plan_every=3)).items() if k not in ("plan_step", "fine_radius")
    }
    with pytest.raises(ValueError, match="fine_radius only matters with plan_step > 1"):
        PolicyConfig(fine_radius=3.0)  # it would have no effect
    assert PolicyConfig.completed(default) == dataclasses.asdict(PolicyConfig())
    assert PolicyConfig.completed(PolicyConfig(plan_step=3).record())["plan_step"] == 3
    assert PolicyConfig.completed(PolicyConfig(plan_every=3).record())["plan_every"] == 3
    saved = json.loads((Path(__file__).parents[1] / "reports" / "navigation" / "config.json").read_text())
    assert saved["policy"] == default  # the committed runs are today's default policy's
