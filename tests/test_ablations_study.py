"""studies.ablations (the paper's Table 2): each row's changes give the recipe of its switches, and
the ci scale trains, evaluates and navigates every configured row, reuses its saved results and
redraws from them alone."""

from __future__ import annotations

import csv
import math
import shutil
from pathlib import Path

import pytest

from odolab.cli.study import command, study
from odolab.config import ConfigError
from studies import ablations, framework

DEFINITION = ablations.load_definition()


def _recipes(scale: str, root: Path) -> dict[int, object]:
    """Every row's recipe at ``scale`` (a row without a model of its own: the model it runs)."""
    s = DEFINITION.scales[scale]
    return {
        n: ablations.recipe(DEFINITION, s, m, root)
        for n, row in DEFINITION.rows.items()
        if (m := ablations.model_row(row)) is not None
    }


@pytest.mark.parametrize("scale", ["ci", "cpu", "cpu-4x", "paper"])
def test_each_rows_changes_give_the_recipe_of_its_switches(scale: str, tmp_path: Path):
    from odolab.learned.deepvo.config import DeepVOTraining
    from odolab.learned.robust_vo.config import TrainConfig

    recipes = _recipes(scale, tmp_path)
    assert 19 not in DEFINITION.rows and {0, 20} <= set(DEFINITION.rows)
    assert isinstance(recipes[0], DeepVOTraining) and 20 not in recipes
    for n, cfg in recipes.items():
        switches = DEFINITION.rows[n].switches
        if switches is None:
            continue
        assert isinstance(cfg, TrainConfig)
        m = cfg.model
        assert m.visual == ablations.VISUAL[switches.visual], n
        assert m.dd_bins == switches.dd and m.sproj == switches.sproj, n
        assert (m.dropout > 0) == switches.dropout, n
        assert m.kind == ablations.ACTINFO[switches.actinfo], n
        assert any(s.data_aug for s in cfg.stages) == switches.data_aug, n
        assert any(s.geoinv for s in cfg.stages) == switches.geoinv, n
        # the shared base: the warp hands a network the action, so only the rows that know it read
        # the warped frame; the mirrored right turns need SepAct; no depth residual anywhere
        assert m.warp == ("none" if switches.actinfo == "none" else "nominal"), n
        assert m.mirror_turns == (switches.actinfo == "SepAct") and m.depth_residual == 0.0, n
        assert cfg.data_root == str(tmp_path)
    one = recipes[1].model
    assert (one.visual, one.dd_bins, one.sproj, one.kind) == ("rgb", 0, False, "unified")  # RGB only
    assert recipes[17].model.dd_bins == 0 and recipes[17].model.kind == "sepact"  # SepAct without DD
    assert [s.name for s in recipes[17].stages] == ["forward", "turns"]
    assert recipes[18].model.dd_bins == 10 and recipes[18].model.sproj
    assert recipes[6].model.base_planes == recipes[7].model.base_planes == 2 * recipes[4].model.base_planes
    assert recipes[5] == recipes[4] and DEFINITION.rows[5].options == {"mc_samples": 10}


def test_the_cpu_scale_keeps_to_its_budget(tmp_path: Path):
    """At most 20 CPU-hours at 35 pairs/s a unit: the training passes (a GeoInv pair counts twice;
    each stage's ``pairs_per_epoch``, an upper bound where the data hold fewer samples), the wide
    rows' extra (0.4 hours) and the evaluations' estimate in studies/ablations.toml (6.3 hours) fit."""
    passes = 0
    for n, cfg in _recipes("cpu", tmp_path).items():
        if n != ablations.model_row(DEFINITION.rows[n]):
            continue
        if n == 0:
            passes += cfg.epochs * cfg.windows_per_epoch * (cfg.window - 1)
        else:
            passes += sum(s.epochs * s.pairs_per_epoch * (2 if s.geoinv else 1) for s in cfg.stages)
    assert passes / 35 / 3600 + 0.4 + 6.3 <= 20
    scale = DEFINITION.scales["cpu"]
    assert len(scale.seeds) == 3 and scale.episodes == 20 and scale.nav_episodes * len(scale.nav_seeds) >= 50


def test_the_row_18_recipes_of_the_warp_probe_are_the_studys_row_18_at_its_cpu_scale():
    """studies/robust_vo/ablations/row18-cpu-warp.toml trains what the study trains for row 18 at its
    cpu scale (with the shared base of the rows that know the action); row18-cpu.toml, the paper's
    input, differs from it in the warp and the mirrored turns alone; row18-cpu-4x.toml in its epochs alone
    (four times each stage's)."""
    from odolab.learned.robust_vo.config import load_train_config

    folder = ablations.ROOT / "studies" / "robust_vo" / "ablations"
    study = ablations.recipe_identity(ablations.recipe(DEFINITION, DEFINITION.scales["cpu"], 18, Path("data")))
    assert ablations.recipe_identity(load_train_config(str(folder / "row18-cpu-warp.toml"))) == study
    paper = ablations.recipe_identity(load_train_config(str(folder / "row18-cpu.toml")))
    assert paper["model"] == {**study["model"], "warp": "none", "mirror_turns": False}
    assert {k: v for k, v in paper.items() if k != "model"} == {k: v for k, v in study.items() if k != "model"}
    four = ablations.recipe_identity(load_train_config(str(folder / "row18-cpu-4x.toml")))  # the budget probe
    at_4x = ablations.recipe(DEFINITION, DEFINITION.scales["cpu-4x"], 18, Path("data"))
    assert ablations.recipe_identity(at_4x) == four  # the cpu-4x scale's row 18 is the probe's recipe
    seeded = ablations.recipe_identity(ablations.recipe(DEFINITION, DEFINITION.scales["cpu-4x"], 18, Path("data"), 2))
    assert seeded == {**four, "seed": 2} and ablations.default_out("cpu-4x") == Path("reports/ablations-4x")
    assert [s["epochs"] for s in four["stages"]] == [4 * s["epochs"] for s in study["stages"]]
    assert [{**s, "epochs": 0} for s in four["stages"]] == [{**s, "epochs": 0} for s in study["stages"]]
    assert {k: v for k, v in four.items() if k != "stages"} == {k: v for k, v in study.items() if k != "stages"}


