"""Runs that would be silently wrong are marked or refused: an oracle inside a composite, an
odometer that implements nothing, depth read at the wrong scale, a damaged training shard, a
trajectory whose KITTI drift cannot be computed; and odometers load from a file's path."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from odolab import runner
from odolab.action_prior import ActionPrior
from odolab.api import Action, Estimate, Frame, Intrinsics, Odometer, planar_to_transform, register_odometer
from odolab.odometer import REGISTRY, IncompleteOdometerError, OracleInputError, load_odometer
from odolab.parallel import SERIAL, Execution
from tests.test_hostile_inputs import one_line_error

INTRINSICS = Intrinsics.from_hfov(8, 6, 79.0)


class _Steps:
    """A five-frame sequence moving 0.25 m forward per step, with ground truth and actions."""

    name = "steps"
    collisions = None
    intrinsics = INTRINSICS

    def __len__(self) -> int:
        return 5

    def gt_pose(self, i: int) -> np.ndarray:
        return planar_to_transform(0.0, 0.25 * i, 0.0)

    def __getitem__(self, i: int) -> Frame:
        return Frame(np.zeros((6, 8, 3), np.uint8), np.full((6, 8), 2.0, np.float32), float(i), self.gt_pose(i))

    def action(self, i: int) -> Action:
        return Action.MOVE_FORWARD


class _Truth(Odometer):
    """An oracle that answers the true motion, and fails a step whose frames hide it."""

    oracle = True

    def step(self, prev, cur, action):
        if prev.gt_pose is None or cur.gt_pose is None:
            return Estimate.invalid()
        return Estimate(np.linalg.inv(prev.gt_pose) @ cur.gt_pose)


class _BlindComposite(Odometer):
    """A third-party composite that does not pass its input's oracle nature on."""

    def __init__(self, inputs: str = "") -> None:
        self.inner = load_odometer(inputs)

    def step(self, prev, cur, action):
        return self.inner.step(prev, cur, action)


@pytest.fixture()
def oracle_calibration(tmp_path) -> str:
    from odolab.fusion.calibration import Calibration, InputCalibration

    fixed = {a: [0.01, 0.01, 0.01, 0.02, 0.02, 0.02] for a in ("move_forward", "turn_left", "turn_right")}
    one = InputCalibration(fixed, {a: None for a in fixed}, {a: 100 for a in fixed})
    path = tmp_path / "cal.json"
    Calibration({"action-prior": one, "test-truth": one}).save(path)
    register_odometer("test-truth", _Truth)
    register_odometer("test-blind", _BlindComposite)
    return str(path)


def test_a_fused_oracle_input_answers_and_the_fused_row_is_marked_oracle(oracle_calibration):
    fused = REGISTRY.load("fused(test-truth)", calibration=oracle_calibration)
    assert fused.oracle
    result = runner.run_sequence(fused, _Steps(), "fused(test-truth)", ActionPrior.shipped())
    assert result.oracle and result.failures == 0
    assert np.allclose(result.poses[-1][:3, 3], _Steps().gt_pose(4)[:3, 3], atol=1e-6)  # not the action prior's


def test_manhattan_passes_its_inputs_oracle_on():
    assert load_odometer("manhattan(ground-truth)").oracle


def test_a_composite_that_hides_ground_truth_from_its_oracle_input_is_refused(oracle_calibration):
    with pytest.raises(OracleInputError, match="'test-truth' reads ground truth"):
        REGISTRY.load("test-blind(test-truth)")
    assert not REGISTRY.load("test-blind(action-prior)").oracle  # no oracle inside: loads


@pytest.mark.slow
def test_the_calibration_command_names_an_oracle_input(tmp_path, capsys, oracle_calibration):
    from odolab.cli import calibrate_fusion as calibrate

    calibrate.main(
        [
            "--odometers",
            "action-prior,test-truth",
            "--episodes",
            "1",
            "--max-steps",
            "30",
            "--serial",
            "--quiet",
            "--split",
            "val",
            "--cache",
            str(tmp_path / "cache"),
            "--out",
            str(tmp_path / "c.json"),
        ]
    )
    assert "test-truth (an oracle" in capsys.readouterr().out


# ----------------------------------------------------------------------------- an odometer that implements nothing


class _Abstract(Odometer):
    pass


def test_an_odometer_without_step_is_refused_when_loaded():
    register_odometer("test-abstract", _Abstract)
    with pytest.raises(IncompleteOdometerError, match="overrides neither step"):
        load_odometer("test-abstract")


def test_a_comparison_names_an_odometer_without_step_in_one_line():
    from odolab.comparison import ComparisonError, load_odometers

    register_odometer("test-abstract", _Abstract)
    with pytest.raises(ComparisonError, match=r"^odometer 'test-abstract': class _Abstract overrides neither"):
        load_odometers(["test-abstract"])


