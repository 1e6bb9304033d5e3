"""The simulator card: its statistics and files."""

import json

import numpy as np
import pytest

from odolab.cli import run_cli
from odolab.cli.simcard import main
from odolab.simcard import ImageStats
from tests.helpers import outside_folder, stderr_line


def test_image_stats_count_holes_and_depth_error_per_bin():
    s = ImageStats()
    clean = np.full((10, 10), 2.5, np.float32)
    noisy = clean * 1.02
    noisy[0, :] = 0.0  # 10 holes
    noisy[1, 0] = 5.0  # an outlier (+100 %)
    s.add(np.full((10, 10, 3), 100, np.uint8), clean, noisy)
    assert s.holes == 10 and s.frames == 1
    assert s.depth_rows() == []  # fewer than 100 pixels in the bin: no row
    for _ in range(2):
        s.add(np.full((10, 10, 3), 100, np.uint8), clean, noisy)
    (row,) = s.depth_rows()
    assert row["depth_m"] == "2-3" and abs(row["bias_pct"] - 2.0) < 1e-3 and row["spread_pct"] < 1e-3
    assert abs(row["outliers_pct"] - 100 / 90) < 1e-6
    assert s.grey_mean[0] == 100.0 and s.grey_std[0] == 0.0


@pytest.mark.slow
def test_simcard_command_writes_the_card(tmp_path, capsys):
    out = tmp_path / "card"
    assert (
        main(
            [
                "--episodes",
                "3",
                "--rendered",
                "1",
                "--frames",
                "3",
                "--max-steps",
                "40",
                "--serial",
                "--quiet",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    data = json.loads((out / "card.json").read_text())
    assert data["motion"]["episodes"] == 3 and data["images"]["frames"] == 3
    mix = data["motion"]["mix_pct"]
    assert abs(sum(mix.values()) - 100) < 1e-6
    assert 5 < data["images"]["holes_pct"] < 20  # the Redwood table's border holes
    for name in ("card.md", "motion.png", "depth.png", "frames.png"):
        assert (out / name).stat().st_size > 1000
    assert "collisions" in capsys.readouterr().out


def test_simcard_keeps_out_of_a_folder_it_did_not_write(tmp_path, capsys):
    from odolab.cli.simcard import main

    out = tmp_path / "mine"
    out.mkdir()
    (out / "card.md").write_text("my own notes")
    argv = ["--episodes", "1", "--rendered", "1", "--frames", "2", "--max-steps", "5", "--serial", "--quiet"]
    assert run_cli(main, "python -m odolab.simcard", argv + ["--out", str(out)]) == 2
    stderr_line(capsys, "holds files odolab did not write")
    assert (out / "card.md").read_text() == "my own notes"
    linked = tmp_path / "linked"
    linked.mkdir()
    (linked / "manifest.txt").write_text("card.md\n")
    (linked / "card.md").symlink_to(outside_folder(tmp_path) / "victim.tum")
    assert run_cli(main, "python -m odolab.simcard", argv + ["--out", str(linked)]) == 2
    stderr_line(capsys, "card.md", "found a symbolic link to")
    assert (tmp_path / "outside" / "victim.tum").read_text() == "precious"


def test_simcard_of_the_free_family_measures_other_scenes_and_says_so(tmp_path):
    argv = ["--episodes", "2", "--rendered", "1", "--frames", "2", "--max-steps", "20", "--serial", "--quiet"]
    cards = {}
    for family in ("boxes", "free"):
        assert main([*argv, "--scene-family", family, "--out", str(tmp_path / family)]) == 0
        cards[family] = json.loads((tmp_path / family / "card.json").read_text())
    assert (
        cards["free"]["command"].endswith("--scene-family free") and "--scene-family" not in cards["boxes"]["command"]
    )
    assert cards["free"]["motion"]["geodesic_m"] != cards["boxes"]["motion"]["geodesic_m"]
