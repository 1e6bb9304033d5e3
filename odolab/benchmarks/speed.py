"""Speed of the simulator, the odometers, closed-loop navigation and training: what ``python -m
odolab.bench`` (:mod:`odolab.cli.bench`) times.

Simulator figures are ratios to the physical limit measured in the same run: bare Open3D
``cast_rays`` on precomputed rays of the same scene and poses (docs/reference-facts.md section 7). A noisy,
textured frame should cost at most 2x that (aim 1.5x).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # the navigation modules load only when that part runs
    from odolab.navigation.agent import PolicyConfig


def bench_simulator(n_scenes: int = 3, n_poses: int = 40, repeats: int = 3) -> list[dict]:
    """Per test scene: bare cast_rays, clean render, and the noisy frame as episodes make it
    (:class:`~odolab.sim.environment.Sensors`, depth path in a second thread) and in one thread (median ms
    per frame), with the median per-pose ratios noisy / bare."""
    import open3d as o3d

    from odolab.core.geometry import camera_pose_from_agent
    from odolab.sim.camera import CameraSpec
    from odolab.sim.environment import Sensors
    from odolab.sim.scenes import generate_scene, scene_seed

    rows = []
    rng = np.random.default_rng(0)
    for k in range(n_scenes):
        scene = generate_scene(scene_seed("test", k))
        sensors = {
            n: Sensors(scene, CameraSpec(), 1.0, 1.0, np.random.default_rng(1), np.random.default_rng(2), threads=n)
            for n in (1, 2)
        }
        r = sensors[1].renderer
        cells = np.argwhere(scene.navigable)
        poses = []
        for i in rng.integers(len(cells), size=n_poses):
            x, y = scene.cell_to_world(*cells[i])
            poses.append(camera_pose_from_agent(float(x), float(y), float(rng.uniform(-np.pi, np.pi)), 0.88))
        # Interleaved per pose (bare, clean, noisy, noisy in one thread), so load changes hit all alike.
        times = np.empty((4, repeats, len(poses)))
        for rep in range(repeats):
            for i, p in enumerate(poses):
                rays = o3d.core.Tensor(r.rays(p))  # Open3D's own (aligned) copy
                calls = (
                    partial(r.raycasting_scene.cast_rays, rays),
                    partial(r.render, p),
                    partial(sensors[2].read, p),
                    partial(sensors[1].read, p),
                )
                for j, call in enumerate(calls):
                    t0 = time.perf_counter()
                    call()
                    times[j, rep, i] = time.perf_counter() - t0
        for s in sensors.values():
            s.close()
        bare, clean, full, single = np.median(times, axis=(1, 2))
        rows.append(
            {
                "scene": scene.seed,
                "triangles": len(scene.triangles),
                "cast_rays_ms": bare * 1e3,
                "clean_frame_ms": clean * 1e3,
                "noisy_frame_ms": full * 1e3,
                "noisy_fps": 1.0 / full,
                "ratio_to_cast_rays": float(np.median(times[2] / times[0])),
                "noisy_1thread_ms": single * 1e3,
                "ratio_1thread": float(np.median(times[3] / times[0])),
            }
        )
    return rows


def bench_episodes(n: int = 3, max_steps: int = 100) -> dict:
    """End-to-end episode generation in one process (scene, planning, noisy motion, rendering)."""
    from odolab.sim.episodes import EpisodeSpec, render_episode

    frames, t0 = 0, time.perf_counter()
    for i in range(n):
        frames += len(render_episode(EpisodeSpec(split="test", index=i, seed=0, max_steps=max_steps)))
    seconds = time.perf_counter() - t0
    return {"episodes": n, "frames": frames, "seconds": seconds, "frames_per_s": frames / seconds}


def bench_compare(
    episodes: int = 5, max_steps: int = 60, odometers: list[str] | None = None, execution: object = None
) -> dict:
    """The default comparison, twice. First the command a user runs, ``python -m odolab.compare
    --no-cache`` in a new process (its imports, the odometers loaded and checked, the run, the report
    written, the exit), timed from its start to its exit: ``command_wall_s``, and its ratio to the
    limit, the odometers' own step times of that run summed (``steps / fps`` of each timed row of
    its ``table.csv``) over the machine's cores (``command_ratio``: 1 would be every core busy with
    odometer steps only). Then its pipeline alone in this process (modules already imported, nothing
    written: :func:`odolab.reporting.pipeline.run_comparison`), the same figures (``wall_s``,
    ``odometer_step_s``, ``ratio``) and the wall seconds of each of its phases (``<phase>_s``,
    :attr:`ComparisonResult.phases`). ``odometers``: every available one when None; ``execution``:
    where the episodes are made and the odometers run (default: a local Ray instance, as the command
    does; not in parallel: the command with ``--serial`` too)."""
    import csv
    import os
    import sys
    import tempfile

    from odolab.benchmarks.commands import timed_command
    from odolab.core.parallel import Execution
    from odolab.reporting.pipeline import ComparisonConfig, run_comparison

    def own_seconds(rows: list[tuple[float, float]]) -> float:
        """Steps over steps/s, summed over the rows that were timed."""
        return sum(steps / fps for steps, fps in rows if np.isfinite(fps) and fps > 0)

    cores = os.cpu_count() or 1
    execution = Execution(progress=False) if execution is None else execution
    chosen = ["--odometers", ",".join(odometers)] if odometers else []
    chosen += [] if execution.parallel else ["--serial"]
    with tempfile.TemporaryDirectory(prefix="odolab-bench-compare-") as folder:
        out = Path(folder) / "compare"
        command = [sys.executable, "-m", "odolab.compare", "--no-cache", "--quiet", "--out", str(out)]
        command += ["--episodes", str(episodes), "--max-steps", str(max_steps), *chosen]
        command_wall = timed_command(command)
        with open(out / "table.csv", newline="") as f:
            command_own = own_seconds([(float(r["steps"]), float(r["fps"])) for r in csv.DictReader(f)])

    config = ComparisonConfig(
        odometers=odometers, episodes=episodes, max_steps=max_steps, cache=None, execution=execution
    )
    t0 = time.perf_counter()
    result = run_comparison(config)
    wall = time.perf_counter() - t0
    own = own_seconds([(r.steps, r.fps) for r in result.rows])
    return {
        "episodes": episodes,
        "max_steps": max_steps,
        "odometers": len(result.rows),
        "cores": cores,
        "command_wall_s": command_wall,
        "command_odometer_step_s": command_own,
        "command_ratio": command_wall / (command_own / cores) if command_own > 0 else float("nan"),
        "wall_s": wall,
        "odometer_step_s": own,
        "ratio": wall / (own / cores) if own > 0 else float("nan"),
        **{f"{name}_s": seconds for name, seconds in result.phases.items()},
    }


def bench_odometers(
    names: list[str],
    episodes: int = 4,
    max_steps: int = 60,
    options: dict | None = None,
    rows: list[dict] | None = None,
    after_each: Callable[[], None] | None = None,
) -> list[dict]:
    """Steps per second of each odometer's ``step`` on test-split episodes (341 x 192); ``options``:
    constructor options by odometer name. Each odometer's row is appended to ``rows`` (a new list
    when None, returned) as soon as it is timed, then ``after_each()`` is called."""
    from odolab.core.parallel import SERIAL
    from odolab.odometry.odometer import load_odometer
    from odolab.running import runner, summary
    from odolab.running.threads import odometer_threads
    from odolab.sim.episodes import EpisodeSpec, load_episodes

    eps = load_episodes(
        [EpisodeSpec(split="test", index=i, seed=0, max_steps=max_steps) for i in range(episodes)],
        execution=SERIAL,
    )
    out = [] if rows is None else rows
    for name in names:
        odo = load_odometer(name, **(options or {}).get(name, {}))
        res = runner.run({name: odo}, eps)
        row = summary.summarize(res)[0]
        out.append({"odometer": name, "steps": row.steps, "steps_per_s": row.fps, "failures": row.failures})
        if (options or {}).get(name):  # what was timed: the options beside the name
            out[-1]["options"] = " ".join(f"{k}={v}" for k, v in sorted(options[name].items()))
        if hasattr(odo, "fusion_seconds"):  # a fused odometer: the graph's own share, its inputs excluded
            out[-1]["graph_ms_per_step"] = 1000.0 * odo.fusion_seconds / max(odo.fused_steps, 1)
        if hasattr(odo, "network_steps_per_s"):  # a learned odometer: its network's pass alone, the limit
            with odometer_threads(odo):
                bare = odo.network_steps_per_s()
            out[-1]["network_steps_per_s"] = bare
            out[-1]["over_network"] = row.fps / bare
        if hasattr(odo, "input_ms"):  # what its step adds before the network: resizing, warp, psi
            with odometer_threads(odo):
                out[-1]["input_ms"] = odo.input_ms(eps[0][0], eps[0][1], eps[0].action(0))
        if after_each is not None:
            after_each()
    return out


def bench_navigation(
    odometers: Sequence[str] = ("ground-truth", "action-prior"),
    episodes: int = 3,
    max_steps: int = 100,
    policy: PolicyConfig | None = None,
) -> list[dict]:
    """Closed-loop navigation in one process (:func:`odolab.navigation.episode.navigate`, default
    policy) on the first test episodes: steps per second and milliseconds per step in the policy (of
    which fast-marching planning), the sensors, the odometer and the rest (episode set-up). The action prior's agent believes a
    wrong map and plans over the whole of it more often: the costly case. A short untimed episode
    first pays the one-off imports and caches, so the first row is timed as the others. ``policy``:
    the policy (None: the default), named in each row by its settings that differ from the default's."""
    from odolab.config import describe
    from odolab.navigation.agent import PolicyConfig
    from odolab.navigation.episode import navigate
    from odolab.odometry.odometer import load_odometer
    from odolab.sim.episodes import EpisodeSpec

    config = policy or PolicyConfig()
    defaults = {s.name: s.value for s in describe(PolicyConfig)}
    changed = " ".join(f"{s.name}={s.value}" for s in describe(config) if s.value != defaults[s.name])
    navigate(EpisodeSpec(split="test", index=episodes, seed=0, max_steps=3), load_odometer("ground-truth"), config)
    rows = []
    for name in odometers:
        odo, parts = load_odometer(name), {}
        started = time.perf_counter()
        for i in range(episodes):
            navigate(EpisodeSpec(split="test", index=i, seed=0, max_steps=max_steps), odo, config, timings=parts)
        seconds, steps = time.perf_counter() - started, max(parts.get("steps", 0), 1)
        timed = sum(parts.get(k, 0.0) for k in ("policy", "sensors", "odometer"))
        rows.append(
            {
                "odometer": name,
                "policy": changed or "default",
                "episodes": episodes,
                "max_steps": max_steps,
                "steps": int(parts.get("steps", 0)),
                "steps_per_s": steps / seconds,
                **{
                    f"{k}_ms_per_step": 1e3 * parts.get(k, 0.0) / steps
                    for k in ("policy", "planning", "sensors", "odometer")
                },
                "rest_ms_per_step": 1e3 * (seconds - timed) / steps,  # episode set-up (scene, renderer), bookkeeping
                "planning_share": parts.get("planning", 0.0) / seconds,
                "planning_to_sensors": parts.get("planning", 0.0) / max(parts.get("sensors", 0.0), 1e-9),
            }
        )
    return rows