class _Never(Odometer):
    def step(self, prev, cur, action):
        return Estimate.invalid()


def test_an_odometer_failing_every_step_is_said_on_the_compare_console():
    from odolab.comparison import ComparisonConfig, run_comparison
    from odolab.summary import every_step_failed

    register_odometer("test-never", _Never)
    result = run_comparison(
        ComparisonConfig(
            odometers=["test-never", "action-prior"],
            episodes=1,
            max_steps=3,
            cache=None,
            execution=SERIAL,
        )
    )
    assert every_step_failed(result.rows) == [
        "test-never: failed steps: every one of 3; its figures are the action prior's, which stood in for each"
    ]


@pytest.mark.slow
def test_the_navigate_console_counts_failed_steps(tmp_path, capsys):
    from odolab.cli import run_cli
    from odolab.navigate import main as navigate

    register_odometer("test-never", _Never)
    args = [
        "--odometers",
        "test-never,action-prior",
        "--episodes",
        "1",
        "--max-steps",
        "3",
        "--serial",
        "--quiet",
        "--out",
        str(tmp_path),
    ]
    assert run_cli(navigate, "python -m odolab.navigate", args) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "failed steps: every one of 3" in next(ln for ln in lines if "test-never:" in ln)
    assert "no failed steps" in next(ln for ln in lines if "action-prior:" in ln)


# ----------------------------------------------------------------------------- odometers from a file

ODOMETER_FILE = """
from dataclasses import dataclass
from odolab.api import Estimate, Odometer

@dataclass
class Settings:
    dz: float = 0.25

class Forward(Odometer):
    def __init__(self, dz: float = 0.25):
        self.settings = Settings(dz)

    def step(self, prev, cur, action):
        return Estimate.from_planar(0.0, self.settings.dz, 0.0)
"""


def test_an_odometer_loads_from_a_file_path_without_pythonpath(tmp_path, monkeypatch):
    folder = tmp_path / "my odometers"
    folder.mkdir()
    (folder / "forward_vo.py").write_text(ODOMETER_FILE)
    odo = load_odometer(f"{folder / 'forward_vo.py'}:Forward", dz=0.5)
    frame = _Steps()[0]
    assert odo.step(frame, frame, None).planar[1] == pytest.approx(0.5)
    monkeypatch.chdir(folder)  # a relative path, and the same file again: the same class
    again = load_odometer("forward_vo.py:Forward")
    assert type(again) is type(odo) and again.name == "forward_vo.py:Forward"


def test_an_odometer_file_that_is_missing_or_broken_is_named(tmp_path):
    from odolab.comparison import ComparisonError, load_odometers

    with pytest.raises(ComparisonError, match="no such file"):
        load_odometers([f"{tmp_path / 'nothing.py'}:Forward"])
    (tmp_path / "broken.py").write_text("def oops(:\n")
    with pytest.raises(ComparisonError, match="broken.py raised SyntaxError"):
        load_odometers([f"{tmp_path / 'broken.py'}:Forward"])
    (tmp_path / "fine.py").write_text(ODOMETER_FILE)
    with pytest.raises(ComparisonError, match="has no attribute 'Backward'"):
        load_odometers([f"{tmp_path / 'fine.py'}:Backward"])


# ----------------------------------------------------------------------------- TUM folders at another depth scale

TUM = Path(__file__).parent / "data" / "tum_fr1_xyz_10"
FR1 = (517.3, 516.5, 318.6, 255.3)


@pytest.fixture()
def millimetre_folder(tmp_path) -> Path:
    """The 10-frame TUM sequence with its depth rewritten in millimetres, in a folder whose name
    names no TUM camera."""
    import cv2

    dst = tmp_path / "my_recording"
    shutil.copytree(TUM, dst)
    for png in (dst / "depth").glob("*.png"):
        raw = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(png), np.round(raw / 5.0).astype(np.uint16))
    return dst


def test_millimetre_depth_is_read_at_the_scale_given_and_a_wrong_scale_is_warned_of(millimetre_folder):
    from odolab.io.tum_rgbd import UnknownCameraError, load_tum_sequence

    with pytest.raises(UnknownCameraError):
        load_tum_sequence(millimetre_folder)
    truth = load_tum_sequence(TUM)
    seq = load_tum_sequence(millimetre_folder, FR1, depth_scale=1000)
    assert seq.intrinsics == truth.intrinsics  # the size is the images'
    assert np.allclose(seq[3].depth, truth[3].depth, atol=0.0011) and seq.depth_warning() is None
    wrong = load_tum_sequence(millimetre_folder, FR1)  # TUM's 5000 per metre: a fifth of the truth
    assert np.allclose(wrong[3].depth * 5, seq[3].depth, atol=1e-5)
    warning = wrong.depth_warning()
    assert "median is 0.22 m at a depth scale of 5000" in warning
    assert "At 1000 per metre (millimetres) it would be 1.08 m" in warning
    assert "At 5000 per metre it would be 1.08 m" in load_tum_sequence(TUM, depth_scale=1000).depth_warning()
    assert truth.depth_warning() is None
    with pytest.raises(ValueError, match=r"depth_scale must be a number of PNG values per metre in \[1, 1e\+06\]"):
        load_tum_sequence(millimetre_folder, FR1, depth_scale=0)


