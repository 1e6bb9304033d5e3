"""The studies resume from their saved results (keyed by what they depend on) and redraw their
reports from them without computing anything (issue 42)."""

from __future__ import annotations

import shutil

import pytest

import studies.noise_robustness as noise
import studies.turns_by_depth as turns
from odolab.cli.study import command
from studies import framework

CI = ["--scale", "ci", "--serial", "--quiet"]


def _turns(*args) -> int:
    return command("turns-by-depth", [*CI, *map(str, args)])


def _counting(monkeypatch) -> list[str]:
    """Every turn an odometer answers, by odometer class name."""
    calls: list[str] = []
    real = turns._answer

    def answer(odometer, *args):
        calls.append(type(odometer).__name__)
        return real(odometer, *args)

    monkeypatch.setattr(turns, "_answer", answer)
    return calls


@pytest.mark.slow
def test_the_turns_study_resumes_scene_by_scene_and_redraws_without_computing(tmp_path, monkeypatch, capsys):
    out = tmp_path / "t"
    scale = framework.scale_params(framework.load_study("turns_by_depth"), "ci", turns.Scale)
    per_run = len(scale.odometers) * scale.scenes * scale.per_scene
    calls = _counting(monkeypatch)
    assert _turns("--out", out) == 0
    assert len(calls) == per_run
    table = (out / "table.csv").read_text()
    calls.clear()
    assert _turns("--out", out) == 0
    assert calls == [] and (out / "table.csv").read_text() == table  # all saved: nothing computed
    unit = turns.units(scale, {o: None for o in scale.odometers})[-1]  # interrupted before the last scene
    (out / "results" / f"{unit.digest}.json").unlink()
    assert _turns("--out", out) == 0
    assert len(calls) == scale.per_scene and (out / "table.csv").read_text() == table  # only that scene
    calls.clear()
    real = framework.identities
    monkeypatch.setattr(  # as if ground-truth's settings had changed
        framework, "identities", lambda *a: {**real(*a), "ground-truth": "0" * 64}
    )
    assert _turns("--out", out) == 0
    assert len(calls) == scale.scenes * scale.per_scene and (out / "table.csv").read_text() == table
    monkeypatch.setattr(framework, "identities", real)
    calls.clear()
    # --redraw: the report from the saved results alone, in a folder holding nothing else
    copy = tmp_path / "copy"
    shutil.copytree(out / "results", copy / "results")
    shutil.copy(out / "manifest.txt", copy / "manifest.txt")
    monkeypatch.setattr(turns, "unit_result", lambda key: pytest.fail("computed a unit"))
    capsys.readouterr()
    assert _turns("--redraw", "--out", copy) == 0
    assert "0 units computed" in capsys.readouterr().out
    assert calls == [] and (copy / "table.csv").read_text() == table and (copy / "turns.png").stat().st_size > 10_000
    assert command("turns-by-depth", ["--scale", "ci", "--redraw", "--out", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err
    assert "no saved results in" in err and err.count("\n") == 1


@pytest.mark.slow
def test_the_noise_study_redraws_from_its_results_without_computing(tmp_path, monkeypatch, capsys):
    def cli(*args) -> int:
        return command("noise-robustness", [*CI, *map(str, args)])

    out = tmp_path / "n"
    assert cli("--out", out) == 0
    table = (out / "table.csv").read_text()
    for name in ("table.md", "table.csv", "errors.png", "growth.png", "index.html"):
        (out / name).unlink()
    monkeypatch.setattr(noise, "unit_result", lambda key: pytest.fail("computed a unit"))
    capsys.readouterr()
    assert cli("--out", out, "--redraw") == 0
    assert "0 units computed" in capsys.readouterr().out
    assert (out / "table.csv").read_text() == table and (out / "errors.png").stat().st_size > 10_000
    victim = min((out / "results").glob("*.json"))
    victim.write_text('{"a":' * 100_000)  # damaged: left out, and said so
    assert cli("--out", out, "--redraw") == 0
    captured = capsys.readouterr()
    assert "note: no saved result (no number in the table comes from them):" in captured.err
    assert "Missing (not computed):" in (out / "index.html").read_text()
    assert len((out / "table.csv").read_text().splitlines()) == len(table.splitlines()) - 1
