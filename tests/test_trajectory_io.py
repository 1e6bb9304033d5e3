"""Trajectory files (TUM, KITTI) and timestamp association, checked against evo; repeated timestamps
counted."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from odolab.cli import run_cli
from odolab.core.trajectory import Trajectory
from odolab.io.errors import FileFormatError
from odolab.io.kitti import read_kitti_poses, write_kitti_poses
from odolab.io.tum import (
    associate,
    matrix_to_quaternion,
    quaternion_to_matrix,
    read_tum_trajectory,
    write_tum_trajectory,
)
from tests.helpers import TUM_OK

DATA = Path(__file__).parent / "data" / "evo"
TUM_LINE = "1.0 0 0 0 0 0 0 1"


def random_rotations(n: int, rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return quaternion_to_matrix(q)


def random_poses(n: int, rng: np.random.Generator) -> np.ndarray:
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = random_rotations(n, rng)
    T[:, :3, 3] = rng.normal(scale=10.0, size=(n, 3))
    return T


def write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


# ----------------------------------------------------------------------------- Trajectory


def test_trajectory_value():
    poses = random_poses(5, np.random.default_rng(0))
    tr = Trajectory(np.arange(5.0), poses)
    assert len(tr) == 5
    np.testing.assert_array_equal(tr.positions, poses[:, :3, 3])
    sub = tr.subset([1, 3])
    assert len(sub) == 2 and list(sub.timestamps) == [1.0, 3.0]
    with pytest.raises(ValueError):
        Trajectory(None, np.zeros((3, 3, 4)))
    with pytest.raises(ValueError):
        Trajectory(np.arange(4.0), poses)


# ----------------------------------------------------------------------------- quaternions


def test_quaternion_round_trip_including_half_turns():
    rng = np.random.default_rng(1)
    R = random_rotations(500, rng)
    half_turns = np.array([np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1])])
    R = np.concatenate([R, half_turns, np.eye(3)[None]])
    q = matrix_to_quaternion(R)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    assert np.all(q[:, 3] >= 0)
    np.testing.assert_allclose(quaternion_to_matrix(q), R, atol=1e-12)


def test_quaternion_matches_evo():
    from evo.core import transformations as tf

    q = np.random.default_rng(2).normal(size=(50, 4))
    ours = quaternion_to_matrix(q)
    for qi, Ri in zip(q, ours):
        theirs = tf.quaternion_matrix(np.roll(qi, 1))[:3, :3]  # evo wants w first
        np.testing.assert_allclose(Ri, theirs, atol=1e-12)


# ----------------------------------------------------------------------------- TUM files


def test_tum_round_trip_exact(tmp_path):
    rng = np.random.default_rng(3)
    tr = Trajectory(1305031102.0 + np.cumsum(rng.uniform(0.01, 0.05, 40)), random_poses(40, rng))
    path = tmp_path / "t.txt"
    write_tum_trajectory(path, tr)
    back = read_tum_trajectory(path)
    np.testing.assert_array_equal(back.timestamps, tr.timestamps)
    np.testing.assert_allclose(back.poses, tr.poses, atol=1e-12)
    assert [p.name for p in tmp_path.iterdir()] == ["t.txt"]  # no temporary file left


def test_tum_write_replaces_atomically_and_needs_timestamps(tmp_path):
    path = write(tmp_path, "t.txt", "old\n")
    with pytest.raises(ValueError):
        write_tum_trajectory(path, Trajectory(None, np.eye(4)[None]))
    assert path.read_text() == "old\n"
    write_tum_trajectory(path, Trajectory(np.array([0.5]), np.eye(4)[None]))
    assert read_tum_trajectory(path).timestamps[0] == 0.5
    assert len(list(tmp_path.iterdir())) == 1


def test_tum_reader_normalises_quaternions_and_skips_comments(tmp_path):
    path = write(tmp_path, "t.txt", "# header\n\n1.0 1 2 3 0 0 0 2\n  # indented comment\n2.0 1 2 3 0 0 3 3\n")
    tr = read_tum_trajectory(path)
    assert len(tr) == 2
    np.testing.assert_allclose(tr.poses[0], np.diag([1.0, 1, 1, 1]) + np.c_[np.zeros((4, 3)), [1, 2, 3, 0]])
    np.testing.assert_allclose(tr.poses[1, :3, :3], quaternion_to_matrix(np.array([0, 0, 1.0, 1.0]) / np.sqrt(2))[0])


def test_tum_reader_matches_evo_on_shipped_files():
    from evo.tools import file_interface

    for name in ("freiburg1_xyz-groundtruth.txt", "freiburg1_xyz-rgbdslam.txt"):
        ours = read_tum_trajectory(DATA / name)
        theirs = file_interface.read_tum_trajectory_file(str(DATA / name))
        np.testing.assert_array_equal(ours.timestamps, theirs.timestamps)
        np.testing.assert_allclose(ours.poses, np.array(theirs.poses_se3), atol=1e-12)


TUM_BAD = [
    ("missing", None, None, "no such file"),
    ("empty", "", None, "no poses"),
    ("comments only", "# nothing\n\n", None, "no poses"),
    ("columns", f"{TUM_LINE}\n2.0 0 0 0 0 1\n", 2, "expected 8 columns"),
    ("not a number", f"{TUM_LINE}\n2.0 0 0 zero 0 0 0 1\n", 2, "'zero' is not a number"),
    ("nan", f"# c\n{TUM_LINE}\n2.0 0 nan 0 0 0 0 1\n", 3, "not finite"),
    ("inf", f"{TUM_LINE}\n2.0 0 0 0 0 0 0 inf\n", 2, "not finite"),
    ("zero quaternion", f"{TUM_LINE}\n2.0 0 0 0 0 0 0 0\n", 2, "zero quaternion"),
    ("backwards", f"{TUM_LINE}\n3.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 1\n", 3, "backwards"),
]


@pytest.mark.parametrize("case,text,line,problem", TUM_BAD, ids=[c[0] for c in TUM_BAD])
def test_tum_reader_errors(tmp_path, case, text, line, problem):
    path = tmp_path / "gt.txt"
    if text is not None:
        path.write_text(text)
    with pytest.raises(FileFormatError) as info:
        read_tum_trajectory(path)
    err = info.value
    assert isinstance(err, ValueError)
    assert err.line_no == line and problem in err.problem
    where = str(path) if line is None else f"{path}, line {line}"
    assert str(err).startswith(f"{where}: ")


def test_error_message_format():
    assert str(FileFormatError("groundtruth.txt", 7, "expected 8 columns, got 6")) == (
        "groundtruth.txt, line 7: expected 8 columns, got 6"
    )


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


# ----------------------------------------------------------------------------- KITTI files


def kitti_line(T: np.ndarray) -> str:
    return " ".join(repr(float(v)) for v in T[:3].reshape(-1))


def test_kitti_round_trip_and_matches_evo(tmp_path):
    from evo.tools import file_interface

    tr = read_kitti_poses(DATA / "KITTI_00_ORB.txt")
    theirs = file_interface.read_kitti_poses_file(str(DATA / "KITTI_00_ORB.txt"))
    assert tr.timestamps is None and len(tr) == 4541
    np.testing.assert_array_equal(tr.poses, np.array(theirs.poses_se3))
    write_kitti_poses(tmp_path / "k.txt", tr)
    np.testing.assert_array_equal(read_kitti_poses(tmp_path / "k.txt").poses, tr.poses)
    assert len(list(tmp_path.iterdir())) == 1


KITTI_OK = kitti_line(np.eye(4))
KITTI_BAD = [
    ("missing", None, None, "no such file"),
    ("empty", "\n\n", None, "no poses"),
    ("columns", f"{KITTI_OK}\n1 0 0 0 0 1 0 0 0 0 1\n", 2, "expected 12 columns"),
    ("not a number", f"{KITTI_OK}\n1 0 0 0 0 1 0 x 0 0 1 0\n", 2, "'x' is not a number"),
    ("nan", f"{KITTI_OK}\n1 0 0 0 0 1 0 0 0 0 1 NaN\n", 2, "not finite"),
    ("scaled", f"{KITTI_OK}\n2 0 0 0 0 2 0 0 0 0 2 0\n", 2, "not a rotation"),
    ("reflection", f"{KITTI_OK}\n{KITTI_OK}\n-1 0 0 0 0 1 0 0 0 0 1 0\n", 3, "not a rotation"),
]


@pytest.mark.parametrize("case,text,line,problem", KITTI_BAD, ids=[c[0] for c in KITTI_BAD])
def test_kitti_reader_errors(tmp_path, case, text, line, problem):
    path = tmp_path / "poses.txt"
    if text is not None:
        path.write_text(text)
    with pytest.raises(FileFormatError) as info:
        read_kitti_poses(path)
    assert info.value.line_no == line and problem in info.value.problem


def test_kitti_accepts_rounded_rotations(tmp_path):
    R = random_rotations(1, np.random.default_rng(4))[0]
    path = write(tmp_path, "p.txt", " ".join(f"{v:.6e}" for v in np.c_[R, [1, 2, 3]].reshape(-1)) + "\n")
    np.testing.assert_allclose(read_kitti_poses(path).poses[0, :3, :3], R, atol=1e-6)


# ----------------------------------------------------------------------------- association


def evo_associate(t_ref: np.ndarray, t_est: np.ndarray, max_diff: float):
    """evo's association, returned as index arrays into t_ref and t_est."""
    from evo.core import sync
    from evo.core.trajectory import PoseTrajectory3D

    def traj(t):
        return PoseTrajectory3D(
            positions_xyz=np.c_[np.arange(len(t), dtype=float), np.zeros((len(t), 2))],
            orientations_quat_wxyz=np.tile([1.0, 0, 0, 0], (len(t), 1)),
            timestamps=t,
        )

    a, b = sync.associate_trajectories(traj(t_ref), traj(t_est), max_diff=max_diff)
    return a.positions_xyz[:, 0].astype(int), b.positions_xyz[:, 0].astype(int)


