"""The TUM RGB-D folder reader: frames, association, camera choice, depth scale and every bad-input error."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from odolab.api import Sequence, load_tum_sequence
from odolab.io.errors import FileFormatError
from odolab.io.tum_rgbd import TUM_CAMERAS, TumSequence, tum_camera_for
from tests.helpers import FR1, ROOT

TUM = Path(__file__).parent / "data" / "tum_fr1_xyz_10"


@pytest.fixture
def copy(tmp_path) -> Path:
    """A writable copy of the 10-frame sequence, in a folder whose name still says fr1."""
    dst = tmp_path / "tum_fr1_copy"
    shutil.copytree(TUM, dst)
    return dst


def edit_line(path: Path, line_no: int, new: str) -> None:
    lines = path.read_text().splitlines()
    lines[line_no - 1] = new
    path.write_text("\n".join(lines) + "\n")


def test_reads_the_sequence():
    seq = load_tum_sequence(TUM)
    assert isinstance(seq, TumSequence) and isinstance(seq, Sequence)
    assert len(seq) == 10
    assert seq.intrinsics == TUM_CAMERAS["freiburg1"]
    f = seq[0]
    assert f.rgb.shape == (480, 640, 3) and f.rgb.dtype == np.uint8
    assert f.depth.shape == (480, 640) and f.depth.dtype == np.float32
    bgr = cv2.imread(str(TUM / "rgb" / "1305031102.000000.png"))
    assert np.array_equal(f.rgb, bgr[:, :, ::-1])  # RGB order
    raw = cv2.imread(str(TUM / "depth" / "1305031102.000000.png"), cv2.IMREAD_UNCHANGED)
    assert np.allclose(f.depth, raw / 5000.0) and f.depth[raw == 0].max() == 0
    assert 0.3 < np.median(f.depth[f.depth > 0]) < 4.0
    assert f.timestamp == pytest.approx(1305031102.0)
    assert seq[-1].timestamp == pytest.approx(1305031102.3)
    assert seq.action(3) is None
    assert np.allclose(seq.timestamps[1] - seq.timestamps[0], 1 / 30, atol=1e-6)


def test_ground_truth_is_camera_to_world():
    seq = load_tum_sequence(TUM)
    T = seq.gt_pose(0)
    # groundtruth.txt line 4: 1305031102.000000 1.3434 0.6271 1.6606 0.6583 0.6112 -0.2938 -0.3266
    assert np.allclose(T[:3, 3], [1.3434, 0.6271, 1.6606])
    x, y, z, w = np.array([0.6583, 0.6112, -0.2938, -0.3266]) / np.linalg.norm([0.6583, 0.6112, -0.2938, -0.3266])
    assert T[0, 0] == pytest.approx(1 - 2 * (y * y + z * z))
    assert T[2, 1] == pytest.approx(2 * (y * z + x * w))
    assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)
    assert np.array_equal(seq[0].gt_pose, T)
    traj = seq.ground_truth()
    assert len(traj) == 10 and np.array_equal(traj.poses[0], T)
    seq.gt_pose(0)[0, 3] = 99.0  # callers get copies
    assert seq.gt_pose(0)[0, 3] == pytest.approx(1.3434)


def test_indexing():
    seq = load_tum_sequence(TUM)
    with pytest.raises(IndexError):
        seq[10]
    with pytest.raises(IndexError):
        seq.gt_pose(-11)
    with pytest.raises(TypeError):
        seq[1:3]


@pytest.mark.parametrize(
    "name,camera",
    [
        ("rgbd_dataset_freiburg1_xyz", "freiburg1"),
        ("rgbd_dataset_freiburg2_desk", "freiburg2"),
        ("tum_fr3_office", "freiburg3"),
        ("FR2-pioneer", "freiburg2"),
        ("frame12", None),
        ("fr12_xyz", None),
        ("kitchen", None),
    ],
)
def test_camera_from_folder_name(name, camera):
    expected = None if camera is None else TUM_CAMERAS[camera]
    assert tum_camera_for(name) == expected


def test_unknown_camera_needs_intrinsics(tmp_path):
    dst = tmp_path / "my_kinect_recording"
    shutil.copytree(TUM, dst)
    with pytest.raises(ValueError, match="intrinsics="):
        load_tum_sequence(dst)
    seq = load_tum_sequence(dst, intrinsics=TUM_CAMERAS["freiburg3"])
    assert seq.intrinsics == TUM_CAMERAS["freiburg3"] and len(seq) == 10


def test_association_by_nearest_time_within_the_limit(copy):
    # depth 8 ms late everywhere (TUM's depth and colour are not simultaneous); one depth missing
    lines = (copy / "depth.txt").read_text().splitlines()
    out = []
    for line in lines:
        if line.startswith("#"):
            out.append(line)
        elif "102.100000" not in line:
            t, p = line.split()
            out.append(f"{float(t) + 0.008:.6f} {p}")
    (copy / "depth.txt").write_text("\n".join(out) + "\n")
    seq = load_tum_sequence(copy)
    assert len(seq) == 9
    assert 1305031102.1 not in np.round(seq.timestamps, 6)
    with pytest.raises(FileFormatError, match="no colour image has a depth image within 0.005"):
        load_tum_sequence(copy, max_time_diff=0.005)


def test_missing_folder(tmp_path):
    with pytest.raises(FileNotFoundError, match="no_such_fr1"):
        load_tum_sequence(tmp_path / "no_such_fr1")


@pytest.mark.parametrize("name", ["rgb.txt", "depth.txt", "groundtruth.txt"])
def test_missing_list_file(copy, name):
    (copy / name).unlink()
    with pytest.raises(FileFormatError, match=rf"{name}: no such file"):
        load_tum_sequence(copy)


@pytest.mark.parametrize(
    "name,line_no,new,problem",
    [
        ("rgb.txt", 5, "1305031102.033333 rgb/1305031102.033333.png extra", r"rgb.txt, line 5: expected 2 columns"),
        ("depth.txt", 4, "1305031102.000000", r"depth.txt, line 4: expected 2 columns"),
        ("rgb.txt", 6, "soon rgb/1305031102.066667.png", r"rgb.txt, line 6: timestamp 'soon' is not a number"),
        ("rgb.txt", 6, "1305031101.0 rgb/1305031102.066667.png", r"rgb.txt, line 6: timestamp .* times must increase"),
        ("rgb.txt", 7, "1305031102.100000 rgb/missing.png", r"rgb.txt, line 7: rgb/missing.png: no such file"),
        ("groundtruth.txt", 5, "1305031102.033333 1.3329 0.6258", r"groundtruth.txt, line 5: expected 8 columns"),
    ],
)
def test_malformed_lines_name_file_and_line(copy, name, line_no, new, problem):
    edit_line(copy / name, line_no, new)
    with pytest.raises(FileFormatError, match=problem):
        load_tum_sequence(copy)


def test_list_without_images(copy):
    (copy / "depth.txt").write_text("# depth maps\n")
    with pytest.raises(FileFormatError, match="depth.txt: lists no images"):
        load_tum_sequence(copy)


def test_no_ground_truth_near_the_frames(copy):
    lines = (copy / "groundtruth.txt").read_text().splitlines()
    shifted = [l if l.startswith("#") else f"{float(l.split()[0]) + 100:.6f} {' '.join(l.split()[1:])}" for l in lines]
    (copy / "groundtruth.txt").write_text("\n".join(shifted) + "\n")
    with pytest.raises(FileFormatError, match="no frame has a ground-truth pose within 0.02 s"):
        load_tum_sequence(copy)


def test_image_that_does_not_load(copy):
    (copy / "rgb" / "1305031102.066667.png").write_bytes(b"not a png at all")
    seq = load_tum_sequence(copy, check_images=False)  # decoding is lazy when asked
    seq[0]
    with pytest.raises(
        FileFormatError, match=r"1305031102.066667.png: cannot be read as an image \(listed in rgb.txt, line 6\)"
    ):
        seq[2]


def test_depth_must_be_16_bit(copy):
    path = copy / "depth" / "1305031102.033333.png"
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(path), (raw // 256).astype(np.uint8))
    with pytest.raises(
        FileFormatError, match=r"depth must be a 16-bit single-channel image, got uint8 \(listed in depth.txt, line 5\)"
    ):
        load_tum_sequence(copy)


def test_depth_of_the_wrong_size(copy):
    path = copy / "depth" / "1305031102.000000.png"
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(path), raw[:240, :320])
    with pytest.raises(FileFormatError, match=r"depth image is 320x240, the camera's is 640x480"):
        load_tum_sequence(copy)[0]


@pytest.mark.parametrize(
    "kind,damage,problem",
    [
        ("rgb", "truncated", "cannot be read as an image"),
        ("depth", "truncated", "cannot be read as an image"),
        ("depth", "three channels", "got 3-channel uint16"),
        ("rgb", "smaller", "colour image is 320x240, the camera's is 640x480"),
    ],
)
def test_bad_images_are_found_before_any_frame_is_used(copy, kind, damage, problem):
    listed = sorted((copy / kind).iterdir())
    path = listed[len(listed) // 2]
    if damage == "truncated":
        path.write_bytes(path.read_bytes()[:200])
    else:
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        img = np.dstack([img] * 3) if damage == "three channels" else img[:240, :320]
        cv2.imwrite(str(path), img)
    with pytest.raises(FileFormatError, match=problem) as info:
        load_tum_sequence(copy)
    assert path.name in str(info.value) and f"{kind}.txt, line" in str(info.value)


def test_image_path_outside_the_folder_is_refused(copy):
    edit_line(copy / "rgb.txt", 4, "1305031102.175304 ../../etc/passwd")
    with pytest.raises(FileFormatError, match="rgb.txt, line 4: ../../etc/passwd: outside the sequence folder"):
        load_tum_sequence(copy)


def test_frames_without_depth_or_ground_truth_are_counted(copy):
    assert load_tum_sequence(copy).dropped == {"no depth": 0, "no ground truth": 0}
    lines = (copy / "depth.txt").read_text().splitlines()
    (copy / "depth.txt").write_text("\n".join(lines[:-2]) + "\n")  # the last two depth maps are gone
    seq = load_tum_sequence(copy)
    assert seq.dropped["no depth"] == 2 and len(seq) == 8


@pytest.mark.slow
@pytest.mark.parametrize("command", ["odolab.compare", "baselines.measure_tum"])
def test_a_bad_image_stops_before_any_odometer_runs(tmp_path, command):
    import shutil

    folder = tmp_path / "rgbd_dataset_freiburg1_bad"
    shutil.copytree(TUM, folder)
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


@pytest.mark.parametrize(
    "pinhole, words", [((525.0, 525.0, 1e9, 1e9), "principal point"), ((1e-9, 1e-9, 0.0, 0.0), "implausible")]
)
def test_implausible_tum_intrinsics_are_refused(pinhole, words):
    from odolab.io.tum_rgbd import load_tum_sequence

    folder = Path(__file__).parent / "data" / "tum_fr1_xyz_10"
    with pytest.raises(ValueError, match=words):
        load_tum_sequence(folder, intrinsics=pinhole)


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
