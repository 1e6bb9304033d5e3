"""studies.robust_vo.scaling: samples seen and hours accumulate over stages; bad files are one line."""

import json
from pathlib import Path

import pytest

from studies.robust_vo import scaling

CURVES = """epoch,split,stage,loss,pairs,pairs_per_s,epochs,action,component,mae,prior_mae
1,train,forward,0.01,1000,10,1,,,,
1,val,forward,,50,,1,move_forward,dz,0.04,0.05
2,train,forward,0.01,1000,20,2,,,,
2,val,forward,,50,,2,move_forward,dz,0.03,0.05
1,train,turns,0.01,500,50,1,,,,
1,val,turns,,20,,1,turn_left,dyaw,0.02,0.05
"""


def test_points_count_every_earlier_stage(tmp_path: Path):
    run = tmp_path / "run-a"
    run.mkdir()
    (run / "curves.csv").write_text(CURVES)
    points = scaling.read_curves(run)
    assert [(p.stage, p.pairs) for p in points] == [("forward", 1000), ("forward", 2000), ("turns", 2500)]
    assert points[-1].hours == pytest.approx((100 + 50 + 10) / 3600)
    assert points[0].run == "run-a" and points[1].mae == 0.03


def test_a_run_from_a_trained_model_starts_after_that_models_training(tmp_path: Path):
    run = tmp_path / "warm"
    run.mkdir()
    (run / "curves.csv").write_text(CURVES)
    init = {
        "path": "m.pt",
        "sha256": "0" * 64,
        "stages": {"a": {"pairs_seen": 700, "hours": 0.5}, "b": {"pairs_seen": 300, "hours": 0.25}},
    }
    (run / "training.json").write_text(json.dumps({"stages": {}, "init": init}))
    points = scaling.read_curves(run)
    assert [p.pairs for p in points] == [2000, 3000, 3500]
    assert points[-1].hours == pytest.approx(0.75 + 160 / 3600)
    init["stages"]["b"]["hours"] = float("nan")
    (run / "training.json").write_text(json.dumps({"init": init}))
    with pytest.raises(ValueError, match=r"training.json: init.stages: expected"):
        scaling.read_curves(run)


def test_bad_files_are_named(tmp_path: Path):
    run = tmp_path / "r"
    run.mkdir()
    with pytest.raises(ValueError, match="curves.csv: cannot read"):
        scaling.read_curves(run)
    (run / "curves.csv").write_text("a,b\n1,2\n")
    with pytest.raises(ValueError, match="expected a training curves file"):
        scaling.read_curves(run)
    (run / "curves.csv").write_text(CURVES.replace("1000,10", "many,10"))
    with pytest.raises(ValueError, match="row 2: expected whole numbers"):
        scaling.read_curves(run)


def test_classical_lines_are_metres_and_radians(tmp_path: Path):
    table = tmp_path / "t.csv"
    table.write_text("odometer,action,dx,dz,dyaw\nicp,move_forward,1.5,0.8,1.1\nrobust-vo,move_forward,2,2,2\n")
    lines = scaling.read_classical(table)
    assert lines == {
        ("icp", "move_forward", "dx"): pytest.approx(0.015),
        ("icp", "move_forward", "dz"): pytest.approx(0.008),
        ("icp", "move_forward", "dyaw"): pytest.approx(0.011),
    }
