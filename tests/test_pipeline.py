"""compare's orchestration as one library call: what a study, a notebook or navigation would make; a TUM
folder's depth scale and camera, and an odometer that fails every step said so. Guards: a broken entry
point left out of the default list with one warning, the step time limit reaching the runner, frames
without depth and one-frame TUM folders said in one line."""

import csv
import shutil
import threading
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from odolab import api
from odolab.api import register_odometer
from odolab.cli import run_cli
from odolab.compare import main
from odolab.core.parallel import SERIAL, Execution
from odolab.odometry import odometer
from odolab.reporting import pipeline
from odolab.reporting.pipeline import ComparisonConfig, ComparisonError, load_odometers
from odolab.running.runner import SequenceResult
from tests.helpers import FR1, Never


def test_run_comparison_matches_the_command_line(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the library call writes nothing
    config = api.ComparisonConfig(
        odometers=["ground-truth", "action-prior"],
        episodes=2,
        max_steps=8,
        seed=5,
        cache=None,
        execution=SERIAL,
    )
    result = api.run_comparison(config)
    assert list(tmp_path.iterdir()) == []
    assert [r.odometer for r in result.rows] == ["ground-truth", "action-prior"]
    assert len(result.results) == 4 and len(result.plans) == 2
    assert result.rows[0].ate_m < 1e-9 < result.rows[1].ate_m
    assert any("collisions" in n for n in result.notes) and result.action_rows
    out = tmp_path / "cli"
    assert (
        run_cli(
            main,
            "odolab.compare",
            [
                "--odometers",
                "ground-truth,action-prior",
                "--episodes",
                "2",
                "--max-steps",
                "8",
                "--seed",
                "5",
                "--no-cache",
                "--serial",
                "--quiet",
                "--out",
                str(out),
            ],
        )
        == 0
    )
    table = {r["odometer"]: float(r["ate_m"]) for r in csv.DictReader((out / "table.csv").read_text().splitlines())}
    assert table["action-prior"] == pytest.approx(result.rows[1].ate_m, abs=1e-5)  # the CSV keeps 5 decimals


def test_run_comparison_reports_bad_configuration_as_one_line():
    with pytest.raises(api.ComparisonError, match="split 'dev'"):
        api.run_comparison(api.ComparisonConfig(split="dev", cache=None))


def test_each_configurable_odometers_settings_reach_the_result():
    from odolab.api import load_odometer
    from odolab.reporting.pipeline import odometer_configs

    configs = odometer_configs({"icp": load_odometer("icp", max_depth=3.0), "gt": load_odometer("ground-truth")})
    assert list(configs) == ["icp"] and "depth.max_depth=3.0" in configs["icp"]


@pytest.mark.slow
def test_collided_forward_steps_get_their_own_row_with_what_each_odometer_saw():
    import numpy as np

    from odolab.running.summary import COLLIDED_FORWARD

    config = api.ComparisonConfig(
        odometers=["ground-truth", "action-prior"],
        episodes=3,
        max_steps=60,
        seed=1,
        cache=None,
        execution=SERIAL,
    )
    result = api.run_comparison(config)
    prior = [r for r in result.results if r.odometer == "action-prior"]
    blocked = sum(int(((r.actions == api.Action.MOVE_FORWARD.value) & r.collisions).sum()) for r in prior)
    rows = {(r.odometer, r.action): r for r in result.action_rows}
    assert blocked  # these seeded episodes collide
    row, forward = rows[("action-prior", COLLIDED_FORWARD)], rows[("action-prior", "move_forward")]
    assert row.steps == blocked < forward.steps
    assert row.dz > forward.dz  # the prior claims a full step where the robot did not move
    assert rows[("ground-truth", COLLIDED_FORWARD)].dz == 0 and np.isfinite(row.dx)


def test_compare_takes_the_depth_scale_and_the_camera_and_warns_of_a_wrong_scale(millimetre_folder):
    from odolab.reporting.pipeline import ComparisonConfig, run_comparison

    def run(scale):
        config = ComparisonConfig(
            odometers=["ground-truth"],
            tum=millimetre_folder,
            tum_depth_scale=scale,
            tum_intrinsics=FR1,
            execution=Execution(progress=False),
        )
        return run_comparison(config)

    assert not any("median" in w for w in run(1000.0).warnings)
    assert any("depth's median is 0.22 m" in w for w in run(None).warnings)


def test_an_odometer_failing_every_step_is_said_on_the_compare_console():
    from odolab.reporting.pipeline import ComparisonConfig, run_comparison
    from odolab.running.summary import every_step_failed

    register_odometer("test-never", Never)
    result = run_comparison(
        ComparisonConfig(
            odometers=["test-never", "action-prior"],
            episodes=1,
            max_steps=3,
            cache=None,
            execution=SERIAL,
        )
    )
    assert every_step_failed(result.rows) == [
        "test-never: failed steps: every one of 3; its figures are the action prior's, which stood in for each"
    ]


TUM = Path(__file__).parent / "data" / "tum_fr1_xyz_10"


@pytest.fixture
def broken_default(monkeypatch):
    """The registry's entry points: only one, whose module is not installed (built-ins stay)."""
    point = SimpleNamespace(name="broken-plugin", value="odolab_test_not_installed:Odo")
    monkeypatch.setattr(odometer, "entry_points", lambda group: [point])


def _tum_folder(tmp_path: Path, frames: int) -> Path:
    """A copy of the test TUM folder keeping its first ``frames`` colour images."""
    dst = tmp_path / "tum_fr1_short"
    shutil.copytree(TUM, dst)
    lines = (dst / "rgb.txt").read_text().splitlines()
    head = [line for line in lines if line.startswith("#")]
    (dst / "rgb.txt").write_text("\n".join(head + [line for line in lines if not line.startswith("#")][:frames]) + "\n")
    return dst


def _with_empty(sequence: str, odometer: str, empty: int, n: int = 4) -> SequenceResult:
    return SequenceResult(
        odometer=odometer,
        sequence=sequence,
        oracle=False,
        estimates=np.tile(np.eye(4), (n, 1, 1)),
        truth=None,
        poses=np.tile(np.eye(4), (n + 1, 1, 1)),
        gt_poses=None,
        actions=np.zeros(n, np.int8),
        valid=np.ones(n, bool),
        step_seconds=np.zeros(n),
        empty_depth=empty,
    )


def test_a_broken_entry_point_is_left_out_of_the_default_list_with_one_warning(broken_default):
    said: list[str] = []
    loaded = load_odometers(None, warn=said.append)
    assert sorted(loaded) == ["action-prior", "ground-truth"]
    line = (
        "warning: left out of the default list of odometers: odometer 'broken-plugin': cannot import "
        "'odolab_test_not_installed:Odo' (No module named 'odolab_test_not_installed')"
    )
    assert said == [line]


def test_the_warning_goes_to_stderr_by_default(broken_default, capsys):
    load_odometers(None)
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and "broken-plugin" in err and "left out" in err


def test_a_broken_entry_point_named_or_given_options_is_still_an_error(broken_default):
    with pytest.raises(ComparisonError, match="^odometer 'broken-plugin': cannot import"):
        load_odometers(["broken-plugin", "ground-truth"], warn=pytest.fail)
    with pytest.raises(ComparisonError, match="cannot import"):
        load_odometers(None, {"broken-plugin": {"k": 1}}, warn=pytest.fail)


def test_no_odometer_left_is_an_error(monkeypatch):
    monkeypatch.setattr(pipeline, "standalone_odometers", lambda: ["broken-plugin"])
    monkeypatch.setattr(pipeline, "unknown_odometer", lambda name: None)
    with pytest.raises(ComparisonError, match="^no odometer could be loaded"):
        load_odometers(None, warn=lambda line: None)


@pytest.mark.parametrize(
    "field, value",
    [
        ("step_timeout", 0),
        ("step_timeout", float("inf")),
        ("step_timeout", "60"),
        ("episodes", True),
        ("episodes", 1001),
        ("max_steps", 501),
        ("seed", -1),
        ("tum_depth_scale", 0.5),
    ],
)
def test_comparison_config_refuses_numbers_outside_their_settings(field, value):
    with pytest.raises(ComparisonError, match=f"^{field} must be"):
        ComparisonConfig(**{field: value})


def test_comparison_config_keeps_its_numbers():
    assert ComparisonConfig(step_timeout=None).step_timeout is None and ComparisonConfig().step_timeout == 60.0
    assert type(ComparisonConfig(max_steps=np.int64(5)).max_steps) is int


def test_a_tum_folder_of_one_frame_is_one_line(tmp_path):
    config = ComparisonConfig(odometers=["action-prior"], tum=_tum_folder(tmp_path, 1), cache=None)
    with pytest.raises(ComparisonError) as err:
        pipeline.run_comparison(config)
    assert str(err.value) == (
        "1 usable frame (a colour image with a depth image and a ground-truth pose); "
        "a comparison needs at least 2, one step between them"
    )


def test_the_step_timeout_reaches_the_runner(tmp_path):
    release = threading.Event()

    class Stuck(api.Odometer):
        def step(self, prev, cur, action):
            release.wait(10)
            return api.Estimate(np.eye(4))

    config = ComparisonConfig(odometers=["stuck"], tum=_tum_folder(tmp_path, 3), cache=None, step_timeout=0.02)
    try:
        result = pipeline.run_comparison(config, odometers={"stuck": Stuck()})
    finally:
        release.set()
    assert pipeline.failure_reasons(result.results) == {"stuck": {"timed-out": 2}}


def test_a_needs_action_that_raises_is_one_line(tmp_path):
    class Odd(api.Odometer):
        @property
        def needs_action(self):
            raise RuntimeError("unknown")

    config = ComparisonConfig(odometers=["odd"], tum=_tum_folder(tmp_path, 2), cache=None)
    with pytest.raises(ComparisonError, match="^odometer 'odd': reading needs_action raised RuntimeError: unknown$"):
        pipeline.run_comparison(config, odometers={"odd": Odd()})


def test_a_config_property_that_raises_shows_no_settings():
    class Odd(api.Odometer):
        @property
        def config(self):
            raise RuntimeError("no config")

    assert pipeline.odometer_configs({"odd": Odd()}) == {}


def test_frames_without_depth_give_one_warning_per_sequence():
    results = [_with_empty("a", "x", 2), _with_empty("a", "y", 2), _with_empty("b", "x", 0), _with_empty("c", "x", 5)]
    assert pipeline.empty_depth_warnings(results) == [
        "a: 2 of 5 frames have no depth at all (every depth pixel is 0); odometers that use depth cannot use them",
        "c: 5 of 5 frames have no depth at all (every depth pixel is 0); odometers that use depth cannot use them",
    ]


@pytest.mark.slow
def test_odometers_run_as_ray_tasks_answer_as_in_this_process(tmp_path):
    """In parallel (a local Ray instance, one task per episode and odometer, a temporary episode
    cache) the tables are the serial run's but for the steps/s; the observer hears every task's
    steps with their own time, against the total from the start."""

    class Heard:
        def __init__(self):
            self.total, self.steps, self.closed = None, [], False

        def start(self, total):
            self.total = total

        def advance(self, name, steps, seconds=None):
            self.steps.append((name, steps, seconds))

        def close(self):
            self.closed = True

    config = ComparisonConfig(odometers=["planar-depth", "action-prior"], episodes=2, max_steps=6, cache=None)
    heard = Heard()
    fanned = pipeline.run_comparison(replace(config, execution=Execution(progress=False)), observer=heard)
    serial = pipeline.run_comparison(replace(config, execution=SERIAL))
    assert pipeline.fans_out(replace(config, execution=Execution()), ["planar-depth"])
    without_fps = [{k: v for k, v in vars(r).items() if k != "fps"} for r in fanned.rows]
    assert without_fps == [{k: v for k, v in vars(r).items() if k != "fps"} for r in serial.rows]
    assert fanned.plans.keys() == serial.plans.keys() and [r.sequence for r in fanned.results] == [
        r.sequence for r in serial.results
    ]
    assert heard.closed and heard.total == sum(s for _, s, _ in heard.steps) == sum(
        len(r.actions) for r in serial.results
    )
    assert len(heard.steps) == 4 and all(seconds is not None and seconds >= 0 for _, _, seconds in heard.steps)
    assert list(fanned.phases) == ["load_odometers", "motions", "ray_start", "tasks", "ray_shutdown"]
    assert list(serial.phases) == ["load_odometers", "run"] and all(v >= 0 for v in fanned.phases.values())
    assert fanned.phases["tasks"] >= max(sum(r.step_seconds) for r in fanned.results)  # the tasks hold the steps
    cached = replace(config, cache=tmp_path / "cache", execution=Execution(progress=False))
    made = pipeline.run_comparison(cached)  # the episodes rendered by Ray tasks into the cache, then read back
    assert len(list((tmp_path / "cache").glob("*.npz"))) == 2
    again = pipeline.run_comparison(cached, observer=heard)
    assert heard.total == sum(len(r.actions) for r in serial.results)
    for run in (made, again):
        assert [{k: v for k, v in vars(r).items() if k != "fps"} for r in run.rows] == without_fps


@pytest.mark.slow
def test_episodes_rendered_here_while_ray_starts_reach_the_tasks_where_the_cache_cannot_keep_them(
    tmp_path, monkeypatch, capsys
):
    """While the local Ray instance starts, the driver renders the first missing episodes itself;
    one the cache cannot keep (a folder in its entry's place) is handed to the tasks, so the tables
    are the serial run's, and the cache's warning is said once."""
    from odolab.sim.datasets import episode_specs
    from odolab.sim.episodes import EpisodeCache

    config = ComparisonConfig(odometers=["planar-depth", "action-prior"], episodes=2, max_steps=6)
    first = episode_specs(config.split, 2, seed=config.seed, max_steps=config.max_steps)[0]
    EpisodeCache(tmp_path / "cache").path(first).mkdir(parents=True)
    here = []
    render_kept = pipeline._render_kept

    def recorded(spec, motion, folder):
        here.append(spec.key())
        return render_kept(spec, motion, folder)

    monkeypatch.setattr(pipeline, "_render_kept", recorded)  # the driver's calls (a task imports its own)
    fanned = pipeline.run_comparison(replace(config, cache=tmp_path / "cache", execution=Execution(progress=False)))
    assert first.key() in here  # Ray's start takes seconds; a 6-step episode does not
    serial = pipeline.run_comparison(replace(config, cache=None, execution=SERIAL))
    assert [{k: v for k, v in vars(r).items() if k != "fps"} for r in fanned.rows] == [
        {k: v for k, v in vars(r).items() if k != "fps"} for r in serial.rows
    ]
    assert capsys.readouterr().err.count("cannot write the episode cache") == 1


def test_render_kept_hands_the_caches_notices_back_and_leaves_stderr_alone(tmp_path, capsys, monkeypatch):
    """The driver renders beside Ray's start on a thread: the cache's notices come back as lines, and
    the process's standard error (the main thread's too) is never swapped."""
    import sys

    from odolab.sim.episodes import EpisodeCache, EpisodeSpec, rollout

    spec = EpisodeSpec(split="test", index=0, seed=0, max_steps=3)
    EpisodeCache(tmp_path / "bad").path(spec).mkdir(parents=True)
    stderr, seen, put = sys.stderr, [], EpisodeCache.put

    def watched(self, episode):
        seen.append(sys.stderr)  # the process's stderr while the cache writes and says why it cannot
        return put(self, episode)

    monkeypatch.setattr(EpisodeCache, "put", watched)
    episode, lines = pipeline._render_kept(spec, rollout(spec), tmp_path / "bad")
    assert seen == [stderr] and sys.stderr is stderr and capsys.readouterr().err == ""
    assert episode is not None and len(lines) == 1 and "cannot write the episode cache" in lines[0]


def test_render_into_hands_back_the_episode_and_the_warning_a_cache_that_cannot_keep_it_gives(tmp_path, capsys):
    """The Ray task that renders an episode for the odometers' tasks writes it to the cache; where the
    cache cannot keep it (a folder in the entry's place) it returns the episode itself and the cache's
    warning, which the driver says once (a worker's stderr is not seen)."""
    from odolab.sim.episodes import EpisodeCache, EpisodeSpec, rollout

    spec = EpisodeSpec(split="test", index=0, seed=0, max_steps=3)
    kept, said = pipeline._render_into(spec, rollout(spec), tmp_path / "ok")
    assert kept is None and said == "" and EpisodeCache(tmp_path / "ok").has(spec)
    EpisodeCache(tmp_path / "bad").path(spec).mkdir(parents=True)
    episode, said = pipeline._render_into(spec, rollout(spec), tmp_path / "bad")
    assert episode is not None and len(episode.actions) == 3 and "cannot write the episode cache" in said
    unit = pipeline._Unit("action-prior", {}, spec, tmp_path / "bad", None)
    result, info, unit_said = pipeline._run_unit(unit, episode)  # the episode handed over, not read
    assert len(result.actions) == 3 and info["scene_seed"] == episode.info["scene_seed"] and unit_said == ""
    seen: set[str] = set()
    pipeline._said(said + said, seen)
    pipeline._said(said, seen)
    assert capsys.readouterr().err.count("cannot write the episode cache") == 1


def test_fans_out_only_simulated_parallel_local_runs_of_named_odometers(monkeypatch):
    """Ray tasks for 2+ odometer-episode pairs of registered odometers on a local instance; never for
    a TUM folder (its frames are read here), a serial run or a cluster address."""
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    config = ComparisonConfig(odometers=["icp", "action-prior"], episodes=2, execution=Execution())
    assert pipeline.fans_out(config, ["icp", "action-prior"])
    assert not pipeline.fans_out(replace(config, episodes=1), ["icp"])
    assert not pipeline.fans_out(replace(config, tum=FR1), ["icp", "action-prior"])
    assert not pipeline.fans_out(replace(config, execution=SERIAL), ["icp", "action-prior"])
    assert not pipeline.fans_out(replace(config, execution=Execution(ray_address="127.0.0.1:1")), ["icp"])
