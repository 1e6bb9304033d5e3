"""``python -m odolab.evaluate``: reference figures, JSON contents, plots, and one-line errors; the file
format told (past a byte-order mark), and why RPE or t_rel has no value said truthfully."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from odolab.cli import run_cli
from odolab.evaluate import main
from tests.helpers import TUM_OK, one_line_error

DATA = Path(__file__).parent / "data" / "evo"
KITTI_GT, KITTI_ORB = DATA / "KITTI_00_gt.txt", DATA / "KITTI_00_ORB.txt"
TUM_GT, TUM_EST = DATA / "freiburg1_xyz-groundtruth.txt", DATA / "freiburg1_xyz-rgbdslam.txt"


def cli(*args: str | Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "odolab.evaluate", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def run_json(capsys, *args) -> dict:
    assert main([*map(str, args), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_kitti_reference_figures_through_cli():
    proc = cli(KITTI_GT, KITTI_ORB, "--format", "kitti", "--json")
    assert proc.returncode == 0, proc.stderr
    est = json.loads(proc.stdout)["estimates"][0]
    assert abs(est["ate"] - 1.3035) < 1e-4
    assert round(est["t_rel"], 4) == 0.6997 and round(est["r_rel"], 4) == 0.2533
    assert est["coverage"] == 1.0
    assert est["pairing"]["method"] == "by index" and est["pairing"]["pairs"] == 4541
    assert est["poses"]["gt"] == {"total": 4541, "used": 4541, "dropped": 0}
    assert est["alignment"]["method"] == "se3" and est["alignment"]["scale"] == 1.0
    assert est["kitti"]["segments"] == 3283 and len(est["kitti"]["per_length"]) == 8


def test_tum_reference_figure_and_provenance(capsys):
    doc = run_json(capsys, TUM_GT, TUM_EST, "--format", "tum", "--align", "se3")
    est = doc["estimates"][0]
    assert round(est["ate"], 4) == 0.0135
    assert est["pairing"]["pairs"] == 785 and est["pairing"]["max_diff_s"] == 0.01
    assert est["pairing"]["largest_time_diff_s"] <= 0.01
    assert est["poses"]["est"] == {"total": 788, "used": 785, "dropped": 3}
    # 100 Hz ground truth, ~30 Hz estimate: coverage counts ground truth within reach of an estimate
    assert 0.8 < est["coverage"] < 0.9
    assert est["t_rel"] is None and est["kitti"]["segments"] == 0  # 0.5 m of motion: no 100 m segment
    assert est["rpe_trans"] > 0 and est["rpe_rot"] > 0


def test_sim3_reports_scale_and_several_estimates_make_rows(capsys, tmp_path):
    from odolab.io.kitti import read_kitti_poses, write_kitti_poses

    tr = read_kitti_poses(KITTI_ORB)
    tr.poses[:, :3, 3] *= 0.5
    half = tmp_path / "half.txt"
    write_kitti_poses(half, tr)
    doc = run_json(capsys, KITTI_GT, KITTI_ORB, half, "--format", "kitti", "--align", "sim3")
    a, b = doc["estimates"]
    assert b["alignment"]["scale"] == pytest.approx(2 * a["alignment"]["scale"], rel=1e-9)
    assert b["ate"] == pytest.approx(a["ate"], rel=1e-9)
    assert main([str(KITTI_GT), str(KITTI_ORB), str(half), "--format", "kitti"]) == 0
    table = capsys.readouterr().out
    assert "KITTI_00_ORB.txt" in table and "half.txt" in table and "align se3" in table


def test_plot_is_written(tmp_path, capsys):
    out = tmp_path / "eval.png"
    assert main([str(TUM_GT), str(TUM_EST), "--format", "tum", "--plot", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in tmp_path.iterdir()] == ["eval.png"]


def test_does_not_import_heavy_libraries():
    proc = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "odolab.evaluate", str(TUM_GT), str(TUM_EST), "--format", "tum"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    imported = {line.split("|")[-1].strip().split(".")[0] for line in proc.stderr.splitlines() if "|" in line}
    assert not imported & {"torch", "open3d", "matplotlib", "scipy", "cv2", "evo"}


# ----------------------------------------------------------------------------- bad input

KITTI_ROW = "1 0 0 {x} 0 1 0 {y} 0 0 1 {z}\n"
KITTI_OK = "".join(KITTI_ROW.format(x=x, y=y, z=z) for x, y, z in [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 1)])

# (id, format, bad file text (None: file missing), which file is bad, expected line, words in message)
BAD_INPUTS = [
    ("missing file", "tum", None, "est", None, "no such file"),
    ("empty file", "tum", "", "est", None, "no poses"),
    ("wrong column count", "tum", "1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 1\n", "est", 2, "expected 8 columns, got 6"),
    ("not a number", "tum", "1.0 0 0 0 0 0 0 1\n2.0 0 0 x 0 0 0 1\n", "est", 2, "not a number"),
    ("nan", "tum", "1.0 0 0 0 0 0 0 1\n2.0 0 nan 0 0 0 0 1\n", "gt", 2, "not finite"),
    ("inf", "kitti", KITTI_OK + KITTI_ROW.format(x="inf", y=0, z=0), "est", 5, "not finite"),
    ("zero quaternion", "tum", "1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 0\n", "est", 2, "zero quaternion"),
    (
        "non-monotonic timestamps",
        "tum",
        "1.0 0 0 0 0 0 0 1\n3.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 1\n",
        "est",
        3,
        "backwards",
    ),
    ("non-rotation", "kitti", KITTI_OK.replace("1 0 0 1", "2 0 0 1", 1), "est", 2, "not a rotation"),
    (
        "no associable poses",
        "tum",
        TUM_OK.replace("1.0 ", "101.0 ").replace("2.0 ", "102.0 ").replace("3.0 ", "103.0 ").replace("4.0 ", "104.0 "),
        "est",
        None,
        "no associable poses",
    ),
    ("unequal KITTI lengths", "kitti", KITTI_OK + KITTI_OK.splitlines(True)[0], "est", None, "equal lengths"),
]


@pytest.mark.slow
@pytest.mark.parametrize("case,fmt,text,bad,line,words", BAD_INPUTS, ids=[c[0] for c in BAD_INPUTS])
def test_bad_input_is_one_line_and_exit_2(tmp_path, case, fmt, text, bad, line, words):
    good = TUM_OK if fmt == "tum" else KITTI_OK
    gt, est = tmp_path / "gt.txt", tmp_path / "est.txt"
    (est if bad == "gt" else gt).write_text(good)
    if text is not None:
        (gt if bad == "gt" else est).write_text(text)
    proc = cli(gt, est, "--format", fmt)
    assert proc.returncode == 2, proc.stderr
    assert proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    msg = lines[0]
    assert "Traceback" not in proc.stderr
    assert msg.startswith("python -m odolab.evaluate: error: ")
    assert str(gt if bad == "gt" else est) in msg
    if line is not None:
        assert f", line {line}: " in msg
    assert words in msg


def test_low_coverage_is_an_error_when_asked(tmp_path):
    gt, est = tmp_path / "gt.txt", tmp_path / "est.txt"
    gt.write_text(TUM_OK)
    est.write_text("".join(TUM_OK.splitlines(True)[:3]))
    assert cli(gt, est, "--format", "tum", "--min-coverage", "0.5").returncode == 0
    proc = cli(gt, est, "--format", "tum", "--min-coverage", "0.9")
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1
    assert "coverage 0.750 is below --min-coverage 0.9" in proc.stderr and str(est) in proc.stderr


@pytest.mark.parametrize(
    "args,words",
    [
        (["--format", "xyz"], "invalid choice"),
        (["--format", "tum", "--align", "affine"], "invalid choice"),
        (["--format", "tum", "--delta", "0"], "--delta"),
        (["--format", "tum", "--delta", "1000"], "no pose pair"),
        (["--format", "tum", "--min-coverage", "2"], "--min-coverage"),
    ],
)
def test_bad_options_are_one_line(capsys, tmp_path, args, words):
    gt = tmp_path / "gt.txt"
    gt.write_text(TUM_OK)
    from odolab.cli import run_cli

    assert run_cli(main, "odolab.evaluate", [str(gt), str(gt), *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0]


def test_coverage_halves_when_tracking_is_lost_halfway(capsys, tmp_path):
    lines = [ln for ln in Path(TUM_EST).read_text().splitlines(True) if not ln.startswith("#")]
    half = tmp_path / "half.txt"
    half.write_text("".join(lines[: len(lines) // 2]))
    full = run_json(capsys, TUM_GT, TUM_EST, "--format", "tum")["estimates"][0]["coverage"]
    part = run_json(capsys, TUM_GT, str(half), "--format", "tum")["estimates"][0]["coverage"]
    assert part == pytest.approx(full / 2, abs=0.03)


@pytest.mark.parametrize(
    "args,words",
    [
        (["--delta", "nan"], "--delta must be a finite number"),
        (["--delta", "inf"], "--delta must be a finite number"),
        (["--delta", "1e300"], "--delta must be in (0, 1000000]"),
        (["--t-max-diff", "-1"], "--t-max-diff must be in [0, 60]"),
        (["--min-coverage", "nan"], "--min-coverage must be a finite number"),
    ],
)
def test_evaluate_numeric_options_have_ranges(tmp_path, args, words):
    gt = tmp_path / "gt.txt"
    gt.write_text(TUM_OK)
    one_line_error("odolab.evaluate", gt, gt, "--format", "tum", *args, words=words)


def test_evaluate_refuses_a_device_at_once(tmp_path):
    from odolab.evaluate import main

    (tmp_path / "zero.tum").symlink_to("/dev/zero")
    assert run_cli(main, "python -m odolab.evaluate", [str(tmp_path / "zero.tum"), str(tmp_path / "zero.tum")]) == 2


def test_a_negative_delta_is_told_its_range(tmp_path, capsys):
    from odolab.evaluate import main

    path = tmp_path / "a.tum"
    path.write_text("0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n2 2 0 0 0 0 0 1\n")
    assert run_cli(main, "python -m odolab.evaluate", [str(path), str(path), "--delta", "-1"]) == 2
    assert "--delta must be in (0, 1000000], got -1" in capsys.readouterr().err


def test_evaluate_names_the_delta_unit_option(tmp_path, capsys):
    from odolab.evaluate import main

    path = tmp_path / "a.tum"
    path.write_text("0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n2 2 0 0 0 0 0 1\n")
    assert run_cli(main, "python -m odolab.evaluate", [str(path), str(path), "--delta", "2.5"]) == 2
    err = capsys.readouterr().err
    assert "--delta must be a whole number of frames with --delta-unit f" in err and "-u f" not in err, err


def _evaluate(capsys, *args) -> tuple[int, str, str]:
    from odolab.cli import run_cli
    from odolab.evaluate import main

    code = run_cli(main, "python -m odolab.evaluate", [str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.parametrize("text", [TUM_OK, KITTI_OK, "# a comment\n" + TUM_OK])
def test_evaluate_reads_past_a_byte_order_mark_and_tells_the_format(tmp_path, capsys, text):
    path = tmp_path / "traj.txt"
    path.write_bytes(b"\xef\xbb\xbf" + text.encode())
    code, out, err = _evaluate(capsys, path, path)
    assert code == 0, err
    fmt = "kitti" if text is KITTI_OK else "tum"
    assert f"({len(text.strip().splitlines()) - text.count('#')} poses, {fmt})" in out


def test_evaluate_refuses_a_format_it_cannot_tell_in_one_line(tmp_path, capsys):
    tum, kitti, odd, named = (tmp_path / n for n in ("a.txt", "b.txt", "c.txt", "d.tum"))
    tum.write_text(TUM_OK)
    kitti.write_text(KITTI_OK)
    odd.write_text("1 2 3 4 5\n")
    named.write_text(KITTI_OK)
    for args, words in (
        ([tum, kitti], f"{kitti} is a KITTI file but {tum} a TUM file"),
        ([odd, odd], "expected 8 columns (TUM) or 12 (KITTI), got 5"),
        ([named, named], "named .tum but its lines have 12 columns, as KITTI files do"),
    ):
        code, _, err = _evaluate(capsys, *args)
        assert code == 2 and len(err.strip().splitlines()) == 1 and words in err, err
    assert _evaluate(capsys, named, named, "--format", "kitti")[0] == 0  # --format decides


def test_evaluate_says_why_rpe_has_no_pair_truthfully(tmp_path, capsys):
    one = tmp_path / "one.txt"
    one.write_text(TUM_OK.splitlines(True)[0])
    code, _, err = _evaluate(capsys, one, one, "--align", "none")
    assert code == 2 and "RPE needs at least 2 poses to compare, got 1" in err and "smaller delta" not in err
    four = tmp_path / "four.txt"
    four.write_text(TUM_OK)
    code, _, err = _evaluate(capsys, four, four, "--delta", "9")
    assert code == 2 and "a delta of at most 3 frames does" in err
    code, _, err = _evaluate(capsys, four, four, "--delta", "50", "--delta-unit", "m")
    assert code == 2 and "the path is 3.414 m long" in err


def test_evaluate_says_why_t_rel_is_a_dash(tmp_path, capsys):
    path = tmp_path / "short.txt"
    path.write_text(TUM_OK)
    code, out, _ = _evaluate(capsys, path, path)
    assert code == 0
    assert (
        f"note: {path}: t_rel and r_rel are '-': the KITTI errors need a segment of 100-800 m of the ground "
        "truth, and its paired poses span a path of 3.414 m"
    ) in out