@pytest.mark.parametrize("seed", range(6))
def test_associate_matches_evo(seed):
    rng = np.random.default_rng(seed)
    n_ref, n_est = rng.integers(5, 80, size=2)
    t_ref = np.cumsum(rng.uniform(0.005, 0.04, n_ref))
    t_est = np.cumsum(rng.uniform(0.005, 0.04, n_est)) + rng.uniform(-0.2, 0.2)
    if seed % 2:  # exact ties: some est stamps half-way between two ref stamps, some equal
        k = min(n_ref - 1, n_est)
        t_est[: k // 2] = (t_ref[: k // 2] + t_ref[1 : k // 2 + 1]) / 2
        t_est = np.sort(t_est)
    for max_diff in (0.0, 0.005, 0.01, 0.05):
        ours = associate(t_ref, t_est, max_diff)
        theirs = evo_associate(t_ref, t_est, max_diff) if len(ours[0]) else (np.zeros(0), np.zeros(0))
        np.testing.assert_array_equal(ours[0], theirs[0])
        np.testing.assert_array_equal(ours[1], theirs[1])


def test_associate_shipped_files_matches_evo():
    gt = read_tum_trajectory(DATA / "freiburg1_xyz-groundtruth.txt")
    est = read_tum_trajectory(DATA / "freiburg1_xyz-rgbdslam.txt")
    ours = associate(gt.timestamps, est.timestamps)
    theirs = evo_associate(gt.timestamps, est.timestamps, 0.01)
    assert len(ours[0]) == 785
    np.testing.assert_array_equal(ours[0], theirs[0])
    np.testing.assert_array_equal(ours[1], theirs[1])


def test_associate_edge_cases():
    assert [len(a) for a in associate(np.arange(3.0), np.arange(3.0) + 10)] == [0, 0]
    assert [len(a) for a in associate(np.zeros(0), np.arange(3.0))] == [0, 0]
    with pytest.raises(ValueError):
        associate(np.array([2.0, 1.0]), np.arange(3.0))


def test_a_quaternion_of_huge_or_tiny_components_is_normalised_or_named(tmp_path):
    """(1e308, 1e308, 0, 1) normalises without overflow to a 90-degree turn about x + y; one of
    5e-324 is named as too near zero, not as all zeros."""
    import numpy as np
    import pytest

    from odolab.io.errors import FileFormatError
    from odolab.io.tum import read_tum_trajectory

    huge = tmp_path / "huge.txt"
    huge.write_text("0 0 0 0 1e308 1e308 0 1\n")
    with np.errstate(over="raise", invalid="raise"):
        R = read_tum_trajectory(huge).poses[0, :3, :3]
    assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.trace(R), -1.0)  # a half turn about (1, 1, 0)
    tiny = tmp_path / "tiny.txt"
    tiny.write_text("0 0 0 0 5e-324 0 0 0\n")
    with pytest.raises(FileFormatError, match=r"tiny.txt, line 1: quaternion \(4.94066e-324 0 0 0\) too near zero"):
        read_tum_trajectory(tiny)
