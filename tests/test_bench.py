"""``python -m odolab.bench`` (odolab/cli/bench.py, odolab/benchmarks/): its --json path checked before
work, odometer options it would ignore refused, and each part saved as it finishes."""

from __future__ import annotations

import pytest

from tests.helpers import one_line_error


def test_bench_json_path_is_checked_before_work(tmp_path):
    one_line_error("odolab.bench", "--only", "evaluate", "--json", tmp_path, words="is a folder, not a file")
    notes = tmp_path / "notes.md"  # a slip of the tab key must not overwrite a document
    notes.write_text("mine")
    one_line_error("odolab.bench", "--only", "evaluate", "--json", notes, words="unknown file type '.md'")
    (tmp_path / "link.json").symlink_to(notes)  # the link's name is not what would be replaced
    one_line_error(
        "odolab.bench",
        "--only",
        "evaluate",
        "--json",
        tmp_path / "link.json",
        words=f"links to {notes}, unknown file type '.md'",
    )
    assert notes.read_text() == "mine"
    one_line_error("odolab.bench", "--only", "evaluate", "--json", f"{tmp_path}/new.json/", words="ends in '/'")
    assert not (tmp_path / "new.json").exists()
    one_line_error("odolab.bench", "--only", "evaluate", "--json", tmp_path / ".json", words="has no file extension")
    one_line_error("odolab.action_prior", "--out", f"{tmp_path}/p.json/", words="ends in '/'")


def test_bench_refuses_odometer_options_it_would_ignore():
    one_line_error("odolab.bench", "--only", "evaluate", "--odometers", "icp", words="does not run it")
    one_line_error("odolab.bench", "--only", "evaluate", "--train-threads", "1", words="--train-threads chooses")
    one_line_error(
        "odolab.bench", "--only", "training", "--train-threads", "0", words="--train-threads must be in [1, 256], got 0"
    )
    one_line_error("odolab.bench", "--only", "simulator", "--odometer-option", "icp.x=1", words="does not run it")
    one_line_error("odolab.bench", "--only", "evaluate", "--policy", "plan_step=2", words="--policy chooses")
    one_line_error("odolab.bench", "--only", "navigation", "--policy", "plan_step=9", words="plan_step")


def test_bench_navigation_times_the_policy_asked_and_names_it(monkeypatch):
    from odolab.benchmarks import speed as bench
    from odolab.navigation import episode

    used = []
    real = episode.navigate

    def navigate(spec, odometer, policy=None, **kw):
        used.append(policy.plan_step)
        return real(spec, odometer, policy, **kw)

    monkeypatch.setattr(episode, "navigate", navigate)
    from odolab.navigation.agent import PolicyConfig

    rows = bench.bench_navigation(
        odometers=("ground-truth",), episodes=1, max_steps=4, policy=PolicyConfig(plan_step=2)
    )
    assert used == [2, 2] and rows[0]["policy"] == "plan_step=2" and rows[0]["steps"] == 4
    assert rows[0]["planning_to_sensors"] > 0


def test_bench_saves_each_part_as_it_finishes(tmp_path, monkeypatch):
    import json

    from odolab.benchmarks import speed as bench
    from odolab.cli.bench import main

    out = tmp_path / "b.json"
    out.write_text('{"machine": {"cpus": 2}, "evaluate": {"old": "a complete earlier run"}, "parts_pending": []}')
    seen = []

    def odometers(names, options=None, rows=None, after_each=None):  # the 2nd odometer is interrupted
        rows.append({"odometer": names[0], "steps_per_s": 1.0})
        after_each()
        seen.append(json.loads(out.read_text()))
        raise KeyboardInterrupt

    monkeypatch.setattr(bench, "bench_odometers", odometers)
    with pytest.raises(KeyboardInterrupt):
        main(["--only", "odometers", "--only", "evaluate", "--odometers", "action-prior,icp", "--json", str(out)])
    saved = json.loads(out.read_text())
    assert "evaluate" not in saved and saved == seen[0]
    assert saved["odometers"] == [{"odometer": "action-prior", "steps_per_s": 1.0}]
    assert saved["parts_pending"] == ["odometers", "evaluate"]


def test_bench_compare_times_a_comparison_against_its_odometers_own_steps():
    from odolab.benchmarks.speed import bench_compare
    from odolab.core.parallel import SERIAL

    row = bench_compare(episodes=1, max_steps=4, odometers=["action-prior", "planar-depth"], execution=SERIAL)
    assert row["odometers"] == 2 and row["cores"] >= 1 and 0 < row["odometer_step_s"] < row["wall_s"]
    assert row["ratio"] == row["wall_s"] / (row["odometer_step_s"] / row["cores"])
    assert 0 <= row["load_odometers_s"] + row["run_s"] <= row["wall_s"]  # the phases, within the whole
    assert 0 < row["command_odometer_step_s"] < row["command_wall_s"]  # the command: its own run, its own steps
    assert row["command_ratio"] == row["command_wall_s"] / (row["command_odometer_step_s"] / row["cores"])


def test_bench_odometers_names_the_options_it_timed():
    from odolab.benchmarks import speed as bench

    rows = bench.bench_odometers(
        ["action-prior", "icp"], episodes=1, max_steps=3, options={"icp": {"max_depth": 4.0, "voxel": 0.05}}
    )
    assert "options" not in rows[0] and rows[1]["options"] == "max_depth=4.0 voxel=0.05"