def test_a_definition_naming_an_unknown_row_is_refused(tmp_path: Path):
    text = ablations.DEFINITION.read_text(encoding="utf-8").replace("rows = [0, 1, 4,", "rows = [0, 99, 4,", 1)
    (tmp_path / "a.toml").write_text(text)
    with pytest.raises(ConfigError, match=r"a.toml: scales.ci.rows: no such row 99"):
        ablations.load_definition(tmp_path / "a.toml")


@pytest.mark.parametrize(
    ("old", "new", "said"),
    [
        (
            "row = 6\nswitches",
            "row = 6\nmodel_of = 21\nswitches",
            r"row 6: model_of: a row using another's model trains nothing",
        ),
        ("success = 81,", "success = 81, speed = 3,", r"row 18: paper: unknown field\(s\) speed"),
        ("error = [1.10, 0.84, 0.68]", "error = [1.10, 0.84]", r"row 18: paper.error: expected 3 numbers"),
        (
            "options = { mc_samples = 10 }",
            "options = { mc_samplez = 10 }",
            r"row 5: options: .* no option 'mc_samplez'",
        ),
        ("options = { mc_samples = 10 }", "options = 'x'", r"row 5: options: expected a table, got 'x'"),
        ("options = { mc_samples = 10 }", "options = []", r"row 5: options: expected a table, got \[\]"),
        (
            "model_of = 4",
            "model_of = 0",
            r"row 5: model_of: expected a row of the same odometer that trains a model, got 0",
        ),
        ("model_of = 4", "model_of = 4\nwide = true", r"row 5: model_of: a row using another's model trains nothing"),
        (
            'row = 1\nswitches = { visual = "RGB", dd = 0,',
            'row = 1\nswitches = { visual = "RGB", dd = -3,',
            r"row 1: switches.dd: expected 0",
        ),
        (
            "options = { mc_samples = 10 }",
            'options = { checkpoint = "x.pt" }',
            r"row 5: options: checkpoint is the row's own",
        ),
        ("row = 7\n", "row = 6\n", r"rows: expected one row of each number, got two of 6"),
        (
            "row = 6\nswitches",
            "row = 6\nmodel_of = 6\nswitches",
            r"row 6: model_of: expected another row that trains a model, got its own number",
        ),
        (
            "error = [1.10, 0.84, 0.68]",
            "error = [1.10, nan, 0.68]",
            r"row 18: paper.error\[1\]: expected a finite number >= 0, got nan",
        ),
        ("success = 81,", "success = nan,", r"paper.success: expected a number in \[0, 100\], got nan"),
        ("success = 81,", "success = 150,", r"row 18: paper.success: expected a number in \[0, 100\], got 150"),
        ("d_g = 0.51,", "d_g = -1,", r"row 18: paper.d_g: expected a finite number >= 0, got -1"),
        (
            'odometer = "action-prior"',
            'odometer = "action-prior"\npaper = { success = 1, spl = 1, d_g = 1, soft_spl = 1, params = "" }',
            r"row 21: paper: expected none",
        ),
        ("seeds = [0, 1, 2]", "seeds = []", r"scales.cpu: seeds must hold at least 1 item, got \[\]"),
        ("rows = [0, 1, 4,", "rows = [0, 0, 1, 4,", r"scales.ci: rows must hold no value twice"),
        (
            "nav_episodes = 50",
            "nav_episodes = -4",
            r"scales.cpu: nav_episodes must be in \[1, 1000\], got -4",
        ),
        ('device = "cpu"', 'device = "tpu9"', r"scales.ci: device must be .* got 'tpu9'"),
        ("train_threads = 1", "train_threads = -1", r"scales.ci: train_threads must be in \[0, 1024\]"),
    ],
)
def test_a_bad_row_or_scale_is_refused_when_the_definition_is_read(tmp_path: Path, old: str, new: str, said: str):
    text = ablations.DEFINITION.read_text(encoding="utf-8")
    assert old in text
    (tmp_path / "a.toml").write_text(text.replace(old, new, 1))
    with pytest.raises(ConfigError, match=said):
        ablations.load_definition(tmp_path / "a.toml")


def test_a_paper_row_without_the_papers_numbers_is_refused(tmp_path: Path):
    text = ablations.DEFINITION.read_text(encoding="utf-8")
    start = text.index("paper = {", text.index("row = 3\n"))
    (tmp_path / "a.toml").write_text(text[:start] + text[text.index("\n", start) + 1 :])
    with pytest.raises(ConfigError, match=r"a.toml: row 3: paper: expected the paper's numbers for its row, got none"):
        ablations.load_definition(tmp_path / "a.toml")


