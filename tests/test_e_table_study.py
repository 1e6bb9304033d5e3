"""studies/e_table.py: hand-edited saved results are computed again, and the findings need two of
the paper's odometers and judge the order as used and under the paper's protocol."""

from __future__ import annotations


def test_hand_edited_results_are_computed_again_not_drawn():
    from studies.e_table import valid_result

    good = {"dx": 1.0, "dz": 2.0, "dyaw": 0.5, "dx_own": None, "dz_own": 1.0, "dyaw_own": 0.4}
    good |= {"steps": 6, "failure_share": 0.5, "dx_bias": -0.2, "dz_bias": 0.0, "dyaw_bias": 0.1}
    good |= {"dx_raw": 1.5, "dz_raw": 2.5, "dyaw_raw": 0.6, "raw_missing": 1}
    assert valid_result({"all": good})
    for change in (
        {"dx": float("inf")}, {"dx": float("nan")}, {"dx": None}, {"dx": -5.0}, {"dz_own": -1.0},
        {"steps": True}, {"steps": -5}, {"failure_share": None}, {"failure_share": 5}, {"dyaw": "1"},
        {"dx_bias": None}, {"dz_bias": float("inf")}, {"dyaw_bias": "0.1"},
        {"dx_raw": None}, {"dz_raw": -1.0}, {"raw_missing": 7}, {"raw_missing": 4}, {"raw_missing": 1.0}, {"raw_missing": -1},
    ):  # fmt: skip
        assert not valid_result({"all": {**good, **change}}), change


def test_findings_need_two_of_the_papers_odometers_and_say_a_missing_spread():
    from studies.e_table import findings

    row = {
        "family": "boxes",
        "action": "all",
        "dx": 4.9,
        "dz": 3.0,
        "dyaw": 1.0,
        "dx_sd": float("nan"),
        "dz_sd": 0.1,
        "dyaw_sd": 0.2,
    }
    row |= {f"{c}_raw{sd}": row[f"{c}{sd}"] for c in ("dx", "dz", "dyaw") for sd in ("", "_sd")}
    one = findings([{**row, "odometer": "feature-essential"}])
    assert len(one) == 1 and one[0].startswith("No order to compare") and "holds 1 of them" in one[0]
    e3 = {**row, "odometer": "robust-vo", "dx": 1.0, "dx_raw": 9.0}  # lower as used, higher on the raw steps
    two = findings([{**row, "odometer": "feature-essential"}, e3])
    assert two[0] == (
        "dx, as used: ours E3 1.00 +- -, E1 4.90 +- - (x 1e-2, lowest first); agrees with the paper's order E3 < E1"
    )
    assert two[3] == (
        "dx, the paper's protocol: ours E1 4.90 +- -, E3 9.00 +- - (x 1e-2, lowest first); "
        "differs from the paper's order E3 < E1"
    )


def test_the_error_figure_labels_each_odometer_with_its_failure_share(monkeypatch):
    import odolab.io.atomic
    from studies import e_table
    from tests.helpers import captured_figures

    figures = captured_figures(monkeypatch, odolab.io.atomic)
    rows = [
        {
            "family": "boxes",
            "odometer": name,
            "action": "all",
            "failure_share": share,
            **{c: 1.0 for c in e_table.COMPONENTS},
        }
        | {f"{c}_sd": 0.1 for c in e_table.COMPONENTS}
        for name, share in (("icp", 0.254), ("robust-vo", 0.0))
    ]
    e_table.draw(rows, None)
    labels = [t.get_text() for t in figures[0].axes[0].get_yticklabels()]
    assert labels == ["icp\n(25 % of steps failed)", "robust-vo\n(0 % of steps failed)"]


def test_families_are_judged_against_the_first_only_where_the_spreads_are_apart():
    """With two families: each family's order findings, named, then each odometer's change from the
    first family, "higher" or "lower" only where the mean +- sd ranges over seeds do not overlap."""
    from studies.e_table import findings

    def row(family: str, odometer: str, dx: float, dz: float, sd: float) -> dict:
        out = {"family": family, "odometer": odometer, "action": "all", "dx": dx, "dz": dz, "dyaw": 1.0}
        out |= {"dx_sd": sd, "dz_sd": sd, "dyaw_sd": float("nan")}
        return out | {f"{c}_raw{x}": out[f"{c}{x}"] for c in ("dx", "dz", "dyaw") for x in ("", "_sd")}

    rows = [row("boxes", "icp", 1.0, 2.0, 0.1), row("free", "icp", 1.5, 2.1, 0.1), row("free", "deepvo", 5, 5, 0)]
    said = findings(rows)
    assert (
        said[0] == "boxes: No order to compare: the paper's table ranks E1 (feature-essential), E2 "
        "(feature-essential-oracle-rot), E3 (robust-vo); this table holds 0 of them."
    )
    assert said[1].startswith("free: No order to compare")
    assert said[2:] == [
        (
            "icp, boxes -> free (x 1e-2, as used): dx 1.00 -> 1.50 (higher); dz 2.00 -> 2.10 (undecided); "
            "dyaw 1.00 -> 1.00 (undecided)"
        )
    ]


def test_the_e_table_runs_in_mesh_files_keyed_by_their_digests_into_its_own_folder(tmp_path):
    """--scenes: units of the files' test split, keyed by their digests (a copy of the file elsewhere
    reuses every result, whatever the --cache), the report saying where, the episodes kept in --cache;
    without --out, or with --scene-up alone, refused."""
    import shutil

    import pytest

    from odolab.cli.args import UsageError
    from odolab.cli.study import study
    from odolab.sim.mesh_scenes import export_scene
    from odolab.sim.scenes import generate_scene, scene_seed

    (tmp_path / "a").mkdir(), (tmp_path / "b").mkdir()
    room = export_scene(generate_scene(scene_seed("test", 0)), tmp_path / "a" / "room.ply", up="z")
    copy = shutil.copy(room, tmp_path / "b" / "room.ply")
    out = tmp_path / "e"
    argv = ["--scale", "ci", "--out", str(out), "--serial", "--quiet", "--scene-up", "z"]
    cache, other = tmp_path / "cache", tmp_path / "other-cache"
    assert study("e-table", [*argv, "--scenes", str(room), "--cache", str(cache)]) == 0
    assert any(p.is_file() for p in cache.rglob("*"))  # its episodes kept where --cache says
    rows = (out / "table.csv").read_text().splitlines()
    assert {r.split(",")[0] for r in rows[1:]} == {"mesh"} and len(rows) > 3
    assert "the test split of 1 mesh file" in (out / "index.html").read_text()
    saved = sorted(p.name for p in (out / "results").iterdir())
    assert study("e-table", [*argv, "--scenes", str(copy), "--cache", str(other)]) == 0
    assert sorted(p.name for p in (out / "results").iterdir()) == saved  # nothing new: the same content
    assert not any(p.is_file() for p in other.rglob("*"))  # the cache is where episodes lie, not in the key
    with pytest.raises(UsageError, match="needs its own --out"):
        study("e-table", ["--scale", "ci", "--serial", "--scenes", str(room)])
    with pytest.raises(UsageError, match="--scene-up is for --scenes"):
        study("e-table", [*argv])
