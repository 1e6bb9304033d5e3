"""odolab.learned.training.curves: training curves kept as CSV and drawn as small multiples, the figure redrawn
after an epoch (``final=False``) at most once a minute."""

from __future__ import annotations

import os

from odolab.learned.training.curves import Curves


def _curves() -> Curves:
    rows = [
        {"epoch": e, "split": "val", "action": a, "component": c, "mae": 1.0 / e}
        for e in (1, 2)
        for a in ("move_forward", "turn_left")
        for c in ("dx", "dz")
    ]
    return Curves(rows)


def _draw(curves: Curves, path, final: bool = True) -> None:
    curves.plot(path, x="epoch", rows="action", cols="component", series={"mae": {"label": "model"}}, final=final)


def test_a_fresh_figure_is_kept_and_an_old_or_missing_one_is_drawn(tmp_path):
    path = tmp_path / "curves.png"
    curves = _curves()
    _draw(curves, path, final=False)  # none yet: drawn
    assert path.stat().st_size > 5_000
    path.write_bytes(b"drawn a moment ago")
    _draw(curves, path, final=False)
    assert path.read_bytes() == b"drawn a moment ago"  # younger than a minute: kept
    _draw(curves, path)  # a training's last call: always drawn
    assert path.read_bytes().startswith(b"\x89PNG")
    path.write_bytes(b"drawn long ago")
    old = path.stat().st_mtime - 120
    os.utime(path, (old, old))
    _draw(curves, path, final=False)
    assert path.read_bytes().startswith(b"\x89PNG")


def test_the_csv_keeps_every_row_with_columns_in_first_seen_order(tmp_path):
    curves = _curves()
    curves.add([{"epoch": 3, "split": "train", "loss": 0.5}])
    curves.to_csv(tmp_path / "curves.csv")
    lines = (tmp_path / "curves.csv").read_text().splitlines()
    assert lines[0] == "epoch,split,action,component,mae,loss"
    assert len(lines) == 1 + 8 + 1 and lines[-1] == "3,train,,,,0.5"