def test_compare_takes_the_depth_scale_and_the_camera_and_warns_of_a_wrong_scale(millimetre_folder):
    from odolab.comparison import ComparisonConfig, run_comparison

    def run(scale):
        config = ComparisonConfig(
            odometers=["ground-truth"],
            tum=millimetre_folder,
            tum_depth_scale=scale,
            tum_intrinsics=FR1,
            execution=Execution(progress=False),
        )
        return run_comparison(config)

    assert not any("median" in w for w in run(1000.0).warnings)
    assert any("depth's median is 0.22 m" in w for w in run(None).warnings)


@pytest.mark.parametrize(
    "args,words",
    [
        ([], "cannot tell the camera from the folder's name (no fr1, fr2 or fr3 in it); give it with --intrinsics"),
        (["--intrinsics", "517,516,318"], "--intrinsics must be four numbers fx,fy,cx,cy"),
        (["--intrinsics", "0,516,318,255"], "--intrinsics: the focal lengths fx, fy must be positive"),
        (["--intrinsics", ",".join(map(str, FR1)), "--depth-scale", "0"], "--depth-scale must be in [1, 1e+06]"),
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


# ----------------------------------------------------------------------------- evaluate's frictions

TUM_OK = "1.0 0 0 0 0 0 0 1\n2.0 1 0 0 0 0 0 1\n3.0 1 1 0 0 0 0 1\n4.0 0 1 1 0 0 0 1\n"
KITTI_OK = "".join(f"1 0 0 {x} 0 1 0 {y} 0 0 1 {z}\n" for x, y, z in [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 1)])


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


# ----------------------------------------------------------------------------- damaged training shards


@pytest.fixture(scope="module")
def shards(tmp_path_factory) -> Path:
    from odolab.training_data import DataConfig, make_training_data

    root = tmp_path_factory.mktemp("data") / "train"
    make_training_data(
        DataConfig(split="train", episodes=2, max_steps=4, width=24, height=16, episodes_per_shard=1),
        root,
        execution=SERIAL,
    )
    return root


def _flip_a_frame_byte(shard: Path) -> None:
    from odolab.io.npz_mmap import mmap_npz_member

    offset = mmap_npz_member(shard, "rgb").offset + 5  # a pixel of the first frame: np.load never reads it
    data = bytearray(shard.read_bytes())
    data[offset] ^= 0x10
    shard.write_bytes(bytes(data))


@pytest.mark.parametrize("old", [False, True], ids=["checksum in the manifest", "shard made before checksums"])
def test_a_shard_with_a_flipped_byte_is_named_when_its_frames_are_first_read(shards, tmp_path, old):
    import json

    from odolab.training_data import MANIFEST, DamagedShardError, TrainingData

    copy = tmp_path / "copy"
    shutil.copytree(shards, copy)
    doc = json.loads((copy / MANIFEST).read_text())
    assert all(isinstance(e["crc32"], int) for e in doc["shards"].values())  # written with each shard
    if old:
        for entry in doc["shards"].values():
            del entry["crc32"]
        (copy / MANIFEST).write_text(json.dumps(doc))
    data = TrainingData(copy)
    data.frames(np.arange(len(data.poses)))  # intact: read without complaint
    shard = copy / data.shards[0]
    _flip_a_frame_byte(shard)
    damaged = TrainingData(copy)  # the small arrays are intact: opening is not the check
    with pytest.raises(DamagedShardError, match=f"{shard.name}: damaged: "):
        damaged.frames(np.array([0]))


def test_a_shard_is_checked_once_per_process(shards, monkeypatch):
    from odolab import training_data as td

    calls = []
    real = td.file_crc32
    monkeypatch.setattr(td, "file_crc32", lambda path, *a: calls.append(path) or real(path, *a))
    data = td.TrainingData(shards)
    for _ in range(3):
        data.pair_batch(np.arange(len(data)))
    assert sorted(calls) == sorted(shards / n for n in data.shards)  # each shard once, not once per batch
    import pickle

    worker = pickle.loads(pickle.dumps(data))  # a loader worker's copy keeps what was checked
    worker.frames(np.array([0]))
    assert len(calls) == len(data.shards)
    td.TrainingData(shards).frames(np.array([0]))  # a new opening checks again
    assert len(calls) == len(data.shards) + 1
