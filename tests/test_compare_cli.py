"""`python -m odolab.compare`: outputs, determinism by seed, and one-line errors for bad input."""

import csv
import subprocess
import sys
from pathlib import Path

import pytest

from odolab.cli import run_cli
from odolab.compare import main

FAST = ["--odometers", "ground-truth,action-prior", "--episodes", "2", "--max-steps", "12", "--serial", "--quiet"]


def _table(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def _errors(rows):
    return [(r["odometer"], r["dx"], r["dz"], r["dyaw"], r["ate_m"]) for r in rows]


def test_compare_writes_table_report_and_trajectories(tmp_path, capsys):
    out = tmp_path / "run"
    assert run_cli(main, "odolab.compare", [*FAST, "--out", str(out), "--cache", str(tmp_path / "c")]) == 0
    rows = _table(out / "table.csv")
    assert {"odometer", "dx", "dz", "dyaw", "fps", "failures"} <= set(rows[0])
    assert [r["odometer"] for r in rows] == ["ground-truth", "action-prior"]
    assert float(rows[0]["dz"]) == 0 and float(rows[1]["dz"]) > 0
    for f in ("report.html", "errors.png", "table_per_action.csv", "manifest.txt"):
        assert (out / f).stat().st_size > 0
    seq = min((out / "trajectories").iterdir())
    assert {p.name for p in seq.iterdir()} >= {
        "action-prior.tum",
        "action-prior.kitti",
        "groundtruth.tum",
        "groundtruth.kitti",
        "top-down.png",
    }
    printed = capsys.readouterr().out
    assert "action-prior" in printed and "table.csv" in printed
    page = (out / "report.html").read_text()
    assert "--odometers ground-truth,action-prior" in page  # the report's command names its odometers


def test_same_seed_same_errors_other_seed_other_errors(tmp_path):
    tables = {}
    for name, seed in (("a", "3"), ("b", "3"), ("c", "4")):
        out = tmp_path / name
        # no cache: each run generates its own episodes
        assert run_cli(main, "odolab.compare", [*FAST, "--seed", seed, "--no-cache", "--out", str(out)]) == 0
        tables[name] = _errors(_table(out / "table.csv"))
    assert tables["a"] == tables["b"]
    assert tables["a"] != tables["c"]


@pytest.mark.parametrize(
    "args,words",
    [
        (["--odometers", "nope"], "unknown odometer 'nope'; available:"),
        (["--odometers", ","], "--odometers is empty"),
        (["--split", "dev"], "choose one of train, val, test"),
        (["--episodes", "0"], "--episodes must be in [1, 1000], got 0"),
        (["--max-steps", "-3"], "--max-steps must be in [1, 500], got -3"),
        (["--episodes", "two"], "--episodes must be an integer"),
        (["--out", "/proc/odolab-cannot-write"], "not a writable folder"),
        (["--depth-noise", "-1"], "--depth-noise must be in [0, 10]"),
        (["--rgb-noise", "nan"], "--rgb-noise must be a finite number"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(args, words):
    proc = subprocess.run([sys.executable, "-m", "odolab.compare", *args], capture_output=True, text=True, check=False)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0] and lines[0].startswith("python -m odolab.compare: error:")
    assert "Traceback" not in proc.stderr


def test_compare_loads_a_user_class_by_module_path(tmp_path):
    out = tmp_path / "run"
    args = [
        "--odometers",
        "action-prior,examples.nominal_motion:NominalMotion",
        "--episodes",
        "1",
        "--max-steps",
        "10",
        "--serial",
        "--quiet",
        "--no-cache",
        "--out",
        str(out),
    ]
    proc = subprocess.run(
        [sys.executable, "-m", "odolab.compare", *args],
        capture_output=True,
        text=True,
        cwd=Path(__file__).resolve().parents[1],
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    names = [r["odometer"] for r in _table(out / "table.csv")]
    assert names == ["action-prior", "examples.nominal_motion:NominalMotion"]
    bad = subprocess.run(
        [sys.executable, "-m", "odolab.compare", "--odometers", "nowhere.mod:Nope"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert bad.returncode == 2 and "cannot import 'nowhere.mod:Nope'" in bad.stderr and "Traceback" not in bad.stderr


DATA = Path(__file__).resolve().parent / "data" / "tum_fr1_xyz_10"


def test_compare_on_a_tum_folder(tmp_path, capsys):
    out = tmp_path / "tum"
    args = ["--tum", str(DATA), "--odometers", "action-prior,ground-truth", "--out", str(out), "--quiet"]
    assert run_cli(main, "odolab.compare", args) == 0
    rows = {r["odometer"]: r for r in _table(out / "table.csv")}
    assert float(rows["action-prior"]["trans_mm"]) == pytest.approx(
        12.10, abs=0.01
    )  # no motion, docs/reference-facts.md section 6
    assert float(rows["ground-truth"]["trans_mm"]) < 1e-6
    assert "trans mm" in capsys.readouterr().out


def test_compare_on_a_broken_tum_folder_is_one_line(tmp_path):
    import shutil

    broken = tmp_path / "rgbd_dataset_freiburg1_broken"
    shutil.copytree(DATA, broken)
    (broken / "depth.txt").write_text("# header\n1305031102.175304 depth/1305031102.160407.png extra\n")
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "odolab.compare",
            "--tum",
            str(broken),
            "--odometers",
            "action-prior",
            "--out",
            str(tmp_path / "o"),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    line = proc.stderr.strip()
    assert "depth.txt" in line and "line 2" in line and len(line.splitlines()) == 1


def test_evaluate_reads_what_compare_wrote(tmp_path):
    import json

    out = tmp_path / "one"
    args = [
        "--odometers",
        "action-prior",
        "--episodes",
        "1",
        "--max-steps",
        "15",
        "--serial",
        "--quiet",
        "--no-cache",
        "--out",
        str(out),
    ]
    assert run_cli(main, "odolab.compare", args) == 0
    ate = float(_table(out / "table.csv")[0]["ate_m"])
    seq = next((out / "trajectories").iterdir())
    for fmt in ("tum", "kitti"):
        proc = subprocess.run(
            [
                sys.executable,
                "-m",
                "odolab.evaluate",
                str(seq / f"groundtruth.{fmt}"),
                str(seq / f"action-prior.{fmt}"),
                "--format",
                fmt,
                "--align",
                "none",
                "--json",
            ],
            capture_output=True,
            text=True,
            check=False,
        )
        assert proc.returncode == 0, proc.stderr
        doc = json.loads(proc.stdout)
        assert doc["estimates"][0]["ate"] == pytest.approx(ate, rel=1e-3)


def test_noiseless_sensors_and_actuation_change_the_errors(tmp_path):
    base = ["--odometers", "action-prior", "--episodes", "1", "--max-steps", "12", "--serial", "--quiet", "--no-cache"]
    assert run_cli(main, "odolab.compare", [*base, "--out", str(tmp_path / "a")]) == 0
    assert run_cli(main, "odolab.compare", [*base, "--actuation-noise", "0", "--out", str(tmp_path / "b")]) == 0
    noisy, exact = _table(tmp_path / "a" / "table.csv")[0], _table(tmp_path / "b" / "table.csv")[0]
    # Without actuation noise the true motion is the nominal one; the prior's mean is off by its bias only
    assert float(exact["dyaw"]) < float(noisy["dyaw"])


def test_a_composite_is_paired_with_its_input_in_table_paired_and_the_report(tmp_path, capsys):
    out = tmp_path / "run"
    names = "action-prior,noiseless-depth(action-prior)"  # the prior reads no depth: no difference
    argv = ["--odometers", names, "--episodes", "2", "--max-steps", "6", "--serial", "--quiet", "--no-cache"]
    assert run_cli(main, "odolab.compare", [*argv, "--out", str(out)]) == 0
    assert "noiseless-depth(action-prior) against action-prior, paired on 12 steps" in capsys.readouterr().out
    rows = _table(out / "table_paired.csv")
    assert {(r["action"], r["component"]) for r in rows} >= {("all", "dx"), ("all", "dz"), ("all", "dyaw")}
    assert all(float(r["diff"]) == 0 and r["verdict"] == "undecided" for r in rows)
    assert {r["sequences"] for r in rows if r["action"] == "all"} == {"2"}
    assert "What each composite adds over its input" in (out / "report.html").read_text()
    assert "table_paired.csv" in (out / "manifest.txt").read_text()
