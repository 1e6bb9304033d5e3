"""python -m odolab.navigation.diff: two runs of the same episodes compared episode by episode; a file
given for a run's folder is named."""

from __future__ import annotations

import numpy as np
import pytest

from odolab.cli import run_cli
from odolab.cli.navigation_diff import main
from odolab.navigation.diff import diff_runs, episode_difference, markdown, read_episodes, setting_notes, unpaired

HEAD = "odometer,episode,split,seed,d0,d_end,path,stopped,steps,collisions,success,spl,soft_spl,failed_steps\n"


def _row(o, e, s, steps, coll, split="test"):
    return f'"{o}",{e},{split},0,5.0,0.1,6.0,True,{steps},{coll},{s}.0000,{0.8 * s},0.5,0\n'


def _folder(tmp_path, name, rows):
    folder = tmp_path / name
    folder.mkdir()
    (folder / "episodes.csv").write_text(HEAD + "".join(_row(*r) for r in rows))
    return folder


def _diff(args, capsys):
    code = run_cli(main, "python -m odolab.navigation.diff", [str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err.strip().splitlines()


def test_won_and_lost_episodes_are_paired_by_odometer_and_episode(tmp_path, capsys):
    before = _folder(tmp_path, "a", [("x", 0, 1, 10, 2), ("x", 1, 0, 500, 40), ("x", 2, 1, 20, 0), ("y", 0, 1, 5, 0)])
    after = _folder(
        tmp_path,
        "b",
        [("x", 2, 0, 500, 90), ("x", 1, 1, 30, 4), ("x", 0, 1, 10, 2), ("x", 3, 1, 9, 9), ("fused(a,b)", 0, 1, 5, 5)],
    )
    b, a = read_episodes(before), read_episodes(after)
    (d,) = diff_runs(b, a)  # y and fused(a,b) are in one run only
    assert (d.odometer, d.episodes, d.success, d.won, d.lost) == ("x", 3, (2, 2), ("1",), ("2",))
    assert d.collisions == (14.0, 32.0) and d.spl == pytest.approx((0.8 * 2 / 3, 0.8 * 2 / 3))
    assert d.success_p == 1.0 and d.spl_change.mean == pytest.approx(0.0)  # one won, one lost: no change
    half = 4.302653 * 0.8 / np.sqrt(3)  # Student's t (2 degrees of freedom) of the differences 0, +0.8, -0.8
    assert (d.spl_change.low, d.spl_change.high) == pytest.approx((-half, half), abs=1e-6)
    assert "| x | 3 | 2 -> 2 | 1 | 2 | 1 | 0.53 -> 0.53 | +0.000 [-1.987, +1.987] | 14.0 -> 32.0 | 177 -> 180 |" in (
        markdown([d])
    )
    assert unpaired(b, a) == [
        "1 odometer(s) only in BEFORE: y",
        "1 odometer(s) only in AFTER: fused(a,b)",
        "episodes of the shared odometers left out: 0 only in BEFORE, 1 only in AFTER",
    ]
    code, out, err = _diff([before, after], capsys)
    assert code == 0 and out.startswith("| odometer |") and len(err) == 4 and err[0].startswith("note: ")
    assert "no readable config.json" in err[3]  # these folders hold a table only


def test_runs_made_with_other_settings_are_pointed_out(tmp_path):
    import json

    def config(folder, policy, max_steps=500):
        (folder / "config.json").write_text(
            json.dumps({"options": {}, "policy": policy, "episodes": [{"max_steps": max_steps, "noise": {"rgb": 1.0}}]})
        )

    before, after = _folder(tmp_path, "a", [("x", 0, 1, 10, 2)]), _folder(tmp_path, "b", [("x", 0, 1, 10, 2)])
    config(before, {"cell": 0.05, "fallback_radius": 0.0})
    config(after, {"cell": 0.05, "fallback_radius": 0.0})
    assert setting_notes(before, after) == []
    config(after, {"cell": 0.05, "fallback_radius": 0.1}, max_steps=12)
    assert setting_notes(before, after) == [
        "the policies differ: fallback_radius 0.0 -> 0.1",
        "the episodes' max_steps differ: 500 -> 12",
    ]
    config(before, {"cell": 0.05})  # a parameter only one folder records
    assert setting_notes(before, after)[0] == "the policies differ: fallback_radius - -> 0.1"
    config(before, {"cell": 0.05, "fallback_radius": 0.1}, max_steps=12)  # a record leaves defaults out
    config(after, {"cell": 0.05, "fallback_radius": 0.1, "plan_every": 4, "plan_step": 2, "fine_radius": 2.0}, 12)
    assert setting_notes(before, after) == ["the policies differ: plan_every 1 -> 4, plan_step 1 -> 2"]
    (after / "config.json").write_text("{")
    assert setting_notes(before, after) == [f"no readable config.json in {after}: the runs' settings were not compared"]


def test_runs_of_other_episodes_are_refused_in_one_line(tmp_path, capsys):
    """Another scene family, other mesh files or other goal distances make other episodes: no pairs;
    the step limit, noise and camera stay notes (the same episodes run otherwise)."""
    import json

    def config(folder, **episode):
        record = {"split": "test", "index": 0, "seed": 0, "max_steps": 500, "noise": {"rgb": 1.0}, **episode}
        (folder / "config.json").write_text(json.dumps({"options": {}, "policy": {}, "episodes": [record]}))

    before, after = _folder(tmp_path, "a", [("x", 0, 1, 10, 2)]), _folder(tmp_path, "b", [("x", 0, 1, 10, 2)])
    config(before)
    config(after, max_steps=12, noise={"rgb": 2.0})
    assert episode_difference(before, after) is None
    code, _, err = _diff([before, after], capsys)
    assert code == 0 and len(err) == 2  # the two notes
    config(after, family="free")
    assert episode_difference(before, after) == "family - -> free"
    config(after, min_goal_distance=5.0, scenes={"digests": ["ab"]})
    assert episode_difference(before, after) == "min_goal_distance - -> 5.0, scenes - -> {'digests': ['ab']}"
    code, out, err = _diff([before, after], capsys)
    assert code == 2 and out == "" and len(err) == 1 and "ran other episodes (min_goal_distance" in err[0]
    config(after, goal_radius=float("nan"), noise="a\nb")  # NaN is NaN; a note stays on one line
    config(before, goal_radius=float("nan"))
    assert episode_difference(before, after) is None
    assert setting_notes(before, after) == ["the episodes' noise differ: {'rgb': 1.0} -> a b"]
    (after / "config.json").write_text(json.dumps({"options": {}, "policy": {}, "episodes": []}))
    assert episode_difference(before, after) is None  # no episode record: not compared, said in a note
    assert setting_notes(before, after) == [
        f"{after}/config.json is not a navigation config: the runs' settings were not compared"
    ]


def test_episodes_of_other_splits_are_named_with_them_and_odd_names_stay_in_their_cell(tmp_path):
    before = _folder(tmp_path, "a", [("x", 0, 0, 10, 2), ("x", 0, 0, 10, 2, "val"), ("a|b\\c\x1b", 0, 0, 1, 1)])
    after = _folder(tmp_path, "b", [("x", 0, 1, 10, 2), ("x", 0, 1, 10, 2, "val"), ("a|b\\c\x1b", 0, 0, 1, 1)])
    x, odd = diff_runs(read_episodes(before), read_episodes(after))
    assert x.won == ("test/0/0", "val/0/0")
    row = markdown([odd]).splitlines()[-1]
    assert row.startswith("| a\\|b\\\\c? | 1 |") and row.count(" | ") == 9


def test_bad_tables_are_refused_in_one_line_naming_file_and_line(tmp_path, capsys):
    good = _folder(tmp_path, "good", [("x", 0, 1, 10, 2)])
    bad = _folder(tmp_path, "bad", [("x", 0, 1, 10, 2)])
    text = (bad / "episodes.csv").read_text()
    cases = [
        (text.replace(",10,2,", ",ten,2,"), "line 2: steps must be a whole number in [0, 1000000], got 'ten'"),
        (text.replace(",10,2,", ",10," + "9" * 400 + ","), "line 2: collisions must be a whole number"),
        (text + text.splitlines()[1] + "\n", "line 3: episode 0 of 'x' (test, seed 0) appears twice"),
        (text.replace(",1.0000,", ",0.5,"), "line 2: success must be 0 or 1, got '0.5'"),
        (text.replace(",1.0000,0.8,", ",1.0000,nan,"), "line 2: spl must be a number in [0, 1]"),
        (text.replace('"x",0,', '"x",0_0,'), "line 2: episode must be a whole number"),
        (text.replace("\n", "\n\n\n", 1).replace(",10,2,", ",ten,2,"), "line 4: steps"),
        ("odometer,episode\nx,0\n", "no column split, seed, success"),
        (HEAD.replace("spl,soft", "success,soft"), "column success appears twice"),
        (HEAD, "holds no episodes"),
        (HEAD + "x,0,test\n", "line 2: 3 fields, the header has 14"),
        (HEAD + '"x,0,test,0\n', "not CSV"),
        (HEAD + "L" * 200_000 + ",0\n", "not CSV"),
        ("\ufeff" + text, None),
        ("\xff\xfe", "not UTF-8 text"),
    ]
    for content, words in cases:
        (bad / "episodes.csv").write_text(content, encoding="latin-1" if content == "\xff\xfe" else "utf-8")
        code, _, err = _diff([good, bad], capsys)
        if words is None:  # a byte-order mark is not part of the first column's name
            assert code == 0, err
            continue
        assert code == 2 and len(err) == 1 and words in err[0] and str(bad / "episodes.csv") in err[0], (words, err)
    code, _, err = _diff([good, tmp_path / "none"], capsys)
    assert (
        code == 2 and len(err) == 1 and "no such episodes table" in err[0] and err[0].count(str(tmp_path / "none")) == 1
    )
    code, _, err = _diff([good, tmp_path / ("x" * 300)], capsys)  # too long a name for the file system
    assert (
        code == 2 and len(err) == 1 and "expected folder and file names of at most 255 bytes, got one of 300" in err[0]
    )
    other = _folder(tmp_path, "other", [("z", 0, 1, 10, 2)])
    code, _, err = _diff([good, other], capsys)
    assert code == 2 and len(err) == 1 and "share no episode" in err[0]  # the refusal alone, no notes first


def test_navigation_diff_given_a_file_names_the_folder_it_expects(tmp_path, capsys):
    from odolab.cli.navigation_diff import main

    (tmp_path / "episodes.csv").write_text("odometer\n")
    argv = [str(tmp_path / "episodes.csv"), str(tmp_path)]
    assert run_cli(main, "python -m odolab.navigation.diff", argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"before {tmp_path}/episodes.csv: is a file" in err
    assert f"({tmp_path})" in err
