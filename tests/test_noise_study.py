"""The noise-robustness study resumes what it finished, and reruns rows whose model file changed."""

import json

import studies.noise_robustness as study
from odolab.parallel import SERIAL


def test_noise_study_resumes_and_reruns_changed_weights(tmp_path, monkeypatch):
    doc = study.run_study(tmp_path, ["action-prior"], [2.0], episodes=1, max_steps=3, execution=SERIAL)
    assert set(doc["results"]) == {"1/action-prior", "2/action-prior"}
    assert doc["results"]["1/action-prior"]["weights"] is None  # not a learned odometer
    calls = []
    real = study.run_comparison

    def counting(config):
        calls.append(config.noise.rgb)
        return real(config)

    monkeypatch.setattr(study, "run_comparison", counting)
    study.run_study(tmp_path, ["action-prior"], [2.0], episodes=1, max_steps=3, execution=SERIAL)
    assert calls == []  # everything was done
    path = tmp_path / "results.json"
    saved = json.loads(path.read_text())
    saved["results"]["2/action-prior"]["weights"] = "0" * 64  # as if made by another model file
    path.write_text(json.dumps(saved))
    again = study.run_study(tmp_path, ["action-prior"], [2.0], episodes=1, max_steps=3, execution=SERIAL)
    assert calls == [2.0]
    assert again["results"]["2/action-prior"]["weights"] is None


def test_noise_study_command_line_levels_and_refusals(tmp_path, capsys):
    """Only-base levels are refused in one line; a figure is named after its level; another run's
    folder is refused naming the settings as options, not as a dict."""
    from odolab.cli import run_cli

    def cli(*args):
        return run_cli(study.main, "python -m studies.noise_robustness", [str(a) for a in args])

    assert cli("--levels", "1", "--out", tmp_path / "a") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "besides 1" in err[0]
    out = tmp_path / "b"
    assert (
        cli(
            "--levels",
            "0,1,0",
            "--odometers",
            "action-prior",
            "--episodes",
            1,
            "--max-steps",
            3,
            "--serial",
            "--quiet",
            "--out",
            out,
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert "level 0" not in printed and "| action-prior |" in printed  # quiet: the table only
    assert sorted(p.name for p in out.glob("*.png")) == ["growth.png"]
    assert (
        cli("--levels", "2", "--odometers", "action-prior", "--episodes", 2, "--max-steps", 3, "--serial", "--out", out)
        == 2
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--episodes 1" in err[0] and "--episodes 2" in err[0] and "{" not in err[0]


def test_noise_study_levels_are_one_per_printed_key_and_nan_rows_run_again(tmp_path, capsys, monkeypatch):
    from odolab.cli import run_cli

    seen = []
    monkeypatch.setattr(
        study, "run_study", lambda out, odometers, levels, *a, **k: seen.append(levels) or {"config": {}, "results": {}}
    )
    monkeypatch.setattr(study, "growth_table", lambda *a: "table")
    monkeypatch.setattr(study, "growth_figure", lambda *a: None)
    assert (
        run_cli(
            study.main,
            "s",
            ["--levels", "2,2.0000001,-0,0", "--odometers", "action-prior", "--out", str(tmp_path / "o")],
        )
        == 0
    )
    assert seen == [[2.0, 0.0]] and str(seen[0][1]) == "0.0"  # not -0.0
    row = {
        "level": 1.0,
        "odometer": "x",
        "steps": 3,
        "dx": 1.0,
        "dz": 1.0,
        "dyaw": 1.0,
        "dx_own": None,
        "dz_own": 1.0,
        "dyaw_own": 1.0,
        "failure_share": 0.0,
        "ate_m": 0.1,
    }
    assert study._whole(row) and not study._whole(row | {"dx": float("nan")})
