"""studies.robust_vo.scaling: samples seen and hours accumulate over stages; bad files are one line."""

import json
from pathlib import Path

import pytest

from odolab.cli.study import command
from studies.robust_vo import scaling

CURVES = """epoch,split,stage,loss,pairs,pairs_per_s,epochs,action,component,mae,prior_mae
1,train,forward,0.01,1000,10,1,,,,
1,val,forward,,50,,1,move_forward,dz,0.04,0.05
2,train,forward,0.01,1000,20,2,,,,
2,val,forward,,50,,2,move_forward,dz,0.03,0.05
1,train,turns,0.01,500,50,1,,,,
1,val,turns,,20,,1,turn_left,dyaw,0.02,0.05
"""


def test_points_count_the_earlier_stages_that_train_their_action(tmp_path: Path):
    run = tmp_path / "run-a"
    run.mkdir()
    (run / "curves.csv").write_text(CURVES)
    points = scaling.read_curves(run)
    # a turn's point counts the turn stage's samples only, a forward point the forward stage's
    assert [(p.stage, p.pairs) for p in points] == [("forward", 1000), ("forward", 2000), ("turns", 500)]
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
    assert [p.pairs for p in points] == [2000, 3000, 1500]  # the init's stages, not matched to actions: every action
    assert points[-1].hours == pytest.approx(0.75 + 160 / 3600)
    assert {(p.start, p.start_from) for p in points} == {(1000, "")}  # m.pt in the working folder: no run name
    # the init's own run beside its model: its stages count for the actions they validate
    (tmp_path / "first").mkdir()
    (tmp_path / "first" / "curves.csv").write_text(CURVES.replace(",forward,", ",a,").replace(",turns,", ",b,"))
    init["path"] = str(tmp_path / "first" / "model.pt")
    (run / "training.json").write_text(json.dumps({"stages": {}, "init": init}))
    points = scaling.read_curves(run)
    assert [p.pairs for p in points] == [1700, 2700, 800] and points[0].start_from == "first"
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
    assert scaling.classical_split(table) == ""  # no trajectories beside it: the split is not known
    for name in ("val-s0-e000", "val-s0-e001"):
        (tmp_path / "trajectories" / name).mkdir(parents=True)
    assert scaling.classical_split(table) == "val"
    (tmp_path / "trajectories" / "test-s0-e000").mkdir()
    assert scaling.classical_split(table) == ""  # two splits: none named


_CURVES_HEAD = "epoch,split,stage,pairs,pairs_per_s,action,component,mae,prior_mae\n"


@pytest.mark.parametrize(
    ("curves", "words"),
    [
        ("", "expected a training curves file"),  # an empty file
        (b"\xff\xfe\x00", "not a text file"),
        (_CURVES_HEAD + "1,train,forward,100,10,,,,\n", "no validation rows"),
        (_CURVES_HEAD + "1,train,forward,100,nan,,,,\n1,val,forward,,,move_forward,dz,0.1,0.2\n", "row 2"),
        (_CURVES_HEAD + "1,train,forward,100,10,,,,\n1,val,forward,,,move_forward,dz,inf,0.2\n", "row 3"),
    ],
)
def test_scaling_refuses_unusable_curves_in_one_line_and_makes_nothing(tmp_path, capsys, curves, words):
    """These were tracebacks (ValueError, UnicodeDecodeError) after --out was made, or an empty plot."""
    run = tmp_path / "run"
    run.mkdir()
    getattr(run / "curves.csv", "write_bytes" if isinstance(curves, bytes) else "write_text")(curves)
    (tmp_path / "t.csv").write_text("odometer,action,dx,dz,dyaw\nicp,move_forward,1,1,1\n")
    argv = ["--runs", str(run), "--classical", str(tmp_path / "t.csv"), "--out", str(tmp_path / "out")]
    assert command("robust-vo-scaling", argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("python -m studies.robust_vo.scaling: error: --runs: ")
    assert words in err and not (tmp_path / "out").exists()


@pytest.mark.slow
def test_scaling_names_a_bad_classical_table_and_keeps_same_named_runs_apart(tmp_path, capsys):
    curves = _CURVES_HEAD + "1,train,forward,100,10,,,,\n1,val,forward,,,move_forward,dz,0.1,0.2\n"
    for parent in ("a", "b"):
        (tmp_path / parent / "run").mkdir(parents=True)
        (tmp_path / parent / "run" / "curves.csv").write_text(curves)
    table = tmp_path / "t.csv"
    table.write_text("odometer,action,dx,dz,dyaw\nicp,move_forward,x,1,1\n")
    runs = ["--runs", str(tmp_path / "a" / "run"), str(tmp_path / "b" / "run" / "curves.csv")]
    out = ["--out", str(tmp_path / "out")]
    assert command("robust-vo-scaling", [*runs, "--classical", str(table), *out]) == 2
    err = capsys.readouterr().err
    assert f"--classical: {table}: row 2: dx: expected a number" in err and len(err.strip().splitlines()) == 1
    assert command("robust-vo-scaling", [*runs[:2], runs[1] + "/", "--classical", str(table), *out]) == 2
    assert "given twice" in capsys.readouterr().err
    table.write_text("odometer,action,dx,dz,dyaw\nicp,move_forward,1,1,1\n")
    assert command("robust-vo-scaling", [*runs, "--classical", str(table), *out]) == 0
    labels = {line.split(",")[0] for line in (tmp_path / "out" / "scaling.csv").read_text().splitlines()[1:]}
    assert labels == {str(tmp_path / "a" / "run"), str(tmp_path / "b" / "run")}
