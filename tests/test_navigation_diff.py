"""python -m odolab.navigation.diff: two runs of the same episodes compared episode by episode."""
from __future__ import annotations

import pytest

from odolab.cli import run_cli
from odolab.navigation.diff import diff_runs, main, markdown, read_episodes

HEAD = "odometer,episode,split,seed,d0,d_end,path,stopped,steps,collisions,success,spl,soft_spl,failed_steps\n"


def _folder(tmp_path, name, rows):
    folder = tmp_path / name
    folder.mkdir()
    (folder / "episodes.csv").write_text(HEAD + "".join(
        f'"{o}",{e},test,0,5.0,0.1,6.0,True,{steps},{coll},{s},{0.8 * s},0.5,0\n' for o, e, s, steps, coll in rows))
    return folder


def test_won_and_lost_episodes_are_paired_by_odometer_and_episode(tmp_path):
    before = _folder(tmp_path, "a", [("x", 0, 1, 10, 2), ("x", 1, 0, 500, 40), ("x", 2, 1, 20, 0), ("y", 0, 1, 5, 0)])
    after = _folder(tmp_path, "b", [("x", 2, 0, 500, 90), ("x", 1, 1, 30, 4), ("x", 0, 1, 10, 2), ("x", 3, 1, 9, 9),
                                    ("fused(a,b)", 0, 1, 5, 5)])
    (d,) = diff_runs(read_episodes(before), read_episodes(after))  # y and fused(a,b) are in one run only
    assert (d.odometer, d.episodes, d.success, d.won, d.lost) == ("x", 3, (2, 2), (1,), (2,))
    assert d.collisions == (14.0, 32.0) and d.spl == pytest.approx((0.8 * 2 / 3, 0.8 * 2 / 3))
    assert "| x | 3 | 2 -> 2 | 1 | 2 | 0.53 -> 0.53 | 14.0 -> 32.0 | 177 -> 180 |" in markdown([d])


def test_bad_tables_are_refused_in_one_line_naming_file_and_line(tmp_path, capsys):
    good = _folder(tmp_path, "good", [("x", 0, 1, 10, 2)])
    bad = _folder(tmp_path, "bad", [("x", 0, 1, 10, 2)])
    text = (bad / "episodes.csv").read_text()
    cases = [(text.replace(",10,2,", ",ten,2,"), "line 2: steps must be a whole number, got 'ten'"),
             (text + text.splitlines()[1] + "\n", "line 3: episode 0 of x appears twice"),
             (text.replace(",1,0.8,", ",nan,0.8,"), "line 2: success must be finite"),
             ("odometer,episode\nx,0\n", "no column split, seed, success"),
             (b"\xff\xfe".decode("latin-1"), "episodes.csv")]
    for content, words in cases:
        (bad / "episodes.csv").write_text(content, encoding="latin-1")
        assert run_cli(main, "python -m odolab.navigation.diff", [str(good), str(bad)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0] and str(bad / "episodes.csv") in err[0], err
    assert run_cli(main, "python -m odolab.navigation.diff", [str(good), str(tmp_path / "none")]) == 2
    assert "no such file" in capsys.readouterr().err
    other = _folder(tmp_path, "other", [("z", 0, 1, 10, 2)])
    assert run_cli(main, "python -m odolab.navigation.diff", [str(good), str(other)]) == 2
    assert "share no episode" in capsys.readouterr().err