@pytest.fixture(scope="module")
def ci_run(tmp_path_factory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("ablations") / "out"
    assert study("ablations", ["--scale", "ci", "--out", str(out), "--serial", "--quiet"]) == 0
    return out, (out / "table.csv").read_text()


def _units(scale: ablations.Scale) -> int:
    """Training units (one per model, and one per further training seed of a train_seed_row) and every
    run's evaluation units (per seed, and per navigation seed and episode)."""
    models = {ablations.model_row(DEFINITION.rows[r]) for r in scale.rows} - {None}
    further = len(scale.train_seed_rows) * len(scale.train_seeds)
    per_row = len(scale.seeds) + len(scale.nav_seeds) * scale.nav_episodes
    return len(models) + further + (len(scale.rows) + further) * per_row


@pytest.mark.slow
def test_the_ci_scale_reports_every_row_beside_the_paper(ci_run):
    out, table = ci_run
    assert {"index.html", "table.csv", "table.md", "success-vs-error.png", "manifest.txt", "results"} <= {
        p.name for p in out.iterdir()
    }
    scale = DEFINITION.scales["ci"]
    rows = list(csv.DictReader(table.splitlines()))
    assert [int(r["row"]) for r in rows] == list(scale.rows)
    for r in rows:
        for column in ("S", "SPL", "d_G", "SoftSPL", "dx", "dz", "dyaw"):
            assert math.isfinite(float(r[column])), (r["row"], column)
        reference = r["row"] in ("20", "21")  # ground truth and the action prior: no speed
        assert math.isnan(float(r["fps"])) if reference else float(r["fps"]) > 0
        paper = DEFINITION.rows[int(r["row"])].paper
        assert math.isnan(float(r["paper_S"])) if paper is None else float(r["paper_S"]) == paper.success
    by_row = {int(r["row"]): r for r in rows}
    assert by_row[20]["dx"] == "0.0" and by_row[18]["S_vs_18"] == ""
    # the action prior (not the paper's): its own numbers, nothing to set beside the paper's
    prior = by_row[21]
    assert prior["setting"] == "Action prior" and float(prior["dx"]) > 0 and prior["params_M"] == ""
    assert prior["S_vs_18"] == prior["error_vs_18"] == "" and prior["paper_error"] == ""
    assert [by_row[18][c] for c in ablations.SWITCH_COLUMNS] == [
        "RGB-D",
        "10",
        "\u2713",
        "\u2713",
        "SepAct",
        "\u2713",
        "\u2713",
    ]
    assert by_row[1]["Visual"] == "RGB" and by_row[1]["ActInfo"] == "" and by_row[0]["setting"] == "DeepVO"
    assert by_row[7]["S_vs_18"] in ("", "tie", "agrees (overlap)", "differs (overlap)")  # 1 episode: no interval
    # two networks: forward, and the turn network that answers right turns mirrored
    assert by_row[18]["params_M"].startswith("2x") and by_row[18]["paper_error"] == "(1.10, 0.84, 0.68)"
    assert by_row[5]["params_M"] == by_row[4]["params_M"]  # row 4's model, run with 10 dropout passes
    # row 18 trained with a second seed: the spread over the two runs beside the row's own numbers
    assert scale.train_seed_rows == (18,) and (out / ablations.model_file(18, 1)).is_file()
    assert by_row[18]["train_seeds"] == "2" and float(by_row[18]["S_train_sd"]) >= 0
    assert float(by_row[18]["error_train_sd"]) > 0  # two trainings of other seeds answer otherwise
    assert by_row[4]["train_seeds"] == "1" and by_row[4]["S_train_sd"] == "" and by_row[21]["train_seeds"] == ""
    for n in {ablations.model_row(DEFINITION.rows[r]) for r in scale.rows} - {None}:
        assert (out / ablations.model_file(n)).is_file()
    assert not [p for p in (out / "work").rglob("*") if p.is_file()]  # finished states go once exported
    assert len(list((out / "results").glob("*.json"))) == _units(scale)
    html = (out / "index.html").read_text()
    assert "row 19 is left out" in html and "Against the paper" in html
    assert "Per-step error against the action prior (row 21" in html and "Spearman" in html


def _line(row: int, error: float, success: float, setting: str = "robust VO") -> dict:
    """A table line with what the findings read: its mean error and navigation, ours and the paper's."""
    nav = {"S": success, "SoftSPL": success / 2, "d_G": 10 - success / 10}
    ranges = {f"{k}_range": (v - 1, v + 1) for k, v in nav.items()}
    return {
        "row": row, "setting": setting, "dx": error, "dz": error, "dyaw": error,
        **{f"{c}_sd": 0.1 for c in ablations.COMPONENTS}, **nav, **ranges, "SPL": success, "SPL_range": (0, 1),
        "paper_error_mean": error, "paper_S": 100 - error, "paper_SoftSPL": 50.0, "paper_d_G": error,
    }  # fmt: skip


def test_the_claim_and_the_floor_are_read_from_the_lines():
    lines = [_line(1, 3.0, 10), _line(2, 2.0, 20), _line(3, 1.0, 40), _line(20, 0.0, 99, "Ground truth")]
    claim = ablations.claim_findings(lines)
    assert claim[0].endswith("ours: S -1.00 (3 rows), SoftSPL -1.00 (3 rows), d_G +1.00 (3 rows)")
    assert claim[1].endswith("the paper's: S -1.00 (3 rows), d_G +1.00 (3 rows)")  # SoftSPL the same in all
    assert ablations.floor_findings(lines) == []  # no action prior
    floor = ablations.floor_findings([*lines, _line(21, 2.5, 15, "Action prior")])
    assert floor[0].endswith("standard deviations over the seeds: dx: 2, 3; dz: 2, 3; dyaw: 2, 3")
    assert floor[1].endswith("S: 2, 3; SPL: none; SoftSPL: 2, 3; d_G: 3")  # d_G 8.0 +- 1 meets 8.5 +- 1


def test_the_papers_claims_get_a_verdict_from_paired_tests_on_the_shared_episodes():
    """claims(): 18 over 13 succeeds on 20 episodes where 13 fails (McNemar: supports, as the paper's
    81 > 79); 16 beats 18 on every episode (contradicts); 15 against 18 on one episode (undecided);
    per-episode errors paired across seeds, a result without them gives no test."""
    import dataclasses

    scale = dataclasses.replace(
        DEFINITION.scales["cpu"], rows=(13, 15, 16, 18), seeds=(0, 1), nav_seeds=(0,), nav_episodes=20
    )

    def nav(row: int, e: int) -> dict:
        success = {18: 1, 13: 0, 16: 1, 15: int(e == 0)}[row] if row != 18 or e < 20 else 0
        return {"success": success, "spl": 0.5 * success}

    navigation = {f"navigate row {r} seed 0 episode {e}": nav(r, e) for r in (13, 16, 18) for e in range(20)}
    navigation |= {"navigate row 15 seed 0 episode 0": nav(15, 0)}
    navigation |= {f"navigate row 18 seed 0 episode {e}": {"success": 0, "spl": 0.0} for e in range(10, 20)}
    rng = __import__("numpy").random.default_rng(0)
    errors = {
        f"errors row {r} seed {s}": {"episodes": [[base + rng.normal(0, 0.05)] * 3 for _ in range(10)]}
        for r, base in ((18, 1.0), (13, 1.0), (15, 1.5), (16, 1.0))
        for s in (0, 1)
    }
    errors["errors row 16 seed 1"] = {}  # saved before per-episode errors were kept: seed 1 is left out
    lines = {(ln["claim"], ln["measure"]): ln for ln in ablations.claims(DEFINITION, scale, errors, navigation)}
    assert set(lines) == {(f"18 over {b}", m) for b in (13, 15, 16) for m in ("success", "SPL", "error")}
    assert all(set(ln) == set(ablations.CLAIM_COLUMNS) for ln in lines.values())
    success = lines[("18 over 13", "success")]
    assert (success["pairs"], success["a_only"], success["b_only"]) == (20, 10, 0)
    assert success["p"] == pytest.approx(2 * 0.5**10) and success["p"] < success["p_holm"] < ablations.ALPHA
    assert success["verdict"] == "supports" and success["diff"] == pytest.approx(50.0)
    assert lines[("18 over 16", "success")]["verdict"] == "contradicts"  # 16 succeeds where 18 fails
    assert lines[("18 over 15", "success")]["pairs"] == 1 and lines[("18 over 15", "success")]["verdict"] == "undecided"
    assert lines[("18 over 15", "error")]["verdict"] == "supports" and lines[("18 over 15", "error")]["pairs"] == 20
    assert lines[("18 over 16", "error")]["pairs"] == 10 and lines[("18 over 13", "error")]["verdict"] == "undecided"
    table = ablations.claims_table(list(lines.values()))
    assert table.name == "claims" and "McNemar" in table.intro[0] and "Holm" in table.intro[0]


def test_claims_between_rows_trained_under_several_seeds_are_tested_over_the_training_runs():
    """10 over 8, both trained under three seeds: the main runs' errors differ by the same 0.3 on every
    episode (a test over episodes would decide), but the runs of the other seeds differ the other
    way, so over the training runs the error is undecided; row 10 succeeding in every run and row 8
    in none is decided over the runs too."""
    import dataclasses

    scale = dataclasses.replace(
        DEFINITION.scales["cpu"],
        rows=(8, 10),
        seeds=(0,),
        nav_seeds=(0,),
        nav_episodes=10,
        train_seed_rows=(8, 10),
        train_seeds=(1, 2),
    )
    runs = {None: 0.3, 1: -0.28, 2: 0.05}  # row 10's error minus row 8's, per training run
    successes = {None: 9, 1: 10, 2: 8}  # row 10's successes of 10 per training run (row 8's: none)
    rng = __import__("numpy").random.default_rng(1)
    errors, navigation = {}, {}
    for k, offset in runs.items():
        for row, value in ((8, 2.0), (10, 2.0 + offset)):
            label = ablations.run_label(row, k)
            errors[f"errors {label} seed 0"] = {"episodes": [[value + rng.normal(0, 1e-3)] * 3 for _ in range(10)]}
            for e in range(10):
                success = int(row == 10 and e < successes[k])
                navigation[f"navigate {label} seed 0 episode {e}"] = {"success": success, "spl": 0.4 * success}

    def claims(scale, navigation=navigation):
        return {(ln["claim"], ln["measure"]): ln for ln in ablations.claims(DEFINITION, scale, errors, navigation)}

    lines = claims(scale)
    error, success = lines[("10 over 8", "error")], lines[("10 over 8", "success")]
    assert error["tested_over"] == success["tested_over"] == "training runs"
    assert error["pairs"] == 3 and error["verdict"] == "undecided"
    assert error["diff"] == pytest.approx(sum(runs.values()) / 3, abs=1e-3)
    assert success["pairs"] == 3 and success["verdict"] == "supports" and success["diff"] == pytest.approx(90.0)
    for seeded in ((8,), ()):
        main = claims(dataclasses.replace(scale, train_seed_rows=seeded, train_seeds=(1, 2) if seeded else ()))
        assert main[("10 over 8", "error")]["tested_over"] == "episodes"  # one row has one run: over episodes
        assert main[("10 over 8", "error")]["verdict"] == "contradicts"  # the main runs alone: 0.3 worse
    flat = {k: {"success": int(" row 10 " in k and k.endswith("episode 0")), "spl": 0.0} for k in navigation}
    flat_success = claims(scale, flat)[("10 over 8", "success")]
    assert flat_success["diff"] == pytest.approx(10.0)  # 10 points more in each of the 3 runs
    assert flat_success["verdict"] == "undecided"  # no spread over 3 runs: no test


@pytest.mark.slow
def test_a_second_run_reuses_every_saved_result(ci_run, capsys):
    out, table = ci_run
    models = {p: p.stat().st_mtime_ns for p in (out / "models").rglob("model.pt")}
    data, aside = out / "data", out.parent / "data-aside"
    data.rename(aside)
    try:
        assert study("ablations", ["--scale", "ci", "--out", str(out), "--serial", "--quiet"]) == 0
        assert not data.exists()  # every model is trained: no training data made again
    finally:
        shutil.rmtree(data, ignore_errors=True)
        aside.rename(data)
    assert "0 units computed" in capsys.readouterr().out
    assert {p: p.stat().st_mtime_ns for p in (out / "models").rglob("model.pt")} == models
    assert (out / "table.csv").read_text() == table


@pytest.mark.slow
def test_redraw_needs_only_the_saved_results(ci_run, tmp_path: Path, capsys):
    out, table = ci_run
    copy = tmp_path / "copy"
    shutil.copytree(out / "results", copy / "results")
    shutil.copy(out / "manifest.txt", copy / "manifest.txt")  # no models, data or work folders
    assert study("ablations", ["--scale", "ci", "--out", str(copy), "--redraw", "--quiet"]) == 0
    assert "0 units computed" in capsys.readouterr().out
    assert (copy / "table.csv").read_text() == table and (copy / "success-vs-error.png").is_file()


@pytest.mark.slow
def test_a_damaged_model_file_is_trained_again(ci_run, tmp_path: Path, capsys):
    out, _ = ci_run
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    (copy / ablations.model_file(4)).write_bytes(b"not a model")
    assert study("ablations", ["--scale", "ci", "--out", str(copy), "--serial", "--quiet"]) == 0
    from odolab.learned.training.checkpoints import what_file

    assert what_file(copy / ablations.model_file(4)) is None  # a model again
    assert "1 training" in capsys.readouterr().out


@pytest.mark.slow
def test_a_folder_where_a_model_file_goes_is_refused_before_training(ci_run, tmp_path: Path, capsys):

    out, _ = ci_run
    copy = tmp_path / "copy"
    shutil.copytree(out / "results", copy / "results")
    shutil.copy(out / "manifest.txt", copy / "manifest.txt")
    (copy / ablations.model_file(4)).mkdir(parents=True)
    assert command("ablations", ["--scale", "ci", "--out", str(copy), "--serial", "--quiet"]) == 2
    assert "expected row 4's model file or nothing, found a folder" in capsys.readouterr().err
    assert not (copy / "data").exists()


@pytest.mark.slow
def test_a_changed_model_file_is_not_taken_for_its_result(ci_run, tmp_path: Path):
    out, _ = ci_run
    value = ablations.model_summary(out / ablations.model_file(18), "robust-vo", out)
    assert ablations.valid_model(value, out=out, check_file=True)
    shutil.copytree(out / "models", tmp_path / "models")
    (tmp_path / ablations.model_file(18)).write_bytes(b"other weights")
    assert not ablations.valid_model(value, out=tmp_path, check_file=True)
    assert ablations.valid_model(value, out=tmp_path, check_file=False)  # --redraw reads numbers only


def test_the_paper_scale_on_a_machine_without_gpus_is_refused_before_anything_is_made(tmp_path, monkeypatch, capsys):
    """The paper scale asks Ray for a GPU per training unit; started here (no GPU, no cluster) it would
    render 14,000 episodes and then wait for ever: one line, exit 2, nothing made."""
    import torch

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 0)
    out = tmp_path / "paper"
    assert command("ablations", ["--scale", "paper", "--out", str(out)]) == 2
    assert "asks Ray for 1 GPU per training unit" in capsys.readouterr().err and not out.exists()


