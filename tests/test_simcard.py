"""The simulator card: its statistics and files."""

import json

import numpy as np

from odolab.cli.simcard import main
from odolab.simcard import ImageStats


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
