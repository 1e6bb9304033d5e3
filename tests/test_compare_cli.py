"""`python -m odolab.compare`: outputs, determinism by seed, and one-line errors for bad input (numbers,
--out and --cache, --tum folders and their camera, Ray addresses), each before any folder is made."""

import csv
import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from odolab.cli import run_cli
from odolab.compare import main
from tests.helpers import FR1, ROOT, one_line_error, outside_folder, stderr_line

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


@pytest.mark.slow
def test_same_seed_same_errors_other_seed_other_errors(tmp_path):
    tables = {}
    for name, seed in (("a", "3"), ("b", "3"), ("c", "4")):
        out = tmp_path / name
        # no cache: each run generates its own episodes
        assert run_cli(main, "odolab.compare", [*FAST, "--seed", seed, "--no-cache", "--out", str(out)]) == 0
        tables[name] = _errors(_table(out / "table.csv"))
    assert tables["a"] == tables["b"]
    assert tables["a"] != tables["c"]


@pytest.mark.slow
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


@pytest.mark.slow
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


def test_a_bad_option_is_one_line_from_the_command_line():
    proc = subprocess.run(
        [sys.executable, "-m", "odolab.compare", "--seed", "-1"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
        check=False,
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip() == "python -m odolab.compare: error: --seed must be in [0, 4294967295], got -1"


@pytest.mark.parametrize(
    "args,words",
    [
        (["--seed", "-1"], "--seed must be in [0, 4294967295], got -1"),
        (["--seed", "99999999999"], "--seed must be in"),
        (["--rgb-noise", "inf"], "--rgb-noise must be a finite number"),
        (["--depth-noise", "1e300"], "--depth-noise must be in [0, 10]"),
        (["--actuation-noise", "nan"], "--actuation-noise must be a finite number"),
        (["--episodes", "10000000"], "--episodes must be in [1, 1000]"),
        (["--max-steps", "100000"], "--max-steps must be in [1, 500]"),
    ],
)
def test_compare_numeric_options_have_ranges(args, words):
    one_line_error("odolab.compare", *args, words=words)


@pytest.mark.slow
def test_compare_output_paths_are_checked_before_work(tmp_path):
    a_file = tmp_path / "file"
    a_file.write_text("x")
    one_line_error("odolab.compare", "--cache", a_file, "--out", tmp_path / "o", words="--cache")
    one_line_error("odolab.compare", "--out", a_file, words="is a file, not a folder")
    one_line_error(
        "odolab.compare",
        "--no-cache",
        "--cache",
        tmp_path / "c",
        "--out",
        tmp_path / "o",
        words="--cache and --no-cache contradict",
    )
    # /proc refuses new files even to root: a read-only location on every Linux machine
    one_line_error(
        "odolab.compare",
        "--cache",
        "/proc/odolab-cache",
        "--out",
        tmp_path / "o",
        words="--cache /proc/odolab-cache: not a writable folder",
    )


def test_a_tum_folder_without_its_lists_is_refused_before_the_out_folder_is_made(tmp_path):
    folder = tmp_path / "rgbd_dataset_freiburg1_xyz"
    folder.mkdir()
    one_line_error(
        "odolab.compare", "--odometers", "icp", "--tum", folder, "--out", tmp_path / "o", words="rgb.txt: no such file"
    )
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    "address,words",
    [
        ("127.0.0.1:1", "no Ray cluster there"),  # a dead loopback port: nothing listens
        ("not an address", "is not an address"),
        ("127.0.0.1:99999", "is not an address"),
    ],
)
def test_ray_address_fails_within_seconds(tmp_path, address, words):
    start = time.monotonic()
    one_line_error(
        "odolab.compare",
        "--ray-address",
        address,
        "--odometers",
        "action-prior",
        "--episodes",
        "2",
        "--max-steps",
        "5",
        "--no-cache",
        "--out",
        tmp_path,
        words=words,
    )
    assert time.monotonic() - start < 30


@pytest.mark.parametrize(
    "args,words",
    [
        (["--episodes", "3"], "--episodes: simulator option, meaningless with --tum"),
        (["--split=val", "--rgb-noise", "2"], "--split, --rgb-noise: simulator options"),
    ],
)
def test_tum_refuses_simulator_options(tmp_path, args, words):
    one_line_error("odolab.compare", "--tum", DATA, *args, "--out", tmp_path, words=words)


def test_tum_says_how_many_frames_it_left_out(tmp_path, capsys):
    import shutil

    from odolab.compare import main

    folder = tmp_path / "rgbd_dataset_freiburg1_cut"
    shutil.copytree(DATA, folder)
    lines = (folder / "depth.txt").read_text().splitlines()
    (folder / "depth.txt").write_text("\n".join(lines[:-3]) + "\n")
    out = tmp_path / "out"
    assert (
        run_cli(
            main, "odolab.compare", ["--tum", str(folder), "--odometers", "action-prior", "--quiet", "--out", str(out)]
        )
        == 0
    )
    said = "7 frames; colour images left out: 3 without a depth image and 0 without a ground-truth pose"
    assert said in capsys.readouterr().err and said in (out / "report.html").read_text()


def test_an_empty_out_or_a_folder_of_someone_elses_files_is_refused(tmp_path):
    one_line_error("odolab.compare", "--out", "", words="--out is empty")
    one_line_error("odolab.compare", "--cache", "", words="--cache is empty")
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "report.html").write_text("mine")
    one_line_error("odolab.compare", "--out", theirs, "--serial", words="holds files odolab did not write")
    assert (theirs / "report.html").read_text() == "mine"


