"""The ``odolab`` console command: its subcommands are the ``python -m`` commands; its help, version and
near names; every command names itself as typed in its errors."""

from __future__ import annotations

import subprocess
import sys

import pytest

from odolab.cli.commands import COMMANDS, entry_of, main, usage


def test_help_lists_every_subcommand(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for name, (module, _, _) in COMMANDS.items():
        assert name in out and f"python -m {module}" in out
    assert main([]) == 2  # no command: the list, and a usage error's exit code


def test_every_subcommand_names_a_real_main():
    for name in COMMANDS:
        assert callable(entry_of(name)), name


def test_an_unknown_command_is_one_line(capsys):
    assert main(["comapre"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown command 'comapre'" in err[0] and "compare" in err[0]


def test_a_subcommand_runs_its_command(capsys, tmp_path):
    # the same one-line usage error as python -m odolab.evaluate, under the odolab name
    assert main(["evaluate", str(tmp_path / "missing.tum"), str(tmp_path / "missing.tum")]) == 2
    assert capsys.readouterr().err.startswith("odolab evaluate: error:")
    with pytest.raises(SystemExit) as exit_:
        main(["bench", "--help"])
    assert exit_.value.code == 0
    assert "usage" in usage()


def test_a_plug_in_beside_the_user_loads_under_the_odolab_face(tmp_path, monkeypatch, capsys):
    import sys
    from pathlib import Path

    source = Path(__file__).resolve().parents[1] / "examples" / "nominal_motion.py"
    (tmp_path / "my_plug_in_odometer.py").write_text(source.read_text())
    monkeypatch.chdir(tmp_path)
    path = list(sys.path)
    argv = ["--odometers", "my_plug_in_odometer:NominalMotion", "--episodes", "1", "--max-steps", "2"]
    code = main(["compare", *argv, "--serial", "--quiet", "--no-cache", "--out", str(tmp_path / "out")])
    assert code == 0, capsys.readouterr().err
    assert (tmp_path / "out" / "table.csv").read_text().count("my_plug_in_odometer") == 1
    assert sys.path == path  # the folder is importable only while the command runs


@pytest.mark.slow
@pytest.mark.parametrize(
    "module",
    [
        "odolab.compare",
        "odolab.bench",
        "odolab.simcard",
        "odolab.evaluate",
        "odolab.navigate",
        "odolab.action_prior",
        "odolab.training_data",
        "odolab.fusion.calibrate",
        "odolab.navigation.diff",
    ],
)
def test_every_command_names_itself_as_typed_in_its_errors(module):
    proc = subprocess.run([sys.executable, "-m", module, "--bogus-option"], capture_output=True, text=True, check=False)
    assert proc.returncode == 2 and proc.stderr.startswith(f"python -m {module}: error: "), proc.stderr


def test_the_odolab_command_help_version_and_near_names(capsys):
    from odolab.cli.commands import main

    assert main([]) == 2  # a usage error: the list goes to stderr, not into a pipe's data
    got = capsys.readouterr()
    assert not got.out and "commands:" in got.err
    with pytest.raises(SystemExit) as exit_:
        main(["help", "evaluate"])  # = odolab evaluate --help, not the general list
    assert exit_.value.code == 0 and "ground-truth trajectory file" in capsys.readouterr().out
    assert main(["--version"]) == 0 and capsys.readouterr().out.startswith("odolab ")
    assert main(["navigation_diff"]) == 2
    assert "did you mean 'navigation-diff'?" in capsys.readouterr().err


def test_a_study_is_named_in_full_under_the_odolab_face(capsys):
    """odolab study NAME: its usage and errors carry the study's name; options go after it."""
    assert main(["study", "e-table", "--scale", "nope"]) == 2
    assert capsys.readouterr().err.startswith("odolab study e-table: error: argument --scale")
    assert main(["study", "--scale", "ci", "e-table"]) == 2
    assert "expected the study's name first" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_:  # argparse's --help exits, as under python -m
        main(["help", "study", "e-table"])
    assert exit_.value.code == 0 and capsys.readouterr().out.startswith("usage: odolab study e-table")
