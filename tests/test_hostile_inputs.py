"""Hostile input, one test per class: every command answers with one line and exit code 2 (no
traceback), damaged caches regenerate, finished work is never lost, outputs honour the umask."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from odolab.cli import run_cli
from odolab.parallel import SERIAL, Execution

ROOT = Path(__file__).resolve().parents[1]
TUM_OK = "1.0 0 0 0 0 0 0 1\n2.0 1 0 0 0 0 0 1\n3.0 1 1 0 0 0 0 1\n4.0 0 1 1 0 0 0 1\n"


def one_line_error(module: str, *args: str, words: str) -> None:
    """Run ``python -m module args`` in this process (as its ``__main__`` would, through
    ``run_cli``): exit 2, one line on stderr naming ``words``, no traceback."""
    import contextlib
    import importlib
    import io

    from odolab.cli.commands import COMMANDS

    command = {m: c for m, c, _ in COMMANDS.values()} | {"odolab.action_prior": "odolab.cli.action_prior"}
    main = importlib.import_module(command.get(module, module)).main
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = run_cli(main, module, [str(a) for a in args])
    assert code == 2, err.getvalue()
    lines = err.getvalue().strip().splitlines()
    assert len(lines) == 1, err.getvalue()
    assert words in lines[0] and lines[0].startswith(f"{module}: error: "), lines[0]


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


# ----------------------------------------------------------------------------- numeric options


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


@pytest.mark.parametrize(
    "args,words",
    [
        (["--delta", "nan"], "--delta must be a finite number"),
        (["--delta", "inf"], "--delta must be a finite number"),
        (["--delta", "1e300"], "--delta must be <="),
        (["--t-max-diff", "-1"], "--t-max-diff must be in [0, 60]"),
        (["--min-coverage", "nan"], "--min-coverage must be a finite number"),
    ],
)
def test_evaluate_numeric_options_have_ranges(tmp_path, args, words):
    gt = tmp_path / "gt.txt"
    gt.write_text(TUM_OK)
    one_line_error("odolab.evaluate", gt, gt, "--format", "tum", *args, words=words)


@pytest.mark.parametrize(
    "args,words",
    [
        (["--seed", "-5"], "--seed must be in"),
        (["--episodes", "1e9"], "--episodes must be an integer"),
        (["--episodes", "100000000"], "--episodes must be in"),
        (["--max-steps", "0"], "--max-steps must be in"),
    ],
)
def test_action_prior_numeric_options_have_ranges(args, words):
    one_line_error("odolab.action_prior", *args, words=words)


# ----------------------------------------------------------------------------- output paths


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


@pytest.mark.parametrize(
    ("module", "option", "words"),
    [
        ("odolab.compare", "icp.max_depth=-1", "max_depth must be in"),
        ("odolab.navigate", "icp.bogus=1", "has no option 'bogus'"),
        ("odolab.compare", "icp.max_dept=3", "has no option 'max_dept' (did you mean 'max_depth'"),
    ],
)
def test_a_bad_odometer_option_is_refused_before_the_out_folder_is_made(tmp_path, module, option, words):
    one_line_error(module, "--odometers", "icp", "--odometer-option", option, "--out", tmp_path / "o", words=words)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("module", ["odolab.compare", "odolab.navigate"])
def test_an_odometer_list_with_an_empty_name_is_refused(tmp_path, module):
    one_line_error(module, "--odometers", "icp,", "--out", tmp_path / "o", words="'icp,' has an empty name")


def test_a_tum_folder_without_its_lists_is_refused_before_the_out_folder_is_made(tmp_path):
    folder = tmp_path / "rgbd_dataset_freiburg1_xyz"
    folder.mkdir()
    one_line_error(
        "odolab.compare", "--odometers", "icp", "--tum", folder, "--out", tmp_path / "o", words="rgb.txt: no such file"
    )
    assert not (tmp_path / "o").exists()


def test_evaluate_plot_path_is_checked_before_work(tmp_path):
    gt = tmp_path / "gt.txt"
    gt.write_text(TUM_OK)
    one_line_error(
        "odolab.evaluate", gt, gt, "--format", "tum", "--plot", tmp_path / "fig.xyz", words="unknown file type '.xyz'"
    )
    one_line_error("odolab.evaluate", gt, gt, "--format", "tum", "--plot", tmp_path, words="is a folder, not a file")
    one_line_error(
        "odolab.evaluate", gt, gt, "--format", "tum", "--plot", tmp_path / "no" / "f.png", words="does not exist"
    )
    one_line_error("odolab.evaluate", gt, gt, "--format", "tum", "--plot", "/proc/f.png", words="cannot write in /proc")


def test_bench_json_path_is_checked_before_work(tmp_path):
    one_line_error("odolab.bench", "--only", "evaluate", "--json", tmp_path, words="is a folder, not a file")
    notes = tmp_path / "notes.md"  # a slip of the tab key must not overwrite a document
    notes.write_text("mine")
    one_line_error("odolab.bench", "--only", "evaluate", "--json", notes, words="unknown file type '.md'")
    (tmp_path / "link.json").symlink_to(notes)  # the link's name is not what would be replaced
    one_line_error(
        "odolab.bench",
        "--only",
        "evaluate",
        "--json",
        tmp_path / "link.json",
        words=f"links to {notes}, unknown file type '.md'",
    )
    assert notes.read_text() == "mine"
    one_line_error("odolab.bench", "--only", "evaluate", "--json", f"{tmp_path}/new.json/", words="ends in '/'")
    assert not (tmp_path / "new.json").exists()
    one_line_error("odolab.bench", "--only", "evaluate", "--json", tmp_path / ".json", words="has no file extension")
    one_line_error("odolab.action_prior", "--out", f"{tmp_path}/p.json/", words="ends in '/'")


# ----------------------------------------------------------------------------- Ray addresses


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


# ----------------------------------------------------------------------------- damaged cache


@pytest.mark.parametrize("damage", ["truncated", "bad crc"])
def test_damaged_cache_entry_is_named_and_regenerated(tmp_path, small_spec, capsys, damage):
    import dataclasses

    from odolab.episodes import EpisodeCache, load_episodes, render_episode

    small_spec = dataclasses.replace(small_spec, max_steps=4)
    cache = EpisodeCache(tmp_path)
    path = cache.put(render_episode(small_spec))
    good = path.read_bytes()
    k = len(good) // 3  # inside the rgb member: the zip directory stays readable, the CRC fails
    path.write_bytes(
        good[: len(good) // 2] if damage == "truncated" else good[:k] + bytes([good[k] ^ 0xFF]) + good[k + 1 :]
    )
    capsys.readouterr()
    (ep,) = load_episodes([small_spec], cache, execution=SERIAL)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0] and "damaged" in err[0]
    assert path.read_bytes() == good  # regenerated, bit for bit, and written back
    assert cache.get(small_spec) is not None and np.array_equal(ep.rgb, cache.get(small_spec).rgb)


# ----------------------------------------------------------------------------- TUM files


def test_duplicate_timestamps_keep_the_first_and_are_counted(tmp_path, capsys):
    from odolab.evaluate import main
    from odolab.io.tum import read_tum_file

    gt = tmp_path / "gt.txt"
    lines = TUM_OK.splitlines(True)
    gt.write_text(lines[0] + lines[1] + lines[1].replace(" 1 0 0 0", " 9 0 0 0", 1) + "".join(lines[2:]))
    traj, dropped = read_tum_file(gt)
    assert dropped == 1 and len(traj) == 4 and traj.poses[1, 0, 3] == 1.0
    est = tmp_path / "est.txt"
    est.write_text(TUM_OK)
    assert run_cli(main, "odolab.evaluate", [str(gt), str(est), "--format", "tum"]) == 0
    assert f"repeated timestamps dropped, first kept: 1 in {gt}" in capsys.readouterr().out


def test_error_messages_print_plain_numbers(tmp_path):
    from odolab.io.errors import FileFormatError
    from odolab.io.tum import read_tum_trajectory

    bad = tmp_path / "t.txt"
    bad.write_text("2.5 0 0 0 0 0 0 1\n1.5 0 0 0 0 0 0 1\n")
    with pytest.raises(FileFormatError) as info:
        read_tum_trajectory(bad)
    assert "1.5 (previous line 1 has 2.5)" in str(info.value) and "np." not in str(info.value)


# ----------------------------------------------------------------------------- file modes


def test_outputs_honour_the_umask(tmp_path):
    from odolab.io.atomic import atomic_open, write_text_atomic

    old = os.umask(0o027)
    try:
        write_text_atomic(tmp_path / "a.txt", "x")
        with atomic_open(tmp_path / "b.bin") as f:
            f.write(b"y")
    finally:
        os.umask(old)
    for name in ("a.txt", "b.bin"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o640


# ----------------------------------------------------------------------------- --tum and its options

TUM_DIR = ROOT / "tests" / "data" / "tum_fr1_xyz_10"


@pytest.mark.parametrize(
    "args,words",
    [
        (["--episodes", "3"], "--episodes: simulator option, meaningless with --tum"),
        (["--split=val", "--rgb-noise", "2"], "--split, --rgb-noise: simulator options"),
    ],
)
def test_tum_refuses_simulator_options(tmp_path, args, words):
    one_line_error("odolab.compare", "--tum", TUM_DIR, *args, "--out", tmp_path, words=words)


def test_tum_says_how_many_frames_it_left_out(tmp_path, capsys):
    import shutil

    from odolab.compare import main

    folder = tmp_path / "rgbd_dataset_freiburg1_cut"
    shutil.copytree(TUM_DIR, folder)
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


def test_fan_out_checks_the_address_before_starting_ray():
    from odolab.parallel import fan_out

    start = time.monotonic()
    with pytest.raises(ValueError, match="no Ray cluster there"):
        fan_out(abs, [1, 2], execution=Execution(ray_address="127.0.0.1:1", progress=False))
    assert time.monotonic() - start < 10


@pytest.mark.parametrize("command", ["odolab.compare", "baselines.measure_tum"])
def test_a_bad_image_stops_before_any_odometer_runs(tmp_path, command):
    import shutil

    folder = tmp_path / "rgbd_dataset_freiburg1_bad"
    shutil.copytree(TUM_DIR, folder)
    depth = max((folder / "depth").iterdir())  # the last frame: found before the first step
    depth.write_bytes(depth.read_bytes()[:100])
    args = ["--tum", folder, "--out", tmp_path / "o"] if command == "odolab.compare" else [folder]
    proc = subprocess.run(
        [sys.executable, "-m", command, *map(str, args)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr and proc.stdout == ""
    (line,) = proc.stderr.strip().splitlines()
    assert f"{depth}: cannot be read as an image (listed in depth.txt, line 13)" in line


def test_measure_tum_runs_reference_rows_and_names_an_unknown_odometer(capsys):
    from baselines.measure_tum import main as measure_main

    assert (
        measure_main([str(TUM_DIR), "--odometers", "ground-truth", "action-prior", "no-motion", "--repeat", "1"]) == 0
    )
    out = capsys.readouterr().out
    rows = {
        line.split("|")[1].strip(): line.split("|")[2].strip() for line in out.splitlines() if line.startswith("| ")
    }
    assert rows["ground-truth"] == "0.00" and float(rows["no-motion"]) > 5 and rows["action-prior"] == rows["no-motion"]
    assert measure_main([str(TUM_DIR), "--odometers", "nope"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown odometer 'nope'" in err[0]


def test_an_empty_out_or_a_folder_of_someone_elses_files_is_refused(tmp_path):
    one_line_error("odolab.compare", "--out", "", words="--out is empty")
    one_line_error("odolab.compare", "--cache", "", words="--cache is empty")
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "report.html").write_text("mine")
    one_line_error("odolab.compare", "--out", theirs, "--serial", words="holds files odolab did not write")
    assert (theirs / "report.html").read_text() == "mine"


def test_an_interrupted_rerun_never_mixes_two_runs(tmp_path):
    from odolab.report import MANIFEST, OutputFolder

    first = OutputFolder(tmp_path)
    for rel in ("table.csv", "report.html", "trajectories/a/icp.tum"):
        first.path(rel).write_text("old")
    first.finish()
    second = OutputFolder(tmp_path)  # the previous run's files go first
    assert not (tmp_path / "report.html").exists() and not (tmp_path / "trajectories").exists()
    second.path("table.csv").write_text("new")
    # interrupted here: the manifest already names what this run wrote, and nothing else
    assert (tmp_path / MANIFEST).read_text().splitlines() == ["# odolab compare", "table.csv"]
    OutputFolder(tmp_path)  # the next run cleans it up
    assert not (tmp_path / "table.csv").exists()


def test_an_odometer_calling_sys_exit_fails_its_steps_not_the_comparison():
    from odolab.api import Estimate, Odometer, load_tum_sequence, run_odometers

    class Quitter(Odometer):
        def step(self, prev, cur, action) -> Estimate:
            raise SystemExit(0)

    class QuitsOnReset(Odometer):
        def reset(self, intrinsics) -> None:
            raise SystemExit(3)

    seq = load_tum_sequence(TUM_DIR)
    a, b = run_odometers({"quitter": Quitter(), "reset": QuitsOnReset()}, [seq])
    assert a.failures == b.failures == len(seq) - 1
    assert "SystemExit" in a.errors[0] and "SystemExit" in b.errors[0]


def test_config_files_that_are_not_option_tables_are_one_line(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("odometers = 5\n")
    one_line_error("odolab.compare", "--config", bad, "--out", tmp_path / "o", words="odometers must be a table")
    bad.write_bytes(b"\x90\xff\x00garbage")
    one_line_error("odolab.compare", "--config", bad, "--out", tmp_path / "o", words="not valid TOML")


def test_action_prior_refuses_a_prior_of_nothing_and_odd_out_paths(tmp_path):
    one_line_error("odolab.action_prior", "--episodes", "1", "--max-steps", "1", words="a mean of nothing is no prior")
    one_line_error("odolab.action_prior", "--out", tmp_path / "missing" / "x.json", words="does not exist")
    assert not (tmp_path / "missing").exists()
    afile = tmp_path / "afile"
    afile.write_text("")
    one_line_error("odolab.action_prior", "--out", afile / "x.json", words="is a file, not a folder")


def test_absurd_thread_counts_are_refused_not_crashed_on():
    import numpy as np
    import pytest

    from odolab.api import load_odometer

    for name in ("robust-vo", "deepvo"):
        for bad in (100000, np.inf, np.nan, 2.5, True, "3"):
            with pytest.raises(ValueError, match=r"threads must be an integer in \[1, 256\], got "):
                load_odometer(name, threads=bad)
    for key in ("mc_samples", "batch_size", "seed"):
        with pytest.raises(ValueError, match=f"{key} must be an integer in"):
            load_odometer("robust-vo", **{key: np.nan})
    with pytest.raises(ValueError, match="mirror_tta must be true or false"):
        load_odometer("robust-vo", mirror_tta="yes")


def test_bench_refuses_odometer_options_it_would_ignore():
    one_line_error("odolab.bench", "--only", "evaluate", "--odometers", "icp", words="does not run it")
    one_line_error("odolab.bench", "--only", "evaluate", "--train-threads", "1", words="--train-threads chooses")
    one_line_error(
        "odolab.bench", "--only", "training", "--train-threads", "0", words="--train-threads must be in [1, 256], got 0"
    )
    one_line_error("odolab.bench", "--only", "simulator", "--odometer-option", "icp.x=1", words="does not run it")


def test_json_reports_have_no_nan(tmp_path):
    """JSON has no NaN: a rate too fast to time (bench) or a missing own error (noise study) becomes
    null, so browsers and jq can read the file."""
    import json

    from odolab.io.atomic import write_json_atomic

    report = {
        "odometers": [
            {"odometer": "action-prior", "steps_per_s": float("nan")},
            {"odometer": "icp", "steps_per_s": 18.5, "fails": np.float64("inf")},
        ]
    }
    write_json_atomic(tmp_path / "r.json", report)
    text = (tmp_path / "r.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text)["odometers"][0]["steps_per_s"] is None
    assert json.loads(text)["odometers"][1] == {"odometer": "icp", "steps_per_s": 18.5, "fails": None}


def test_bench_saves_each_part_as_it_finishes(tmp_path, monkeypatch):
    import json

    from odolab import bench
    from odolab.cli.bench import main

    out = tmp_path / "b.json"
    out.write_text('{"machine": {"cpus": 2}, "evaluate": {"old": "a complete earlier run"}, "parts_pending": []}')
    seen = []

    def odometers(names, options=None, rows=None, after_each=None):  # the 2nd odometer is interrupted
        rows.append({"odometer": names[0], "steps_per_s": 1.0})
        after_each()
        seen.append(json.loads(out.read_text()))
        raise KeyboardInterrupt

    monkeypatch.setattr(bench, "bench_odometers", odometers)
    with pytest.raises(KeyboardInterrupt):
        main(["--only", "odometers", "--only", "evaluate", "--odometers", "action-prior,icp", "--json", str(out)])
    saved = json.loads(out.read_text())
    assert "evaluate" not in saved and saved == seen[0]
    assert saved["odometers"] == [{"odometer": "action-prior", "steps_per_s": 1.0}]
    assert saved["parts_pending"] == ["odometers", "evaluate"]


def test_atomic_writes_go_through_links_and_never_replace_devices_or_pipes(tmp_path):
    import os

    from odolab.io.atomic import write_text_atomic

    target = tmp_path / "target.json"
    target.write_text("{}")
    link = tmp_path / "link.json"
    link.symlink_to(target)
    write_text_atomic(link, "new")
    assert link.is_symlink() and target.read_text() == "new"
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match="not a regular file"):
        write_text_atomic(fifo, "x")
    assert not fifo.is_file() and fifo.exists()
    one_line_error("odolab.bench", "--only", "evaluate", "--json", fifo, words="is not a regular file")
    one_line_error("odolab.bench", "--only", "evaluate", "--json", "/dev/null", words="is not a regular file")


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


def test_numbers_too_long_to_read_are_one_line_errors(tmp_path):
    big = "9" * 5000
    one_line_error(
        "odolab.compare",
        "--odometers",
        "action-prior",
        "--odometer-option",
        f"action-prior.x={big}",
        "--episodes",
        "1",
        "--max-steps",
        "5",
        "--no-cache",
        "--out",
        tmp_path / "o",
        words="action-prior.x: a number too long to read",
    )
    cfg = tmp_path / "big.toml"
    cfg.write_text(f'[odometers."action-prior"]\nx = {big}\n')
    one_line_error(
        "odolab.compare",
        "--config",
        cfg,
        "--episodes",
        "1",
        "--max-steps",
        "5",
        "--no-cache",
        "--out",
        tmp_path / "o2",
        words=f"{cfg}: holds a number too long to read",
    )
    from odolab.learning import ConfigError
    from odolab.robust_vo.config import load_train_config

    with pytest.raises(ConfigError, match="holds a number too long to read"):
        load_train_config(str(cfg))


def test_an_action_prior_file_that_is_a_pipe_or_repeats_a_key_is_one_line(tmp_path):
    """A pipe would block the reader for ever, and JSON keeps the last of two equal keys silently."""
    fifo = tmp_path / "prior.fifo"
    os.mkfifo(fifo)
    twice = tmp_path / "twice.json"
    twice.write_text('{"means": {"move_forward": [0, 0, 0]}, "means": {}, "samples": {}}')
    for path, words in [(fifo, "is a pipe, device or socket"), (twice, "key 'means' appears twice")]:
        one_line_error(
            "odolab.compare",
            "--odometers",
            "action-prior",
            "--odometer-option",
            f"action-prior.prior={path}",
            "--episodes",
            "1",
            "--max-steps",
            "5",
            "--no-cache",
            "--out",
            tmp_path / "o",
            words=words,
        )


@pytest.mark.parametrize(
    "value",
    ["[]", "[0]", "[1000000]", '"123"', "[1.5]", "[true]", "[2147483648]", "[5,5,5,5,5,5,5,5]", "20", "[[20,5]]"],
)
def test_open3d_iterations_out_of_range_are_one_line(tmp_path, value):
    """0 iterations would quietly return the starting guess, a million would never end, 8 pyramid
    levels leave a 2 x 1 pixel image, a string would be read digit by digit."""
    one_line_error(
        "odolab.compare",
        "--odometers",
        "open3d-rgbd",
        "--odometer-option",
        f"open3d-rgbd.iterations={value}",
        "--episodes",
        "1",
        "--max-steps",
        "5",
        "--no-cache",
        "--out",
        tmp_path / "o",
        words="iterations: expected a list of 1-6 whole numbers",
    )


@pytest.mark.parametrize("value", ["[0]", "[1000000]", '"123"', "[5,5,5,5,5,5,5]"])
def test_open3d_fallback_iterations_out_of_range_are_one_line(tmp_path, value):
    """The fallback schedule is checked as the first one is (but may be empty: no fallback)."""
    one_line_error(
        "odolab.compare",
        "--odometers",
        "open3d-rgbd",
        "--odometer-option",
        f"open3d-rgbd.fallback_iterations={value}",
        "--episodes",
        "1",
        "--max-steps",
        "5",
        "--no-cache",
        "--out",
        tmp_path / "o",
        words="fallback_iterations: expected a list of 0-6 whole numbers",
    )


def test_an_option_given_twice_is_refused(tmp_path):
    one_line_error(
        "odolab.compare",
        "--odometers",
        "open3d-rgbd",
        "--odometer-option",
        "open3d-rgbd.term=hybrid",
        "--odometer-option",
        "open3d-rgbd.term=color",
        "--episodes",
        "1",
        "--max-steps",
        "5",
        "--no-cache",
        "--out",
        tmp_path / "o",
        words="open3d-rgbd.term is given twice",
    )


@pytest.mark.parametrize(
    "change,words",
    [
        ({"means": [[0, 0.25, 0]]}, "'means' must be an object mapping each of move_forward"),
        ({"samples": "x"}, "'samples' must be an object"),
        ({"means": {"move_forward": "123"}}, "means.move_forward: expected [dx m, dz m, dyaw rad]"),
        ({"means": {"move_forward": [0, 1000, 0]}}, "means.move_forward: expected"),
        ({"means": {"turn_left": None}}, "means.turn_left: expected"),
        ({"means": {"move_forward": [0, 0.25, 0]}, "drop": "turn_left"}, "means: no value for 'turn_left'"),
        ({"means": {"stop": [0, 0, 0]}}, "means: unknown action 'stop'"),
        ({"samples": {"turn_left": -5}}, "samples.turn_left: expected a whole number >= 0"),
        ({"samples": {"turn_left": True}}, "samples.turn_left: expected a whole number >= 0"),
    ],
)
def test_an_action_prior_file_with_bad_fields_names_the_field(tmp_path, change, words):
    import json

    from odolab.action_prior import ActionPrior

    doc = ActionPrior.shipped().to_json()
    for field in ("means", "samples"):
        if field in change:
            doc[field] = {**doc[field], **change[field]} if isinstance(change[field], dict) else change[field]
    if "drop" in change:
        del doc["means"][change["drop"]]
    path = tmp_path / "prior.json"
    path.write_text(json.dumps(doc))
    one_line_error(
        "odolab.compare",
        "--odometers",
        "action-prior",
        "--odometer-option",
        f"action-prior.prior={path}",
        "--episodes",
        "1",
        "--max-steps",
        "5",
        "--no-cache",
        "--out",
        tmp_path / "o",
        words=words,
    )


@pytest.mark.parametrize(
    "option,value,words",
    [
        ("fallback_iterations", "[" * 3000 + "]" * 3000, "open3d-rgbd.fallback_iterations: value nested too deeply"),
        ("max_depth", "inf", "max_depth must be in (0, 1000], got inf"),
        ("max_depth", "1e300", "max_depth must be in (0, 1000], got 1e+300"),
    ],
)
def test_open3d_depth_and_nesting_are_one_line(tmp_path, option, value, words):
    """A depth cut of infinity ran (and wrote Infinity into navigate's JSON); [[[...]]] 3000 deep
    was a RecursionError traceback."""
    one_line_error(
        "odolab.compare",
        "--odometers",
        "open3d-rgbd",
        "--odometer-option",
        f"open3d-rgbd.{option}={value}",
        "--episodes",
        "1",
        "--max-steps",
        "5",
        "--no-cache",
        "--out",
        tmp_path / "o",
        words=words,
    )


def test_a_deeply_nested_options_file_and_a_huge_option_are_short_lines(tmp_path, capsys):
    deep = tmp_path / "deep.toml"
    deep.write_text('[odometers."open3d-rgbd"]\nfallback_iterations = ' + "[" * 3000 + "]" * 3000 + "\n")
    one_line_error(
        "odolab.compare",
        "--odometers",
        "open3d-rgbd",
        "--config",
        deep,
        "--episodes",
        "1",
        "--max-steps",
        "5",
        "--no-cache",
        "--out",
        tmp_path / "o",
        words="holds a value nested too deeply",
    )
    huge = "[" + ",".join(["5"] * 20000) + "]"  # the odometer's message cuts the value; the loader's did not
    from odolab.comparison import ComparisonError, load_odometers

    with pytest.raises(ComparisonError) as info:
        load_odometers(["open3d-rgbd"], {"open3d-rgbd": {"fallback_iterations": [5] * 20000}})
    assert len(str(info.value)) < 500 and "fallback_iterations" in str(info.value)
    assert len(huge) > 30000


def test_equal_settings_give_equal_digests():
    """6 and 6.0 set the same depth cut: a rerun with either reuses the other's episodes."""
    from odolab.odometer import load_odometer

    assert load_odometer("open3d-rgbd", max_depth=6).identity_digest == load_odometer("open3d-rgbd").identity_digest
    assert load_odometer("open3d-rgbd", max_depth=5).identity_digest != load_odometer("open3d-rgbd").identity_digest


def test_a_pasted_20000_character_name_is_not_echoed_whole(tmp_path):
    import contextlib
    import io

    from odolab.cli import MAX_ERROR_CHARS
    from odolab.compare import main

    name = "k" * 20000
    for args in (["--odometers", name], ["--odometers", "icp", "--odometer-option", f"icp.{name}=1"]):
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = run_cli(
                main,
                "odolab.compare",
                [*args, "--episodes", "1", "--max-steps", "3", "--no-cache", "--out", str(tmp_path / "o")],
            )
        line = err.getvalue().strip()
        assert code == 2 and "\n" not in line and line.endswith("more characters)")
        assert len(line) < MAX_ERROR_CHARS + 100


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


def test_tasks_that_ask_for_gpus_get_one_each_or_a_clear_refusal():
    """The ablation study's paper scale asks Ray for a GPU per training unit: Ray then shows each task
    only its GPU; a cluster with none refuses in one line at once instead of waiting for ever."""
    import os

    import ray

    from odolab.parallel import RayAddressError, fan_out

    quiet = Execution(progress=False)
    visible = ["CUDA_VISIBLE_DEVICES"] * 2  # each task's os.getenv of it
    ray.init(num_cpus=2, num_gpus=1, include_dashboard=False, log_to_driver=False)  # a GPU declared, none there
    try:
        assert fan_out(os.getenv, visible, execution=quiet, gpus=1) == ["0", "0"]  # one after the other
    finally:
        ray.shutdown()
    ray.init(num_cpus=2, num_gpus=0, include_dashboard=False, log_to_driver=False)
    try:
        with pytest.raises(RayAddressError) as info:
            fan_out(os.getenv, visible, execution=quiet, gpus=1)
        assert str(info.value) == (
            "the local Ray instance has 0 GPUs; each task asks for 1 (run where there are GPUs, or ask for none)"
        )
    finally:
        ray.shutdown()