@pytest.mark.parametrize(
    ("change", "said"),
    [("model.nope=1", r"model: unknown field\(s\) nope"), ("garbage", r"'garbage': expected path=value")],
)
def test_a_bad_row_change_names_the_definition_and_the_row(tmp_path: Path, change: str, said: str):
    text = ablations.DEFINITION.read_text(encoding="utf-8").replace(
        "changes = ['model.visual=\"rgb\"']", f"changes = ['{change}']", 1
    )
    (tmp_path / "a.toml").write_text(text)
    definition = ablations.load_definition(tmp_path / "a.toml")
    with pytest.raises(ConfigError, match=rf"a.toml: row 1's recipe \(studies/robust_vo/shipped.toml .*\): {said}"):
        ablations.recipe(definition, definition.scales["cpu"], 1, tmp_path / "data")


def test_a_row_option_value_its_odometer_refuses_is_refused_before_any_work(tmp_path: Path):
    text = ablations.DEFINITION.read_text(encoding="utf-8")
    (tmp_path / "a.toml").write_text(text.replace("options = { mc_samples = 10 }", "options = { mc_samples = 1 }", 1))
    definition = ablations.load_definition(tmp_path / "a.toml")
    with pytest.raises(
        ConfigError, match=r"a.toml: row 5: options: mc_samples must be 0 \(off\) or in \[2, 1000\], got 1"
    ):
        ablations.check_option_values(definition, 5)
    ablations.check_option_values(DEFINITION, 5)  # the committed value is taken