def test_a_report_folder_holding_a_pipe_or_a_dead_link_is_refused_before_work(tmp_path):
    import os

    for kind in ("fifo", "dead"):
        out = tmp_path / kind
        out.mkdir()
        (out / "manifest.txt").write_text("table.csv\n")
        if kind == "fifo":
            os.mkfifo(out / "table.csv")
        else:
            (out / "table.csv").symlink_to(tmp_path / "missing" / "t.csv")
        words = "is not a regular file" if kind == "fifo" else "is a link to nothing"
        one_line_error(
            "odolab.compare",
            "--odometers",
            "action-prior",
            "--episodes",
            "1",
            "--max-steps",
            "5",
            "--no-cache",
            "--serial",
            "--out",
            out,
            words=words,
        )


def test_compare_tum_that_is_not_a_folder_is_said_so_before_the_camera(tmp_path, capsys):
    """A file, a missing path or a dead link given to --tum read 'cannot tell the camera from the
    folder's name', or 'no such folder' for a file."""
    from odolab.cli.compare import main

    (tmp_path / "rgbd_fr1.txt").write_text("x")
    (tmp_path / "dead_fr1").symlink_to(tmp_path / "nowhere")
    for name, words in [
        ("rgbd_fr1.txt", "is a file, not a folder"),
        ("missing", "no such folder"),
        ("dead_fr1", "is a link to nothing"),
    ]:
        argv = ["--tum", str(tmp_path / name), "--out", str(tmp_path / "out")]
        assert run_cli(main, "python -m odolab.compare", argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and f"--tum {tmp_path / name}: {words}" in err, err


@pytest.mark.parametrize(
    "args,words",
    [
        ([], "cannot tell the camera from the folder's name (no fr1, fr2 or fr3 in it); give it with --intrinsics"),
        (["--intrinsics", "517,516,318"], "--intrinsics must be four numbers fx,fy,cx,cy"),
        (["--intrinsics", "0,516,318,255"], "--intrinsics: the focal lengths fx, fy must be positive"),
        (["--intrinsics", ",".join(map(str, FR1)), "--depth-scale", "0"], "--depth-scale must be in [1, 1000000]"),
    ],
)
def test_compare_names_a_missing_or_bad_camera_and_scale_in_one_line(millimetre_folder, tmp_path, args, words):
    one_line_error(
        "odolab.compare",
        "--tum",
        millimetre_folder,
        "--odometers",
        "ground-truth",
        *args,
        "--out",
        tmp_path / "o",
        words=words,
    )


def test_the_tum_options_need_a_tum_folder(tmp_path):
    one_line_error(
        "odolab.compare",
        "--depth-scale",
        "1000",
        "--out",
        tmp_path / "o",
        words="--depth-scale describes a TUM folder's images; it needs --tum",
    )


def test_a_terminal_sees_a_line_at_once_that_the_next_one_writes_over(monkeypatch, capsys, tmp_path):
    """Loading the odometers takes seconds: on a terminal a transient line says so at once (ended by a
    carriage return, not a newline); captured output and --quiet get none."""
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    args = ["--odometers", "corrected(feature-essential)", "--out", str(tmp_path / "o")]  # no model shipped
    assert run_cli(main, "python -m odolab.compare", args) == 2
    err = capsys.readouterr().err
    assert err.startswith("loading odometers\r") and err.count("\n") == 1 and "no shipped model" in err
    assert run_cli(main, "python -m odolab.compare", [*args, "--quiet"]) == 2
    assert not capsys.readouterr().err.startswith("loading")


def _compare(argv) -> int:
    from odolab.compare import main

    return run_cli(main, "python -m odolab.compare", [str(a) for a in argv])


COMPARE = ["--odometers", "action-prior", "--episodes", "1", "--max-steps", "3", "--no-cache", "--serial", "--quiet"]


def test_compare_refuses_a_linked_or_misplaced_folder_before_any_work(tmp_path, capsys):
    outside = outside_folder(tmp_path)
    out = tmp_path / "run"
    (out / "trajectories").mkdir(parents=True)
    (out / "manifest.txt").write_text("trajectories/test-0000/victim.tum\n")
    (out / "trajectories" / "test-0000").symlink_to(outside, target_is_directory=True)
    assert _compare(COMPARE + ["--out", out]) == 2
    stderr_line(capsys, "trajectories/test-0000", "expected a file or folder", "found a symbolic link to")
    assert (outside / "victim.tum").read_text() == "precious" and not (out / "table.csv").exists()
    (out / "trajectories" / "test-0000").unlink()
    (out / "trajectories").rmdir()
    (out / "trajectories").write_text("a file where compare keeps a folder")
    assert _compare(COMPARE + ["--out", out]) == 2
    stderr_line(capsys, "trajectories", "expected a folder, found a file")
    assert not (out / "table.csv").exists()
