"""odolab/cli/train.py, the trainers' shared command line: workers a local Ray cannot hold, a dead
RAY_ADDRESS, exports and reports folders that are not the run's, and ``--set`` changes to the recipe;
each refused in one line before any folder is made."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from odolab.cli import UsageError, run_cli
from tests.helpers import robust_job


def _job(tmp_path: Path, *argv: str):
    pytest.importorskip("torch")
    return robust_job(tmp_path, *argv)


def test_workers_a_local_ray_instance_cannot_hold_are_refused_before_any_work(tmp_path, monkeypatch):
    """Ray Train waits forever for workers a fixed local instance lacks (8 workers on 2 CPUs, GPUs
    on a machine without any): refused in one line, before the work and reports folders exist."""
    torch = pytest.importorskip("torch")
    from odolab.cli.train import check_workers

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    cpu = torch.device("cpu")
    two_cpus = lambda: (2.0, 0.0)
    with pytest.raises(UsageError, match="--workers 8: a local Ray instance here has 2 CPUs.*--workers 2 or fewer"):
        check_workers(8, 0.0, None, cpu, None, two_cpus)
    with pytest.raises(UsageError, match="needs 1 GPUs, this machine has 0"):
        check_workers(2, 0.5, None, cpu, None, two_cpus)
    with pytest.raises(UsageError, match="--device cpu contradicts --gpus-per-worker 1"):
        check_workers(2, 1.0, "cpu", cpu, None, two_cpus)
    with pytest.raises(UsageError, match="--gpus-per-worker places Ray Train workers"):
        check_workers(1, 1.0, None, cpu, None, two_cpus)
    check_workers(2, 0.0, "cpu", cpu, None, two_cpus)  # fits
    check_workers(2, 0.5, None, cpu, None, lambda: (2.0, 1.0))  # half a GPU each, one GPU
    check_workers(64, 1.0, None, cpu, "127.0.0.1:6379", two_cpus)  # a cluster may grow: not checked
    monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:6379")
    check_workers(64, 0.0, None, cpu, None, two_cpus)
    monkeypatch.delenv("RAY_ADDRESS")
    monkeypatch.setattr("odolab.learned.training.device.local_ray_resources", two_cpus)
    with pytest.raises(UsageError, match="--workers 3: a local Ray instance"):
        _job(tmp_path, "--workers", "3")
    assert not (tmp_path / "work").exists() and not (tmp_path / "reports").exists()


def test_a_dead_ray_address_in_the_environment_is_one_line_not_a_hang(tmp_path, monkeypatch):
    """ray.init() connects to RAY_ADDRESS as to --ray-address: checked alike, and named."""
    monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:1")
    with pytest.raises(UsageError, match=r"RAY_ADDRESS \(environment\) 127.0.0.1:1: no Ray cluster there.*unset it"):
        _job(tmp_path)
    monkeypatch.setenv("RAY_ADDRESS", "not an address")
    with pytest.raises(UsageError, match="RAY_ADDRESS .*'not an address' is not an address"):
        _job(tmp_path)


def test_the_export_is_never_one_of_the_reports_the_run_writes(tmp_path, monkeypatch):
    """--export reports/training.json: found before training, not after it."""
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    for name in ("training.json", "curves.csv", "curves.png"):
        with pytest.raises(UsageError, match=f"found the path of {name} in --reports"):
            _job(tmp_path, "--export", str(tmp_path / "reports" / ".." / "reports" / name))
    assert _job(tmp_path, "--export", str(tmp_path / "reports" / "model.pt")).export.name == "model.pt"


def test_an_export_mistake_leaves_no_folders_behind(tmp_path):
    with pytest.raises(UsageError, match="found the recipe"):
        _job(tmp_path, "--export", str(tmp_path / "recipe.toml"))
    assert not (tmp_path / "work").exists() and not (tmp_path / "reports").exists()


def test_trainers_and_training_data_refuse_a_folder_of_the_users_files(tmp_path):
    from odolab.cli.training_data import main as make_data

    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "curves.csv").write_text("my own numbers")
    with pytest.raises(UsageError, match="did not write"):
        _job(tmp_path, "--reports", str(mine))
    assert run_cli(make_data, "python -m odolab.training_data", ["--episodes", "1", "--out", str(mine)]) == 2
    assert (mine / "curves.csv").read_text() == "my own numbers" and sorted(p.name for p in mine.iterdir()) == [
        "curves.csv"
    ]


def test_set_changes_the_recipe_and_its_mistakes_are_one_line(tmp_path):
    job = _job(tmp_path, "--set", "seed=7", "--set", "stages.forward.lr=0.0005", "--set", "model.groups=4")
    assert job.config.seed == 7 and job.config.stages[0].lr == 0.0005 and job.config.model.groups == 4
    assert "--set seed=7" in job.command  # the record says how the run differs from its recipe
    for bad, said in (
        ("seed", "--set 'seed': expected path=value"),
        ("model.width.x=1", "--set 'model.width.x=1': model.width is a value, not a table"),
        ("seed.x=1", "seed: expected an integer"),  # a default, not in the file: the recipe's check refuses it
        ("stages.9.lr=1", "--set 'stages.9.lr=1': stages.9: the list has 1 entries (0 to 0)"),
        ("stages.turns.lr=1", "no entry named 'turns'; give a position from 0 or one of forward"),
        ("stages=1", "stages"),  # the whole list replaced by a number: the recipe's check refuses it
        ("seed=abc", "--set 'seed=abc': seed: expected an integer, got 'abc'"),  # the change, not the file
        ("train_data.noise.rgb=-1", "--set 'train_data.noise.rgb=-1': train_data.noise: noise: rgb must be in [0, 10]"),
        ("train_data.noise.controller=nosuch", "noise.controller: expected one of 'ilqr', 'proportional', 'movebase'"),
        ("data_root=", "--set 'data_root=': recipe: data_root must name a folder, got ''"),
    ):
        with pytest.raises(UsageError) as info:
            _job(tmp_path, "--set", bad)
        assert said in str(info.value), str(info.value)
        assert "\n" not in str(info.value)
    with pytest.raises(UsageError, match="unknown field"):
        _job(tmp_path, "--set", "model.widht=341")


def test_a_trainer_refuses_the_reports_of_another_training(tmp_path):
    reports = tmp_path / "reports"
    reports.mkdir()
    (reports / "training.json").write_text(
        json.dumps({"command": "python -m odolab.learned.deepvo.train --config studies/deepvo/shipped.toml"})
    )
    with pytest.raises(UsageError, match=r"--reports .*reports: .*training.json is the summary of another training"):
        _job(tmp_path)
    assert not (tmp_path / "work").exists()  # refused before anything was made
    (reports / "training.json").write_text(
        json.dumps({"command": f"python -m odolab.learned.robust_vo.train --config {tmp_path / 'recipe.toml'} --quiet"})
    )
    assert _job(tmp_path, "--set", f"data_root={tmp_path / 'd'}").reports == reports  # the same recipe, elsewhere


def test_the_trainers_check_ray_address_with_the_shared_function(tmp_path, monkeypatch):
    """odolab.cli.train words RAY_ADDRESS as every other command does (the tests above run the
    trainers' command line itself)."""
    import inspect

    pytest.importorskip("torch")
    from odolab.cli import train as cli

    assert "check_ray_option(args.ray_address)" in inspect.getsource(cli.parse_training_command)


def test_an_empty_recipe_or_a_work_path_that_is_a_file_makes_nothing(tmp_path, monkeypatch):
    """An empty recipe (every field at its default) is never what was asked for; a --work that is a
    file is refused before --reports is made."""
    from odolab.cli.train import train

    monkeypatch.chdir(tmp_path)
    empty = tmp_path / "empty.toml"
    empty.write_text("\n")
    with pytest.raises(UsageError, match="an empty recipe"):
        train("deepvo", ["--config", str(empty)], "python -m odolab.learned.deepvo.train")
    (tmp_path / "afile").write_text("x")
    recipe = tmp_path / "r.toml"
    recipe.write_text("epochs = 1\n")
    with pytest.raises(UsageError, match="--work afile: is a file"):
        train(
            "depth-corrector",
            ["--config", str(recipe), "--work", "afile"],
            "python -m odolab.learned.depth_corrector.train",
        )
    with pytest.raises(UsageError, match="--work /proc/odolab/x: not a writable folder"):  # made nowhere
        train(
            "depth-corrector",
            ["--config", str(recipe), "--work", "/proc/odolab/x"],
            "python -m odolab.learned.depth_corrector.train",
        )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "empty.toml", "r.toml"]