def test_the_switches_a_row_shows_are_those_its_recipe_trains(tmp_path: Path):
    for scale in DEFINITION.scales.values():  # every committed row, at every scale
        for number in scale.rows:
            row = DEFINITION.rows[number]
            if row.switches is not None:
                cfg = ablations.recipe(DEFINITION, scale, ablations.model_row(row), tmp_path)
                ablations.check_switches(DEFINITION, number, cfg)
    text = ablations.DEFINITION.read_text(encoding="utf-8")
    (tmp_path / "a.toml").write_text(
        text.replace('actinfo = "SepAct", data_aug = false', 'actinfo = "Embed", data_aug = false', 1)
    )
    definition = ablations.load_definition(tmp_path / "a.toml")
    cfg = ablations.recipe(definition, definition.scales["cpu"], 8, tmp_path)
    with pytest.raises(
        ConfigError,
        match=r"row 8: switches.actinfo: the table would show 'Embed', but the row's recipe trains 'SepAct'",
    ):
        ablations.check_switches(definition, 8, cfg)


def _figure_lines() -> list[dict]:
    """Lines as :func:`ablations.table` makes them for the figure: a dense cluster of ours (as the
    cpu scale's dx), the paper's spread, a row the paper gives no error for, ground truth and the
    action prior."""
    lines = []
    for k, row in enumerate(range(19)):
        ours = {"dx": 4.0 + 0.02 * k, "dz": 3.0 + 0.3 * (k % 4), "dyaw": 2.5 + 0.7 * k}
        success = float(2 * (k % 9))
        lines.append({
            "row": row, "setting": "robust VO", **ours, "S": success, "S_range": (max(0.0, success - 6), success + 9),
            "paper_S": 40.0 + 2 * k, "paper_errors": (2.4 - 0.07 * k, 1.8 - 0.05 * k, 1.6 - 0.05 * k),
        })  # fmt: skip
    lines[5]["paper_errors"] = ()  # a row the paper gives no per-component error for
    nan = float("nan")
    lines.append({"row": 20, "setting": "Ground truth", "dx": 0.0, "dz": 0.0, "dyaw": 0.0, "S": 98.0,
                  "S_range": (89.5, 99.6), "paper_S": 97.0, "paper_errors": ()})  # fmt: skip
    lines.append({"row": 21, "setting": "Action prior", "dx": 4.3, "dz": 3.0, "dyaw": 5.9, "S": 8.0,
                  "S_range": (3.2, 18.8), "paper_S": nan, "paper_errors": ()})  # fmt: skip
    return lines


