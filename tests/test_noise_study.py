"""studies.noise_robustness: the ci scale end to end (every level and odometer, the report), a
second run reusing every saved result, a changed model's and a damaged file's units computed again,
the findings against the paper's claim, a bad definition or results file refused in one line, and
the growth labels."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import pytest

import studies.noise_robustness as noise
from odolab.cli.study import command, study
from studies import framework

CONFIG = framework.load_study("noise_robustness")
CI = framework.scale_params(CONFIG, "ci", noise.Scale)


def _args(out: Path, *more: str) -> list[str]:
    return ["--scale", "ci", "--out", str(out), "--serial", "--quiet", *more]


@pytest.fixture(scope="module")
def ci_run(tmp_path_factory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("noise") / "out"
    assert study("noise-robustness", _args(out)) == 0
    return out, (out / "table.csv").read_text()


@pytest.mark.slow
def test_the_ci_scale_reports_every_level_and_odometer(ci_run):
    out, table = ci_run
    assert {"index.html", "table.csv", "table.md", "errors.png", "growth.png", "manifest.txt", "results"} <= {
        p.name for p in out.iterdir()
    }
    rows = list(csv.DictReader(table.splitlines()))
    assert [(r["odometer"], float(r["level"])) for r in rows] == [
        (o, v) for o in CI.odometers for v in CI.levels
    ] and len(CI.levels) >= 4
    for r in rows:
        if float(r["level"]) == 1.0:
            assert [float(r[f"growth_{c}"]) for c in noise.COMPONENTS] == [1.0, 1.0, 1.0]
    prior = [r for r in rows if r["odometer"] == "action-prior"]
    assert len({(r["dx"], r["dz"], r["dyaw"]) for r in prior}) == 1  # it does not read the frames
    assert len(list((out / "results").glob("*.json"))) == len(CI.levels) * len(CI.odometers)
    page = (out / "index.html").read_text()
    assert "Against the paper" in page and "section 5" in page and 'src="errors.png"' in page
    assert "action-prior: the same error at every level" in page


def test_a_second_run_reuses_every_saved_result(ci_run, capsys):
    out, table = ci_run
    capsys.readouterr()
    assert study("noise-robustness", _args(out)) == 0
    assert "0 units computed" in capsys.readouterr().out
    assert (out / "table.csv").read_text() == table


@pytest.mark.slow
def test_a_changed_model_and_a_damaged_result_are_computed_again(ci_run, tmp_path, monkeypatch, capsys):
    out, table = ci_run
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    store = framework.ResultStore(copy / "results")
    unit = next(u for u in noise.units(CI, {o: None for o in CI.odometers}) if u.label == "action-prior x2")
    path = copy / "results" / f"{unit.digest}.json"
    doc = json.loads(path.read_text())
    doc["result"]["value"]["dx"] = -1.0  # edited by hand: not a result
    path.write_text(json.dumps(doc))
    assert store.get(unit) is not None and not noise.valid_result(store.get(unit)["value"])
    real = framework.identities

    def retrained(config, scale, odometers, options=None):  # as if icp's settings had changed
        return {**real(config, scale, odometers, options), "icp": "0" * 64}

    monkeypatch.setattr(framework, "identities", retrained)
    capsys.readouterr()
    assert study("noise-robustness", _args(copy)) == 0
    assert f"{1 + len(CI.levels)} units computed" in capsys.readouterr().out  # icp at every level, and the damaged one
    assert (copy / "table.csv").read_text() == table  # the same numbers: only the key changed


def _rows(growth: dict[str, float]) -> list[dict]:
    """Rows at x1 and x3 whose dx, dz, dyaw grow by ``growth[odometer]``."""
    results = {}
    for odo, g in growth.items():
        for level, factor in ((1.0, 1.0), (3.0, g)):
            results[noise.label(odo, level)] = {
                "steps": 10,
                **{c: 2.0 * factor for c in noise.COMPONENTS},
                **{f"{c}_own": None for c in noise.COMPONENTS},
                "failure_share": 0.0,
                "ate_m": 0.1,
            }
    return results


def test_the_findings_say_where_the_papers_claim_holds():
    scale = noise.Scale((1.0, 3.0), 1, 6, ("action-prior", "icp", "robust-vo"), ("robust-vo",))
    holds = noise.findings(scale, noise.table(scale, _rows({"action-prior": 1.0, "icp": 1.3, "robust-vo": 1.01})))
    assert holds[0].startswith("dx at noise x3") and "agrees with the paper's claim" in holds[0]
    assert "agrees in 3 of 3 components" in holds[3] and holds[4].startswith("action-prior: the same error")
    fails = noise.findings(scale, noise.table(scale, _rows({"action-prior": 1.0, "icp": 1.3, "robust-vo": 1.5})))
    assert "differs from the paper's claim" in fails[0] and "agrees in 0 of 3" in fails[3]
    untested = noise.findings(CI, [])
    assert "not tested at this scale" in untested[0]


def test_a_bad_definition_is_refused_naming_file_and_field(tmp_path, monkeypatch, capsys):
    text = (framework.HERE / "noise_robustness.toml").read_text()
    real = framework.load_study
    monkeypatch.setattr(framework, "load_study", lambda name: real(name, tmp_path))
    for old, new, said in (
        ("levels = [1, 1.5, 2, 3]\nepisodes = 1\n", "levels = [1.5, 2]\nepisodes = 1\n", "levels must hold 1"),
        ("learned = []\n\n# cpu", 'learned = ["deepvo"]\n\n# cpu', "learned must name odometers among the odometers"),
        ('odometers = ["action-prior", "icp"]', 'odometers = ["action-prior", "nope"]', "odometers: nope: unknown"),
    ):
        assert old in text, old
        (tmp_path / "noise_robustness.toml").write_text(text.replace(old, new, 1))
        assert command("noise-robustness", _args(tmp_path / "out")) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and f"{tmp_path / 'noise_robustness.toml'}: scales.ci" in err and said in err, err
    assert not (tmp_path / "out").exists()  # refused before any folder was made


def _noise_row() -> dict:
    return {
        "steps": 10,
        "dx": 1.0,
        "dz": 1.0,
        "dyaw": 1.0,
        "dx_own": 1.0,
        "dz_own": None,
        "dyaw_own": 1.0,
        "failure_share": 0.1,
        "ate_m": 0.2,
    }


@pytest.mark.slow
def test_the_noise_study_names_a_damaged_results_file_in_one_line(tmp_path, capsys):
    """A result with an integer of 400 digits, a bool, a negative error or a share above 1 is damage
    (the unit is computed again, or missing with --redraw), and results files of JSON nested 100,000
    deep or of 400-digit numbers are one line, not a traceback."""
    import studies.noise_robustness as noise
    from studies import framework

    assert noise.valid_result(_noise_row())
    for key, value in (
        ("dx", 10**400),
        ("dz", True),
        ("dyaw", -1.0),
        ("failure_share", 1.5),
        ("dx_own", 10**400),
        ("ate_m", float("nan")),
        ("steps", 1.5),
    ):
        assert not noise.valid_result({**_noise_row(), key: value}), key
    scale = framework.scale_params(framework.load_study("noise_robustness"), "ci", noise.Scale)
    unit = noise.units(scale, {o: None for o in scale.odometers})[0]
    out = tmp_path / "n"
    (out / "results").mkdir(parents=True)
    (out / "manifest.txt").write_text("# odolab study noise_robustness\n")
    doc = {"label": unit.label, "key": unit.key, "result": {"value": _noise_row(), "seconds": 10**400}}
    (out / "results" / f"{unit.digest}.json").write_text(json.dumps(doc))
    argv = ["--scale", "ci", "--redraw", "--quiet", "--out", str(out)]
    assert command("noise-robustness", argv) == 0  # its seconds damaged: counted as none
    big = json.dumps(doc).replace('"dx": 1.0', '"dx": 1' + "0" * 400, 1)
    for text in (big, '{"a":' * 100_000):
        (out / "results" / f"{unit.digest}.json").write_text(text)
        capsys.readouterr()
        assert command("noise-robustness", argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err and "no saved results in" in err, err


def test_noise_growth_labels_show_small_growth():
    from studies.noise_robustness import growth_label

    assert growth_label(2.25, 2.34) == "+4.0 %"
    assert growth_label(1.15, 1.20) == "+4.3 %"
    assert growth_label(0.55, 0.74) == "+35 %"
    assert growth_label(2.0, 1.96) == "-2.0 %"
    assert growth_label(1.41, 1.41) == "0.0 %"
    assert growth_label(0.0, 1.0) == ""


def test_the_growth_figure_shows_the_error_itself_under_the_growth_in_the_same_colours():
    import matplotlib.pyplot as plt

    scale = noise.Scale((1.0, 3.0), 1, 6, ("action-prior", "icp", "robust-vo"), ("robust-vo",))
    results = _rows({"action-prior": 1.0, "icp": 1.3, "robust-vo": 1.5})
    results[noise.label("icp", 1.0)]["dx"] = results[noise.label("icp", 3.0)]["dx"] = 9.0  # large, not growing
    rows = noise.table(scale, results)
    fig = noise.figure(scale, rows, growth=True)
    try:
        assert len(fig.axes) == 6
        growth, errors = fig.axes[:3], fig.axes[3:]
        for top, bottom, c in zip(growth, errors, noise.COMPONENTS):
            assert top.get_ylabel() == f"{c}: error / error at x1"
            assert bottom.get_ylabel() == f"{c}: mean abs. error ({noise.UNITS[c]} x 1e-2)"
            assert [ln.get_color() for ln in top.get_lines()[:3]] == [ln.get_color() for ln in bottom.get_lines()]
            for odo, line in zip(scale.odometers, bottom.get_lines()):
                assert list(line.get_ydata()) == [r[c] for r in rows if r["odometer"] == odo]
        # icp's dx does not grow but stays far above robust-vo's, which grows by half
        assert list(errors[0].get_lines()[1].get_ydata()) == [9.0, 9.0]
        assert list(growth[0].get_lines()[2].get_ydata()) == [1.0, 1.5]
        assert [t.get_text() for t in fig.legends[0].get_texts()] == ["action-prior", "icp", "robust-vo (learned)"]
    finally:
        plt.close(fig)
    fig = noise.figure(scale, rows, growth=False)
    try:
        assert len(fig.axes) == 3 and all("mean abs. error" in ax.get_ylabel() for ax in fig.axes)
    finally:
        plt.close(fig)


def test_noise_robustness_runs_in_mesh_files_keyed_by_their_digests(tmp_path):
    """--scenes: every unit's key holds the files' digests (not their paths), the report says where."""
    import json

    from odolab.sim.mesh_scenes import export_scene, read_mesh
    from odolab.sim.scenes import generate_scene, scene_seed

    room = export_scene(generate_scene(scene_seed("test", 1)), tmp_path / "room.glb")
    out = tmp_path / "n"
    assert (
        study("noise-robustness", ["--scale", "ci", "--out", str(out), "--serial", "--quiet", "--scenes", str(room)])
        == 0
    )
    keys = [json.loads(p.read_text())["key"] for p in (out / "results").glob("*.json")]
    assert keys and all(k["scenes"]["digests"] == [read_mesh(room).digest] for k in keys)
    assert str(tmp_path) not in json.dumps(keys) and "mesh file(s)" in (out / "index.html").read_text()
