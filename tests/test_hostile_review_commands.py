"""A hostile review of the command lines (after issue 42): RAY_ADDRESS checked by every command that
can start Ray, refusals that make no folder, calibrations that replace only calibrations, folders
named by their owner, navigation's config.json in plain words. Fast: nothing is computed, and no
Ray cluster is needed (the dead address 127.0.0.1:1 refuses connections at once)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from odolab.cli import UsageError, run_cli

SHIPPED_CALIBRATION = Path(__file__).parents[1] / "odolab" / "data" / "fusion" / "calibration.json"


def _command(name: str):
    """The ``main`` of a command, by its name in these tests."""
    import importlib

    module = {
        "compare": "odolab.cli.compare",
        "navigate": "odolab.cli.navigate",
        "simcard": "odolab.cli.simcard",
        "training_data": "odolab.cli.training_data",
        "calibrate": "odolab.cli.calibrate_fusion",
        "e_table": "studies.e_table",
    }[name]
    return importlib.import_module(module).main


def _argv(name: str, out: Path) -> list[str]:
    """The smallest run of each command, into ``out`` (a folder, or calibrate's file in it)."""
    return (
        {
            "compare": ["--odometers", "action-prior", "--episodes", "2", "--max-steps", "5", "--no-cache"],
            "navigate": ["--odometers", "action-prior", "--episodes", "1", "--max-steps", "5"],
            "simcard": ["--episodes", "1", "--rendered", "1", "--frames", "2", "--max-steps", "5"],
            "training_data": ["--episodes", "1", "--max-steps", "5"],
            "calibrate": [
                "--odometers",
                "action-prior",
                "--episodes",
                "1",
                "--max-steps",
                "30",
                "--cache",
                str(out) + "-cache",
            ],
            "e_table": ["--scale", "ci"],
        }[name]
        + ["--quiet"] * (name not in ("training_data",))
        + [
            "--out",
            str(out / "cal.json" if name == "calibrate" else out),
        ]
    )


def _refused(capsys, name: str, argv: list[str]) -> str:
    """Run command ``name``: exit 2 and one line on stderr, no traceback; returns the line."""
    assert run_cli(_command(name), f"python -m {name}", argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err.strip()


COMMANDS = ["compare", "navigate", "simcard", "training_data", "calibrate", "e_table"]


@pytest.mark.parametrize("name", COMMANDS)
@pytest.mark.parametrize(
    "environment, extra, words",
    [
        ("garbage", [], "RAY_ADDRESS (environment) 'garbage' is not an address"),
        ("127.0.0.1:1", [], "RAY_ADDRESS (environment) 127.0.0.1:1: no Ray cluster there"),
        (None, ["--ray-address", "garbage"], "--ray-address 'garbage' is not an address"),
        (None, ["--ray-address", "127.0.0.1:1", "--serial"], "--ray-address and --serial exclude each other"),
    ],
)
def test_every_command_that_can_start_ray_checks_its_address_before_making_anything(
    tmp_path, monkeypatch, capsys, name, environment, extra, words
):
    """RAY_ADDRESS was a traceback (garbage), a hang (a dead address) or Ray's own text, after
    --out was made; simcard and training_data ignored --ray-address with --serial."""
    if environment is None:
        monkeypatch.delenv("RAY_ADDRESS", raising=False)
    else:
        monkeypatch.setenv("RAY_ADDRESS", environment)
    monkeypatch.chdir(tmp_path)  # a default folder a command would make lands here
    out = tmp_path / "new" / "out"
    err = _refused(capsys, name, _argv(name, out) + extra)
    assert words in err, err
    assert ("unset it for a local instance" in err) == (environment is not None)
    assert list(tmp_path.iterdir()) == [], "a refusal makes no folder"


def test_ray_address_in_the_environment_is_left_alone_when_no_ray_starts(monkeypatch):
    from odolab.cli.args import check_ray_option

    monkeypatch.setenv("RAY_ADDRESS", "garbage")
    check_ray_option(None, serial=True)  # --serial: Ray is never started
    check_ray_option(None, starts_ray=False)  # a study's --redraw computes nothing
    with pytest.raises(UsageError, match=r"^RAY_ADDRESS \(environment\) 'garbage' is not an address"):
        check_ray_option(None)
    monkeypatch.setenv("RAY_ADDRESS", "")  # set but empty: Ray ignores it too
    check_ray_option(None)


def test_the_library_checks_ray_address_before_ray_init_and_names_it(monkeypatch):
    """Library callers (odolab.api) get the typed error, named after the variable, not a hang."""
    pytest.importorskip("ray")
    from odolab.parallel import RayAddressError, start_ray

    monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:1")
    with pytest.raises(RayAddressError, match=r"^RAY_ADDRESS \(environment\) 127.0.0.1:1: no Ray cluster"):
        start_ray(None)


def test_a_ray_client_address_without_ray_client_is_one_line(monkeypatch):
    """ray:// needs Ray Client (ray[client]); without it ray.init() raised after the folders were made."""
    from odolab.cli.args import check_ray_option

    monkeypatch.setattr("odolab.parallel.has_ray_client", lambda: False)
    with pytest.raises(UsageError, match=r"--ray-address ray://127.0.0.1:1: a ray:// address needs Ray Client"):
        check_ray_option("ray://127.0.0.1:1")
    monkeypatch.setenv("RAY_ADDRESS", "ray://127.0.0.1:1")
    with pytest.raises(UsageError, match=r"RAY_ADDRESS \(environment\) ray://127.0.0.1:1: a ray:// address needs"):
        check_ray_option(None)


def test_the_trainers_check_ray_address_with_the_shared_function(tmp_path, monkeypatch):
    """odolab.learning.cli words RAY_ADDRESS as every other command does (tests/test_hostile_review.py
    runs the trainers' command line itself)."""
    import inspect

    pytest.importorskip("torch")
    from odolab.learning import cli

    assert "check_ray_option(args.ray_address)" in inspect.getsource(cli.parse_training_command)


# ----------------------------------------------------------------------------- calibrate-fusion --out


@pytest.mark.parametrize(
    "content, words",
    [
        (json.dumps({"format": 1, "options": {}, "episodes": [], "policy": {}}), "not a fusion calibration (keys"),
        ("my notes, not JSON", "not a fusion calibration (not a JSON document"),
        ("[1, 2]", "not a fusion calibration (not a JSON object"),
        (json.dumps({"format": 1, "source": "by hand", "inputs": {}}), "a calibration that python -m odolab.fusion"),
    ],
)
def test_calibrate_replaces_only_a_calibration_it_wrote(tmp_path, capsys, content, words):
    """--out some/existing.json replaced any file: a navigation config.json, a user's file."""
    out = tmp_path / "config.json"
    out.write_text(content)
    argv = ["--odometers", "action-prior", "--episodes", "1", "--max-steps", "30", "--serial", "--out", str(out)]
    err = _refused(capsys, "calibrate", argv + ["--cache", str(tmp_path / "cache")])
    assert f"--out {out}: expected a new file or a calibration this command wrote, found" in err and words in err
    assert out.read_text() == content and not (tmp_path / "cache").exists()


def test_a_calibration_this_command_wrote_may_be_replaced(tmp_path):
    from odolab.fusion.calibration import what_file

    assert what_file(SHIPPED_CALIBRATION) is None
    old = tmp_path / "old.json"  # an older format of this command's: a new calibration replaces it
    old.write_text(json.dumps({"format": 0, "source": "python -m odolab.fusion.calibrate --out x.json", "inputs": {}}))
    assert what_file(old) is None


def test_calibrate_says_how_few_steps_it_was_given(capsys):
    err = _refused(capsys, "calibrate", ["--episodes", "1", "--max-steps", "5", "--serial"])
    assert "--episodes 1 x --max-steps 5 = 5 steps: too few to calibrate, at least 30" in err, err


# ----------------------------------------------------------------------------- folders


def test_a_study_refusing_redraw_writes_nothing_in_an_empty_folder(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    err = _refused(capsys, "e_table", ["--scale", "ci", "--out", str(empty), "--redraw"])
    assert "--redraw: no saved results" in err and list(empty.iterdir()) == []


def _navigation_folder(path: Path) -> Path:
    path.mkdir()
    (path / "config.json").write_text(json.dumps({"format": 1, "options": {}, "episodes": [{}], "policy": {}}))
    (path / "nav.csv").write_text("odometer\n")
    return path


def _study_folder(path: Path) -> Path:
    path.mkdir()
    (path / "manifest.txt").write_text("# odolab study e_table\ntable.md\n")
    (path / "table.md").write_text("| x |\n")
    return path


def _compare_folder(path: Path) -> Path:
    path.mkdir()
    (path / "manifest.txt").write_text("# odolab compare\ntable.csv\n")
    (path / "table.csv").write_text("odometer\n")
    return path


@pytest.mark.parametrize(
    "name, folder, owner",
    [
        ("compare", _navigation_folder, "a navigation results folder (python -m odolab.navigate)"),
        ("e_table", _navigation_folder, "a navigation results folder (python -m odolab.navigate)"),
        ("training_data", _study_folder, "the report folder of study e_table (python -m studies.e_table)"),
        ("navigate", _compare_folder, "a comparison report folder (python -m odolab.compare)"),
    ],
)
def test_a_folder_odolab_wrote_is_named_by_its_owner(tmp_path, monkeypatch, capsys, name, folder, owner):
    """Such folders were said to hold "files odolab did not write"."""
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    out = folder(tmp_path / "theirs")
    before = sorted(p.name for p in out.iterdir())
    err = _refused(capsys, name, _argv(name, out) + ["--serial"])
    assert f"--out {out}: is {owner}; choose another --out" in err, err
    assert sorted(p.name for p in out.iterdir()) == before


# ----------------------------------------------------------------------------- navigate's config.json


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
    err = _refused(capsys, "navigate", _argv("navigate", out) + ["--serial"])
    assert words in err, err
    assert (out / "config.json").is_dir() if config is None else (out / "config.json").read_text() == config


# ----------------------------------------------------------------------------- small


def test_evaluate_names_the_delta_unit_option(tmp_path, capsys):
    from odolab.evaluate import main

    path = tmp_path / "a.tum"
    path.write_text("0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n2 2 0 0 0 0 0 1\n")
    assert run_cli(main, "python -m odolab.evaluate", [str(path), str(path), "--delta", "2.5"]) == 2
    err = capsys.readouterr().err
    assert "--delta must be a whole number of frames with --delta-unit f" in err and "-u f" not in err, err


def test_a_whole_policy_number_may_be_written_in_e_notation():
    from odolab.navigation.agent import PolicyConfig, PolicyError

    assert PolicyConfig.from_assignments(["memory=1e6"]).memory == 1_000_000
    assert PolicyConfig.from_assignments(["votes=2E1"]).votes == 20
    with pytest.raises(PolicyError, match="memory must be in"):
        PolicyConfig.from_assignments(["memory=2e6"])
    with pytest.raises(PolicyError, match="memory takes a whole number"):
        PolicyConfig.from_assignments(["memory=1.5e0"])
