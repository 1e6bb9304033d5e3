"""studies/robust_vo/inference_precision: both precisions run on the same steps, and the summary
holds each one's row and bf16's paired difference against fp32; bad sizes are refused."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("torch")  # a declared dependency; skip only where it is truly absent

from odolab.cli.study import command
from studies.robust_vo.inference_precision import BF16, FP32


@pytest.mark.slow
def test_inference_precision_pairs_bf16_with_fp32_on_the_same_steps(tmp_path, capsys):
    assert command("inference-precision", ["--episodes", "2", "--max-steps", "4", "--out", str(tmp_path / "out")]) == 0
    found = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert found["command"].startswith("python -m studies.robust_vo.inference_precision --episodes 2")
    assert [r["odometer"] for r in found["rows"]] == [FP32, BF16]
    assert all(r["steps"] == found["rows"][0]["steps"] > 0 for r in found["rows"])
    overall = [p for p in found["paired"] if p["action"] == "all"]
    assert [p["component"] for p in overall] == ["dx", "dz", "dyaw"]
    assert all(p["odometer"] == BF16 and p["against"] == FP32 and p["sequences"] == 2 for p in overall)
    assert all(abs(p["diff"]) < 0.5 for p in overall)  # x 1e-2: bf16 keeps the shipped model's answers
    assert "paired on" in capsys.readouterr().out


def test_inference_precision_refuses_too_few_episodes_in_one_line(capsys):
    assert command("inference-precision", ["--episodes", "1"]) == 2
    said = capsys.readouterr().err.strip().splitlines()
    assert len(said) == 1 and "--episodes" in said[0] and "1" in said[0]


def test_inference_precision_refuses_a_folder_it_does_not_own(tmp_path, capsys):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "summary.json").write_text('{"my": "own data"}')
    assert command("inference-precision", ["--episodes", "2", "--max-steps", "1", "--out", str(mine)]) == 2
    assert "--out" in capsys.readouterr().err and (mine / "summary.json").read_text() == '{"my": "own data"}'
