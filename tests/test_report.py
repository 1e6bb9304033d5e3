"""odolab.report: trajectory file names, the error figure's layout and the trajectory palette."""

from __future__ import annotations

import numpy as np
import pytest

from odolab.report import GROUND_TRUTH_FILE, OutputFolder, file_stem, write_trajectories
from odolab.runner import SequenceResult


def _result(odometer: str, shift: float, sequence: str = "seq", steps: int = 3) -> SequenceResult:
    """A straight ``steps``-step run of ``odometer``, ``shift`` m to the side per step (its own numbers)."""
    gt = np.tile(np.eye(4), (steps + 1, 1, 1))
    gt[:, 0, 3] = np.arange(steps + 1) * 0.25
    poses = gt.copy()
    poses[:, 1, 3] = shift * np.arange(steps + 1)
    return SequenceResult(
        odometer=odometer,
        sequence=sequence,
        oracle=False,
        estimates=np.tile(np.eye(4), (steps, 1, 1)),
        truth=None,
        poses=poses,
        gt_poses=gt,
        actions=np.zeros(steps, np.int8),
        valid=np.ones(steps, bool),
        step_seconds=np.zeros(steps),
    )


# -- trajectory file names ---------------------------------------------------------------------


def test_committed_names_read_as_before():
    # the committed reports (reports/*/trajectories) and kitti-style's saved results name these files
    for name, stem in (
        ("icp", "icp"),
        ("feature-essential-oracle-rot", "feature-essential-oracle-rot"),
        ("fused(icp,open3d-rgbd)", "fused_icp_open3d-rgbd_"),
        ("fused(open3d-rgbd,robust-vo,planar-depth)", "fused_open3d-rgbd_robust-vo_planar-depth_"),
        ("test-s0-e000", "test-s0-e000"),
        ("tum_fr1_xyz_10", "tum_fr1_xyz_10"),
    ):
        assert file_stem(name) == stem


@pytest.mark.parametrize(
    "names",
    [
        ("/a/c 1/x.py:Odo", "/a/c_1/x.py:Odo", "_a_c_1_x.py_Odo"),  # only the characters a file cannot hold differ
        ("icp", "ICP", "Icp"),  # one file on a file system that ignores case
        ("fused(a,b)", "fused_a_b_", "fused(a_b)", "fused(a(b))", "fused(a,b(c))", "fused(a(b,c))"),
        ("icp", "icp-0123abcd", file_stem("icp-0123abcd"), file_stem("ICP")),  # a name shaped like a digest form
        ("x" * 100, "x" * 300, "x" * 301),  # long names are cut
        (GROUND_TRUTH_FILE, "GroundTruth", ".", "..", ""),
    ],
)
def test_different_names_never_share_a_file(names):
    stems = [file_stem(n) for n in names]
    assert len({s.lower() for s in stems}) == len(names), stems
    for s in stems:
        assert s.lower() != GROUND_TRUTH_FILE and s not in ("", ".", "..") and "/" not in s
        assert len(s) <= 110 and not s.startswith(".")


def test_two_odometers_whose_names_differ_in_unsafe_characters_keep_two_files(tmp_path):
    a, b = "/a/c 1/x.py:Odo", "/a/c_1/x.py:Odo"
    out = OutputFolder(tmp_path / "out")
    write_trajectories([_result(a, 0.1), _result(b, 0.2)], out)
    folder = tmp_path / "out" / "trajectories" / "seq"
    for name, shift in ((a, 0.1), (b, 0.2)):
        rows = np.loadtxt(folder / f"{file_stem(name)}.tum")
        assert rows[-1, 2] == pytest.approx(3 * shift)  # each file holds its own odometer's poses


def test_an_odometer_named_groundtruth_leaves_the_true_poses_file_alone(tmp_path):
    out = OutputFolder(tmp_path / "out")
    write_trajectories([_result(GROUND_TRUTH_FILE, 0.5)], out)
    folder = tmp_path / "out" / "trajectories" / "seq"
    assert np.loadtxt(folder / f"{GROUND_TRUTH_FILE}.tum")[-1, 2] == 0.0  # the true path
    assert np.loadtxt(folder / f"{file_stem(GROUND_TRUTH_FILE)}.tum")[-1, 2] == pytest.approx(1.5)
    assert len(list(folder.glob("*.tum"))) == 2


def test_sequences_whose_names_differ_in_unsafe_characters_keep_two_folders(tmp_path):
    out = OutputFolder(tmp_path / "out")
    write_trajectories([_result("icp", 0.1, "room 1"), _result("icp", 0.2, "room_1")], out)
    folders = sorted(p.name for p in (tmp_path / "out" / "trajectories").iterdir())
    assert folders == sorted([file_stem("room 1"), file_stem("room_1")]) and len(set(folders)) == 2


def test_names_that_would_still_share_a_file_are_refused_before_any_is_written(tmp_path, monkeypatch):
    import odolab.report

    monkeypatch.setattr(odolab.report, "file_stem", lambda name: "same")  # a digest collision, forced
    out = OutputFolder(tmp_path / "out")
    with pytest.raises(ValueError, match="'a' and 'b' would share the file name 'same'"):
        write_trajectories([_result("a", 0.1), _result("b", 0.2)], out)
    assert not (tmp_path / "out" / "trajectories").exists()


def test_plain_names_keep_their_place_in_the_manifest(tmp_path):
    out = OutputFolder(tmp_path / "out")
    write_trajectories([_result("icp", 0.1), _result("fused(icp,open3d-rgbd)", 0.2)], out)
    assert set(out.written) == {
        f"trajectories/seq/{stem}.{ext}"
        for stem in ("icp", "fused_icp_open3d-rgbd_", GROUND_TRUTH_FILE)
        for ext in ("tum", "kitti")
    }