def test_the_figure_has_a_panel_per_component_with_ours_and_the_papers_rows_on_one_x_range():
    import matplotlib.pyplot as plt

    lines = _figure_lines()
    fig = ablations.figure(lines)
    try:
        assert len(fig.axes) == len(ablations.COMPONENTS) == 3
        trained = [line for line in lines if line["setting"] not in ablations.REFERENCES]
        for k, (ax, c) in enumerate(zip(fig.axes, ablations.COMPONENTS)):
            assert c in ax.get_xlabel() and f"({ablations.UNITS[c]} x 1e-2)" in ax.get_xlabel()
            points = {col.get_gid(): {tuple(p) for p in col.get_offsets()} for col in ax.collections if col.get_gid()}
            ours, paper = points["ours"], points["paper"]
            assert ours == {(line[c], line["S"]) for line in trained}
            assert paper == {(line["paper_errors"][k], line["paper_S"]) for line in trained if line["paper_errors"]}
            low, high = ax.get_xlim()
            xs = [x for x, _ in ours | paper]
            assert low == 0.0 and max(xs) < high < 1.2 * max(xs)  # one range holds both, from 0
            assert ax.get_ylim() == fig.axes[0].get_ylim()  # one success axis
        assert fig.axes[0].get_ylabel() == "navigation success (%)"
        legend = [t.get_text() for t in fig.legends[0].get_texts()]
        assert any("ours" in t for t in legend) and any("the paper's Table 2" in t for t in legend)
    finally:
        plt.close(fig)
    assert ablations.unplotted_paper_rows(lines) == [5, 20]
    assert "no per-component error for rows 5, 20: left out of its points" in ablations.figure_caption(lines)


