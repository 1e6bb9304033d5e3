"""The studies resume from their saved results (keyed by what they depend on) and redraw their
tables and figures from them without computing anything (issue 42)."""

from __future__ import annotations

import json

import pytest

import studies.noise_robustness as noise
import studies.turns_by_depth as turns
from odolab.cli import run_cli

TURNS = ["--odometers", "ground-truth,action-prior", "--scenes", "2", "--per-scene", "2", "--quiet"]


def _turns(args) -> int:
    return run_cli(turns.main, "python -m studies.turns_by_depth", [str(a) for a in args])


def _counting(monkeypatch) -> list[str]:
    """Every turn an odometer answers, by odometer class name."""
    calls: list[str] = []
    real = turns._answer

    def answer(odometer, *args):
        calls.append(type(odometer).__name__)
        return real(odometer, *args)

    monkeypatch.setattr(turns, "_answer", answer)
    return calls


def test_the_turns_study_resumes_scene_by_scene_and_redraws_without_computing(tmp_path, monkeypatch, capsys):
    out = tmp_path / "t"
    calls = _counting(monkeypatch)
    assert _turns(TURNS + ["--out", out]) == 0
    assert len(calls) == 8  # 2 odometers x 2 scenes x 2 turns
    whole = json.loads((out / "results.json").read_text())
    table = (out / "table.md").read_text()
    calls.clear()
    assert _turns(TURNS + ["--out", out]) == 0
    assert calls == [] and (out / "table.md").read_text() == table  # all saved: nothing computed
    cut = json.loads((out / "results.json").read_text())
    cut["pairs"]["action-prior"] = cut["pairs"]["action-prior"][:2]  # interrupted after its first scene
    (out / "results.json").write_text(json.dumps(cut))
    assert _turns(TURNS + ["--out", out]) == 0
    assert len(calls) == 2 and json.loads((out / "results.json").read_text()) == whole  # only its second scene
    calls.clear()
    changed = json.loads((out / "results.json").read_text())
    changed["config"]["weights"]["ground-truth"] = "0" * 64  # as if made with another model file
    (out / "results.json").write_text(json.dumps(changed))
    assert _turns(TURNS + ["--out", out]) == 0
    assert len(calls) == 4 and json.loads((out / "results.json").read_text()) == whole
    assert "note: ground-truth: saved with another model file or settings" in capsys.readouterr().err
    calls.clear()
    # --redraw: table and figure from results.json alone, no odometer even loaded
    (out / "table.md").unlink()
    (out / "turns.png").unlink()
    monkeypatch.setattr("odolab.comparison.load_odometers", lambda *a, **k: pytest.fail("loaded an odometer"))
    assert _turns(TURNS + ["--redraw", "--out", out]) == 0
    assert calls == [] and (out / "table.md").read_text() == table and (out / "turns.png").stat().st_size > 10_000
    assert _turns(["--odometers", "ground-truth", "--scenes", "2", "--per-scene", "2", "--redraw", "--out", out]) == 0
    assert "action-prior" not in (out / "table.md").read_text()  # the odometers named, only
    capsys.readouterr()
    assert _turns(TURNS + ["--scenes", "3", "--redraw", "--out", out]) == 2
    err = capsys.readouterr().err
    assert "made with --split val --seed 7 --scenes 2 --per-scene 2, not --split val --seed 7 --scenes 3" in err
    assert _turns(["--odometers", "icp", "--scenes", "2", "--per-scene", "2", "--redraw", "--out", out]) == 2
    assert "icp has 0 of 4 pairs" in capsys.readouterr().err
    assert _turns(TURNS + ["--redraw", "--out", tmp_path / "none"]) == 2
    assert "no such results file" in capsys.readouterr().err


def test_the_noise_study_redraws_from_its_results_without_computing(tmp_path, monkeypatch, capsys):
    def cli(*args) -> int:
        return run_cli(noise.main, "python -m studies.noise_robustness", [str(a) for a in args])

    out = tmp_path / "n"
    args = ["--odometers", "action-prior", "--episodes", 1, "--max-steps", 3, "--serial", "--quiet", "--out", out]
    assert cli(*args) == 0
    table = (out / "table.md").read_text()
    (out / "table.md").unlink()
    (out / "growth.png").unlink()
    monkeypatch.setattr(noise, "run_comparison", lambda *a, **k: pytest.fail("computed a comparison"))
    monkeypatch.setattr(noise, "load_odometer", lambda *a, **k: pytest.fail("loaded an odometer"))
    capsys.readouterr()
    assert cli(*args, "--redraw") == 0
    assert (out / "table.md").read_text() == table and (out / "growth.png").stat().st_size > 10_000
    assert cli(*args, "--redraw", "--levels", "3") == 2
    assert "has no result for 3/action-prior" in capsys.readouterr().err
    assert cli("--odometers", "action-prior", "--episodes", 2, "--max-steps", 3, "--redraw", "--out", out) == 2
    assert "--episodes 1" in capsys.readouterr().err