def test_a_training_keeps_its_work_out_of_other_runs_folders_but_may_keep_it_in_its_own_reports(tmp_path):
    """--work inside a study's folder, or a folder another command owns, is refused in one line; the
    states in the training's own --reports folder (the shipped-341 layout) are fine."""
    pytest.importorskip("torch")
    from odolab.cli import UsageError

    study = tmp_path / "study"
    study.mkdir()
    (study / "manifest.txt").write_text("# odolab study ablations\n")
    with pytest.raises(UsageError, match=r"--work .*: lies inside the report folder of study ablations"):
        robust_job(tmp_path, "--work", str(study / "states"))
    (tmp_path / "reports").mkdir()
    same = f"python -m odolab.learned.robust_vo.train --config {tmp_path / 'recipe.toml'}"  # this training's summary
    (tmp_path / "reports" / "training.json").write_text(json.dumps({"command": same, "stages": []}))
    job = robust_job(tmp_path, "--work", str(tmp_path / "reports" / "state"))  # its own reports
    assert job.work == tmp_path / "reports" / "state"
    with pytest.raises(UsageError, match=r"--work .*: is a comparison report folder"):
        compare = tmp_path / "compare"
        compare.mkdir()
        (compare / "manifest.txt").write_text("# odolab compare\n")
        robust_job(tmp_path, "--work", str(compare))