def test_the_figures_row_labels_cover_no_other_label_or_point():
    import matplotlib.pyplot as plt
    from matplotlib.text import Text
    from matplotlib.transforms import Bbox

    fig = ablations.figure(_figure_lines())
    try:
        renderer = fig.canvas.get_renderer()
        for ax in fig.axes:
            notes = [t for t in ax.texts if t.get_gid() == "row-label"]
            boxes = [Bbox.from_extents(*Text.get_window_extent(t, renderer).extents) for t in notes]  # no leader
            assert notes and "18" in {t.get_text() for t in notes}  # the reference row first
            for i, a in enumerate(boxes):
                assert not any(a.overlaps(b) for b in boxes[i + 1 :]), notes[i].get_text()
            points = [ax.transData.transform(p) for col in ax.collections if col.get_gid() for p in col.get_offsets()]
            for note, box in zip(notes, boxes):
                assert not any(box.contains(*p) for p in points), note.get_text()
                assert ax.get_window_extent(renderer).contains(box.x0, box.y0), note.get_text()
    finally:
        plt.close(fig)


@pytest.mark.slow
def test_the_committed_cpu_report_redraws_to_its_own_table(tmp_path: Path):
    """reports/ablations is redrawn from its saved results alone: every unit's key still matches
    (a recipe setting added since, at its default, leaves the keys as they were)."""
    committed = ablations.ROOT / "reports" / "ablations"
    copy = tmp_path / "ablations"
    shutil.copytree(committed / "results", copy / "results")
    shutil.copy(committed / "manifest.txt", copy / "manifest.txt")
    assert study("ablations", ["--scale", "cpu", "--out", str(copy), "--redraw", "--quiet"]) == 0
    assert (copy / "table.csv").read_text() == (committed / "table.csv").read_text()


def test_rows_computes_only_those_rows_and_reports_the_rest_as_missing(tmp_path: Path, capsys):
    """--rows: a long scale in chunks; the chosen rows' units are computed, the others read or missing."""
    out = tmp_path / "chunk"
    assert study("ablations", ["--scale", "ci", "--out", str(out), "--serial", "--quiet", "--rows", "21"]) == 0
    said = capsys.readouterr()
    assert "2 units computed (0 training, 1 error, 1 navigation)" in said.out and "no saved result" in said.err
    rows = {r["row"]: r for r in csv.DictReader((out / "table.csv").read_text().splitlines())}
    assert float(rows["21"]["dx"]) > 0 and rows["18"]["dx"] == "nan" and not (out / "models").exists()
    from odolab.cli import UsageError

    for bad, words in (
        ("19", "row 19 is not a row of --scale ci"),
        ("4,x", "expected row numbers"),
        ("1_8", "expected"),
    ):
        with pytest.raises(UsageError, match=words):
            study("ablations", ["--scale", "ci", "--out", str(out), "--rows", bad])
    with pytest.raises(UsageError, match="--redraw computes none"):
        study("ablations", ["--scale", "ci", "--out", str(out), "--rows", "21", "--redraw"])


def _training_unit(row: int, seed: int | None = None) -> framework.Unit:
    return framework.Unit(ablations.train_label(row, seed), {"row": row, "recipe": {"lr": row}, "train_seed": seed})


def _model_result(tmp_path: Path, row: int, present: bool = True) -> dict:
    """A saved training result of row ``row`` (as :func:`ablations.model_summary` gives it), its model
    file written under ``tmp_path`` when ``present``."""
    path = tmp_path / ablations.model_file(row)
    if present:
        path.parent.mkdir(parents=True)
        path.write_bytes(b"weights")
    sha = ablations._sha256(path) if present else "0" * 64
    return {"model": ablations.model_file(row), "sha256": sha, "parameters": 1, "networks": 1, "pairs_seen": 1,
            "training_hours": 0.1}  # fmt: skip


def test_drop_finished_states_removes_only_the_states_of_saved_models(tmp_path: Path, monkeypatch, capsys):
    saved, running, lost = _training_unit(4), _training_unit(18, 1), _training_unit(7)
    for u in (saved, running, lost):
        folder = ablations.work_folder(tmp_path, u.key)
        folder.mkdir(parents=True)
        (folder / "forward.pt").write_bytes(b"state")
    results = {saved.label: _model_result(tmp_path, 4), lost.label: _model_result(tmp_path, 7, present=False)}
    ablations.drop_finished_states([saved, running, lost], results, tmp_path)
    assert not ablations.work_folder(tmp_path, saved.key).parent.exists()  # its model's folder too, now empty
    assert (ablations.work_folder(tmp_path, running.key) / "forward.pt").is_file()  # no result yet: kept
    assert (ablations.work_folder(tmp_path, lost.key) / "forward.pt").is_file()  # its model being trained again

    def refuse(path, *args, **kwargs):
        raise PermissionError(1, "Operation not permitted", str(path))

    monkeypatch.setattr(ablations.shutil, "rmtree", refuse)
    ablations.drop_finished_states([saved], {saved.label: results[saved.label]}, tmp_path)  # no folder: nothing
    ablations.drop_finished_states([running], {running.label: _model_result(tmp_path, 18)}, tmp_path)  # one line
    out = capsys.readouterr().out
    assert out.count("\n") == 1 and "a finished model's training states, kept (Operation not permitted)" in out


def test_check_states_names_a_damaged_state_before_any_training(tmp_path: Path):
    from odolab.cli import UsageError

    unit = _training_unit(13)
    folder = ablations.work_folder(tmp_path, unit.key)
    folder.mkdir(parents=True)
    ablations.check_states([unit], tmp_path)  # no states yet: nothing to refuse
    (folder / "forward.pt").write_bytes(b"cut short")
    with pytest.raises(
        UsageError,
        match=r"forward\.pt: not a readable torch checkpoint .*; delete it to train "
        r"that stage of train row 13 again",
    ):
        ablations.check_states([unit], tmp_path)