#: Recipes ``--only training`` times by default: the shipped one, and at the paper's input size with
#: 16 base planes (the next shipped recipe) and with the paper's 32.
TRAINING_RECIPES = (
    "studies/robust_vo/shipped.toml",
    "studies/robust_vo/shipped-341.toml",
    "studies/robust_vo/ablations/full-size.toml",
)


def bench_training(
    recipes: Sequence[Path], device: str | None = None, threads: int | None = None, data: Path | None = None
) -> list[dict]:
    """Training throughput per robust-VO recipe (:mod:`odolab.learned.robust_vo.speed`), with ``threads``
    torch threads (None: torch's own choice; the setting is restored afterwards), the end-to-end
    epoch on training-data folder ``data`` (None: 20 val episodes rendered per recipe)."""
    from odolab.learned.robust_vo.config import load_train_config
    from odolab.learned.robust_vo.speed import training_speed
    from odolab.learned.training import pick_device
    from odolab.running.threads import torch_threads

    dev = pick_device(device)
    with torch_threads(threads):
        return [training_speed(load_train_config(str(p)), p.stem, dev, data_folder=data) for p in recipes]


def default_recipes() -> list[Path]:
    """The recipes the training part times by default (:data:`TRAINING_RECIPES`, in this checkout)."""
    root = Path(__file__).resolve().parents[2]
    return [root / r for r in TRAINING_RECIPES]