def test_a_training_report_folder_is_a_run_folder_for_nesting(tmp_path, capsys):
    """A compare --out inside a training's --reports folder is refused: the training owns it."""
    from odolab.cli.compare import main

    reports = tmp_path / "training"
    reports.mkdir()
    (reports / "training.json").write_text(
        json.dumps({"command": "python -m odolab.learned.robust_vo.train", "stages": []})
    )
    assert run_cli(main, "compare", ["--out", str(reports / "cmp"), "--episodes", "1"]) == 2
    assert "lies inside a training's report folder" in capsys.readouterr().err
    assert not (reports / "cmp").exists()


def test_a_training_work_folder_of_other_files_is_refused_and_a_refusal_makes_no_folder(tmp_path):
    """--work holding a user's files is refused (its states would be written among them), and a run
    refused for its --reports or --export leaves no --work folder behind."""
    pytest.importorskip("torch")
    from odolab.cli import UsageError

    user = tmp_path / "user"
    user.mkdir()
    (user / "notes.txt").write_text("mine")
    with pytest.raises(
        UsageError, match=r"--work .*user: expected a new folder or one of training states .*'notes.txt'"
    ):
        robust_job(tmp_path, "--work", str(user))
    with pytest.raises(UsageError, match=r"--reports .*user: holds files odolab did not write"):
        robust_job(tmp_path, "--work", str(tmp_path / "w" / "deep"), "--reports", str(user))
    with pytest.raises(UsageError, match=r"--export .*: folder .*nodir does not exist"):
        robust_job(tmp_path, "--work", str(tmp_path / "w2"), "--export", str(tmp_path / "nodir" / "m.pt"))
    assert not (tmp_path / "w").exists() and not (tmp_path / "w2").exists() and not (tmp_path / "reports").exists()
    states = tmp_path / "states"
    states.mkdir()
    (states / "forward.pt").write_bytes(b"")  # a folder of states (and an atomic write's leftover) is fine
    (states / ".forward.pt.x.tmp").write_bytes(b"")
    assert robust_job(tmp_path, "--work", str(states)).work == states