def test_say_retrained_names_a_saved_model_whose_file_is_gone(tmp_path: Path, capsys):
    store = framework.ResultStore(tmp_path / "results")
    unit, fresh = _training_unit(4), _training_unit(7)
    value = {"model": "models/4/model.pt", "sha256": "0" * 64, "parameters": 1, "networks": 1, "pairs_seen": 1,
             "training_hours": 0.1}  # fmt: skip
    (tmp_path / "results").mkdir()
    store.put(unit, {"value": value, "seconds": 1.0})
    ablations.say_retrained([unit, fresh], store)
    assert capsys.readouterr().out == (
        "train row 4: models/4/model.pt is missing or not the model its saved results came from: trained again\n"
    )


@pytest.mark.slow
def test_rows_reads_the_other_rows_results_without_their_model_files(ci_run, tmp_path: Path, capsys):
    """A checkout holding the results but not every model (a new machine): --rows 21 computes nothing
    of the other rows and still reports them; the chosen rows' models are checked."""
    out, table = ci_run
    copy = tmp_path / "copy"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("models", "data"))
    assert study("ablations", ["--scale", "ci", "--out", str(copy), "--serial", "--quiet", "--rows", "21"]) == 0
    assert "0 units computed" in capsys.readouterr().out
    assert (copy / "table.csv").read_text() == table and not (copy / "models").exists()
    assert study("ablations", ["--scale", "ci", "--out", str(copy), "--serial", "--quiet", "--rows", "4"]) == 0
    said = capsys.readouterr().out
    assert "train row 4: models/4/model.pt is missing or not the model its saved results came from" in said
    assert "1 training" in said and (copy / ablations.model_file(4)).is_file()


def test_only_rows_of_a_row_running_another_rows_model_choose_that_models_training():
    """--rows 5 (row 4's model, ten dropout samples) trains row 4's model where it is missing, and
    evaluates row 5 alone."""
    definition = ablations.load_definition()
    only = ablations._only_rows("5", definition.scales["ci"], "ci", definition)
    assert only(framework.Unit("train row 4", {"row": 4, "recipe": {}}))
    assert only(framework.Unit("errors row 5 seed 0", {"row": 5, "odometer": "robust-vo"}))
    assert not only(framework.Unit("errors row 4 seed 0", {"row": 4, "odometer": "robust-vo"}))
    assert not only(framework.Unit("train row 18", {"row": 18, "recipe": {}}))


def test_valid_navigation_refuses_a_saved_result_out_of_its_ranges():
    ok = {"success": 1, "spl": 0.5, "soft_spl": 0.7, "d_g": 0.1, "steps": 40, "collisions": 0, "failed_steps": 0}
    assert ablations.valid_navigation(ok)
    for change in (
        {"d_g": -5.0},
        {"spl": 1.5},
        {"soft_spl": -0.1},
        {"success": 0},  # an SPL above 0 without success
        {"steps": -1},
        {"spl": float("nan")},
    ):
        assert not ablations.valid_navigation(ok | change), change


@pytest.mark.parametrize("unit", ["step_errors", "navigate_episode"])
def test_an_odometer_that_fails_every_step_is_refused_not_measured(unit: str, monkeypatch, tmp_path: Path):
    """A row whose odometer cannot run (every step raised or was refused: e.g. a model its code cannot
    read) would otherwise be saved with the action prior's numbers; the unit raises, naming the row."""
    monkeypatch.setattr(ablations, "_odometer", lambda key, out: ("tests.helpers:Never", {}))
    noise = {"rgb": 1.0, "depth": 1.0, "actuation": 0.5, "controller": "proportional"}
    key = {"row": 12, "seed": 0, "episodes": 1, "episode": 0, "max_steps": 4, "noise": noise, "policy": {}}
    with pytest.raises(ablations.BrokenOdometer, match="row 12: .* failed every one of its 4 steps"):
        getattr(ablations, unit)(key, out=tmp_path)
    monkeypatch.setattr(ablations, "_odometer", lambda key, out: ("action-prior", {}))
    assert getattr(ablations, unit)(key, out=tmp_path)["steps"] == 4  # one that runs is measured


def test_a_row_whose_odometer_fails_every_step_stops_the_run_with_one_line(tmp_path: Path, monkeypatch, capsys):
    """The command says which row could not run and why in one line (exit 2), saves nothing for it,
    and a rerun once the odometer runs computes the row."""
    from tests.helpers import refused

    out = tmp_path / "broken"
    argv = ["--scale", "ci", "--out", str(out), "--serial", "--quiet", "--rows", "21"]
    monkeypatch.setattr(ablations, "_odometer", lambda key, out: ("tests.helpers:Never", {}))
    line = refused(capsys, "ablations", argv)
    assert "row 21: tests.helpers:Never failed every one of its" in line and "nothing saved for it" in line, line
    assert "(first: 6 step(s) not-valid)" in line, line  # no exception: the runner's reason for the failures
    assert not list((out / "results").glob("*.json"))
    monkeypatch.undo()
    assert study("ablations", argv) == 0
    assert "2 units computed (0 training, 1 error, 1 navigation)" in capsys.readouterr().out
