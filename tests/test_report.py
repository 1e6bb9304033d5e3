"""odolab.reporting.report: trajectory file names, the error figure's layout and the trajectory palette, the
top-down figure's colours and markers, and the output folder's manifest."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from matplotlib.colors import to_rgb

from odolab.io.owned import UnsafeOutputError
from odolab.reporting.report import GROUND_TRUTH_FILE, OutputFolder, file_stem, write_trajectories
from odolab.running.runner import SequenceResult
from tests.helpers import captured_figures, outside_folder


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
    import odolab.reporting.report

    monkeypatch.setattr(odolab.reporting.report, "file_stem", lambda name: "same")  # a digest collision, forced
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


# -- errors.png --------------------------------------------------------------------------------


def _action_rows(names: tuple[str, ...] = ("action-prior", "ground-truth", "icp", "deepvo")) -> list:
    """Per-action rows as a compare run gives them: zero for ground truth, no failures for the
    references, a tall collided dz bar for the prior."""
    from odolab.running.summary import ActionRow

    rows = []
    for k, name in enumerate(names):
        scale = 0.0 if name == "ground-truth" else 1.0 + 0.3 * k
        for action, steps, e in (("move_forward", 12, 2.0), ("turn_left", 5, 1.0), ("move_forward_collided", 2, 9.0)):
            failures = 3 if name == "icp" else 0
            rows.append(
                ActionRow(
                    name, action, e * scale, e * scale, e * scale, e, e, e, steps, failures, 0.0, 0.0, 0.0, e, e, e, 0
                )
            )
    return rows


def _drawn_errors(monkeypatch, rows: list):
    import matplotlib

    import odolab.reporting.report

    matplotlib.use("Agg")
    figures: list = []
    monkeypatch.setattr(
        odolab.reporting.report, "save_figure_atomic", lambda fig, path, dpi=110: figures.append((fig, dpi))
    )
    odolab.reporting.report.plot_errors(rows, Path("errors.png"))
    return figures[0]


def test_the_error_figure_reads_at_the_size_the_report_shows_it(monkeypatch):
    from matplotlib.text import Text

    fig, dpi = _drawn_errors(monkeypatch, _action_rows())
    fig.canvas.draw()
    width_px = fig.get_size_inches()[0] * dpi
    assert 1000 <= width_px <= 1280  # the report's page is 1280 px wide: shown at its own size
    texts = [t for t in fig.findobj(Text) if t.get_text().strip() and t.get_visible()]
    smallest = min(t.get_fontsize() for t in texts) * dpi / 72
    assert smallest >= 10, [(t.get_text(), t.get_fontsize()) for t in texts if t.get_fontsize() * dpi / 72 < 10]
    panels = [ax for ax in fig.axes if ax.get_title()]
    assert len(panels) == 4 and len({round(ax.get_position().y0, 2) for ax in panels}) == 2  # a 2 x 2 grid


def test_the_error_figure_draws_no_empty_bars_and_says_what_it_left_out(monkeypatch):
    fig, _ = _drawn_errors(monkeypatch, _action_rows())
    dx, dz, dyaw, failed = (ax for ax in fig.axes if ax.get_title())
    for ax in (dx, dz, dyaw):
        assert [t.get_text() for t in ax.get_xticklabels()] == ["action-prior", "icp", "deepvo"]
    assert [t.get_text() for t in failed.get_xticklabels()] == ["icp", "deepvo"]
    assert [t.get_text() for t in failed.texts] == ["0 %"]  # deepvo never failed: said, not an empty gap
    said = " ".join(t.get_text() for t in fig.texts)
    assert "ground-truth (zero error everywhere)" in said
    assert "action-prior and ground-truth (references: they never fail)" in said


def test_a_cut_bar_reads_its_value_above_the_axis(monkeypatch):
    from matplotlib.colors import to_rgb

    fig, _ = _drawn_errors(monkeypatch, _action_rows())
    dz = next(ax for ax in fig.axes if ax.get_title().startswith("dz"))
    top = dz.get_ylim()[1]
    assert top < 9.0 and "axis cut at" in dz.get_title()
    values = {t.get_text(): t for t in dz.texts}
    assert set(values) == {"9.0", "14.4", "17.1"}  # the prior's, icp's and deepvo's collided steps
    for t in values.values():
        assert t.get_rotation() == 0 and t.get_position()[1] >= top and t.get_va() == "bottom"
        assert sum(to_rgb(t.get_color())) < 1.5  # dark on the white page, not white on the bar


def test_the_error_figure_of_references_alone_draws_no_empty_panel(monkeypatch):
    fig, _ = _drawn_errors(monkeypatch, _action_rows(("ground-truth",)))
    for ax in (ax for ax in fig.axes if ax.get_title()):
        assert [t.get_text() for t in ax.texts] == ["no odometer to show"] and not ax.patches


# -- trajectory colours ------------------------------------------------------------------------

#: Machado et al. (2009) simulation of protanopia, deuteranopia and tritanopia (severity 1), on linear RGB.
_COLOUR_BLIND = {
    "protanopia": ((0.152286, 1.052583, -0.204868), (0.114503, 0.786281, 0.099216), (-0.003882, -0.048116, 1.051998)),
    "deuteranopia": ((0.367322, 0.860646, -0.227968), (0.280085, 0.672501, 0.047413), (-0.011820, 0.042940, 0.968881)),
    "tritanopia": ((1.255528, -0.076749, -0.178779), (-0.078411, 0.930809, 0.147602), (0.004733, 0.691367, 0.303900)),
}


def _lab(rgb: np.ndarray) -> np.ndarray:
    """CIE L*a*b* (D65) of linear RGB in 0-1."""
    xyz = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]]) @ rgb
    t = xyz / np.array([0.95047, 1.0, 1.08883])
    f = np.where(t > (6 / 29) ** 3, np.cbrt(t), t / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.array([116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2])])


def test_trajectory_colours_stay_apart_for_colour_blind_readers():
    from matplotlib.colors import to_rgb

    from odolab.reporting.report import TRAJECTORY_COLORS

    linear = [
        np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
        for c in map(np.array, map(to_rgb, TRAJECTORY_COLORS))
    ]
    for vision, matrix in [("normal", np.eye(3)), *_COLOUR_BLIND.items()]:
        seen = [_lab(np.clip(np.array(matrix) @ c, 0, 1)) for c in linear]
        nearest = min(np.linalg.norm(a - b) for i, a in enumerate(seen) for b in seen[i + 1 :])
        assert nearest > 12, vision  # CIE76 distance; the old palette's red, brown and pink: 4.6 (protanopia)


def test_every_odometer_has_its_own_colour_marker_and_line_style():
    from odolab.reporting.report import TRAJECTORY_COLORS, trajectory_style

    styles = [trajectory_style(k) for k in range(24)]
    assert len(set(styles)) == len(styles)
    first = styles[: len(TRAJECTORY_COLORS)]
    assert len({c for c, _ in first}) == len(first) and len({s[0] for _, s in first}) == len(first)
    assert all(s[0] not in "os*" for _, s in styles)  # not the start, end or goal markers


# -- wording -----------------------------------------------------------------------------------


def test_one_of_a_thing_reads_in_the_singular():
    from odolab.reporting.report import counted

    assert counted(1, "test episode") == "1 test episode"
    assert counted(5, "test episode") == "5 test episodes" and counted(0, "step") == "0 steps"
    assert counted(2, "odometer run") == "2 odometer runs" and counted(3, "axis", "axes") == "3 axes"


def test_an_interrupted_rerun_never_mixes_two_runs(tmp_path):
    from odolab.reporting.report import MANIFEST, OutputFolder

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


def test_a_manifest_naming_a_users_file_never_deletes_it(tmp_path):
    from odolab.reporting.report import ManifestError, OutputFolder

    (tmp_path / "thesis.docx").write_text("years of work")
    (tmp_path / "table.csv").write_text("old")
    (tmp_path / "manifest.txt").write_text("thesis.docx\ntable.csv\n")
    with pytest.raises(ManifestError, match="thesis.docx"):
        OutputFolder.check(tmp_path)
    folder = OutputFolder(tmp_path)  # even called without the check, the cleanup removes only compare's names
    assert (tmp_path / "thesis.docx").read_text() == "years of work"
    assert not (tmp_path / "table.csv").exists() and folder.not_removed == ["thesis.docx"]


def test_one_command_never_takes_over_anothers_folder(tmp_path):
    from odolab.reporting.report import ManifestError, OutputFolder
    from odolab.simcard import CARD_NAMES

    folder = OutputFolder(tmp_path)
    folder.path("table.csv").write_text("compare's results")
    folder.finish()
    assert (tmp_path / "manifest.txt").read_text().splitlines()[0] == "# odolab compare"
    with pytest.raises(ManifestError, match="odolab compare"):
        OutputFolder.check(tmp_path, owner="simcard", names=CARD_NAMES)
    OutputFolder.check(tmp_path)  # compare itself may write there again
    assert (tmp_path / "table.csv").read_text() == "compare's results"


def test_an_unreadable_manifest_is_refused_not_ignored(tmp_path):
    from odolab.reporting.report import ManifestError, OutputFolder

    (tmp_path / "manifest.txt").write_bytes(b"table.csv\n\xff\xfe garbage\n")
    with pytest.raises(ManifestError, match="cannot be read"):
        OutputFolder.check(tmp_path)


def test_a_meaningless_manifest_line_is_named(tmp_path):
    from odolab.reporting.report import ManifestError, OutputFolder

    (tmp_path / "table.csv").write_text("old")
    (tmp_path / "manifest.txt").write_text("table.csv/x\n")
    with pytest.raises(ManifestError, match="lists 'table.csv/x'"):
        OutputFolder.check(tmp_path)


def test_a_pipe_named_manifest_in_a_parent_does_not_block(tmp_path, capsys):
    import os

    (tmp_path / "p").mkdir()
    os.mkfifo(tmp_path / "p" / "manifest.txt")
    from odolab.reporting.report import manifest_owner

    assert manifest_owner(tmp_path / "p") is None  # returns, does not wait for a writer


def _grey(color) -> bool:
    r, g, b = to_rgb(color)
    return max(r, g, b) - min(r, g, b) < 0.15


def test_top_down_trajectories_never_take_the_obstacles_grey_and_show_start_end_and_goal(monkeypatch):
    from odolab.reporting import report
    from odolab.running.runner import SequenceResult

    obstacle = (report.OBSTACLE_SHADE,) * 3
    for k in range(40):
        color, style = report.trajectory_style(k)
        assert not _grey(color) and to_rgb(color) != obstacle and style
    n = 6
    poses = np.tile(np.eye(4), (n + 1, 1, 1))
    poses[:, 0, 3] = np.linspace(0.0, 1.0, n + 1)
    names = ["ground-truth"] + [f"odometer-{k}" for k in range(13)]

    def result(name: str, shift: float) -> SequenceResult:
        mine = poses.copy()
        mine[:, 1, 3] = shift * np.arange(n + 1)
        return SequenceResult(
            odometer=name,
            sequence="seq",
            oracle=False,
            estimates=np.tile(np.eye(4), (n, 1, 1)),
            truth=None,
            poses=mine,
            gt_poses=poses,
            actions=np.zeros(n, np.int8),
            valid=np.ones(n, bool),
            step_seconds=np.zeros(n),
        )

    plan = report.FloorPlan(np.ones((40, 40), bool), (-1.0, -1.0), 0.1, goal=(20.0, 0.0))
    figures = captured_figures(monkeypatch, report)
    report.plot_sequence([result(name, 0.01 * k) for k, name in enumerate(names)], Path("x.png"), names, plan)
    (ax,) = figures[0].axes
    drawn = [line.get_color() for line in ax.get_lines() if line.get_label() in names[1:]]
    assert len(drawn) == 13 and not any(_grey(c) for c in drawn)
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "start" in labels and any(t.startswith("end") for t in labels) and any("goal" in t for t in labels)
    assert any("goal 19.0 m" in t.get_text() for t in ax.texts)  # off view: an arrow with its distance


def _collided_action_rows():
    from odolab.running.summary import ActionRow

    rows = []
    for name, scale in (("action-prior", 1.0), ("icp", 0.4)):
        for action, steps, dz in (
            ("move_forward", 123, 4.4),
            ("turn_left", 43, 1.2),
            ("turn_right", 59, 1.1),
            ("move_forward_collided", 11, 16.7),
        ):
            e = dz * scale
            rows.append(ActionRow(name, action, e, e, e, e, e, e, steps, 0, 0.0, 0.0, 0.0, e, e, e, 0))
    return rows


def test_the_error_bars_are_not_squashed_by_the_few_collided_steps(monkeypatch):
    from odolab.reporting import report

    figures = captured_figures(monkeypatch, report)
    report.plot_errors(_collided_action_rows(), Path("errors.png"))
    axes = figures[0].axes
    for ax in axes[:3]:
        assert "as used" in ax.get_title() and "as used" in ax.get_ylabel()
        top = ax.get_ylim()[1]
        assert 4.4 < top < 16.7 / 2  # the usual bars fill the panel; the collided one is cut
        assert "16.7" in [t.get_text() for t in ax.texts]  # and carries its value
    labels = [t.get_text() for t in axes[0].get_legend().get_texts()]
    assert "move_forward (n=123)" in labels and "move_forward_collided (n=11)" in labels


def test_a_rerun_removes_nothing_through_a_linked_folder_and_keeps_its_results(tmp_path):
    """A linked ``trajectories/<episode>`` and a crafted manifest line through a linked subfolder:
    nothing outside is deleted, the cleanup never raises, and the folder is refused by check()."""
    from odolab.reporting.report import MANIFEST, OutputFolder

    outside = outside_folder(tmp_path)
    (outside / "keep.txt").write_text("mine")
    root = tmp_path / "out"
    (root / "trajectories").mkdir(parents=True)
    (root / "trajectories" / "ep").symlink_to(outside, target_is_directory=True)
    (root / "sub").symlink_to(outside, target_is_directory=True)
    (root / "table.csv").write_text("old")
    (root / MANIFEST).write_text("table.csv\n" + "x" * 300 + "/a.tum\n")  # a name no file system holds: ignored
    OutputFolder.check(root, files=("table.csv",), folders=("trajectories",))
    (root / MANIFEST).write_text("trajectories/ep/victim.tum\nsub/keep.txt\ntable.csv\n")
    with pytest.raises(UnsafeOutputError, match="ep: expected a folder, found a symbolic link to"):
        OutputFolder.check(root)
    folder = OutputFolder(root)
    assert folder.removed == ["table.csv"] and folder.not_removed == ["trajectories/ep/victim.tum", "sub/keep.txt"]
    assert (outside / "victim.tum").read_text() == "precious" and (outside / "keep.txt").read_text() == "mine"
    folder.path("table.csv").write_text("new")  # a result is written and listed
    with pytest.raises(UnsafeOutputError):
        folder.path("trajectories/ep/icp.tum")
    assert sorted(p.name for p in outside.iterdir()) == ["keep.txt", "victim.tum"]
    assert (root / MANIFEST).read_text() == "# odolab compare\ntable.csv\n"
