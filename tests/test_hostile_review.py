"""Cases a fresh hostile review found after issue 42 (fast: nothing trains, nothing is computed)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from odolab.cli import UsageError, run_cli
from odolab.parallel import SERIAL
from tests.test_output_ownership import ROBUST_RECIPE

RECIPE = ROBUST_RECIPE.replace("{stage}", "forward")  # parsed only: no data is made


def _job(tmp_path: Path, *argv: str):
    pytest.importorskip("torch")
    from odolab.learning.cli import parse_training_command, training_parser
    from odolab.robust_vo.config import load_train_config

    recipe = tmp_path / "recipe.toml"
    recipe.write_text(RECIPE)
    ap = training_parser("python -m odolab.robust_vo.train", "train", "robust-vo")
    return parse_training_command(
        ap,
        ["--config", str(recipe), "--work", str(tmp_path / "work"), "--reports", str(tmp_path / "reports"), *argv],
        load_train_config,
    )


def test_workers_a_local_ray_instance_cannot_hold_are_refused_before_any_work(tmp_path, monkeypatch):
    """Ray Train waits forever for workers a fixed local instance lacks (8 workers on 2 CPUs, GPUs
    on a machine without any): refused in one line, before the work and reports folders exist."""
    torch = pytest.importorskip("torch")
    from odolab.learning.cli import check_workers

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    cpu = torch.device("cpu")
    two_cpus = lambda: (2.0, 0.0)
    with pytest.raises(UsageError, match="--workers 8: a local Ray instance here has 2 CPUs.*--workers 2 or fewer"):
        check_workers(8, 0.0, None, cpu, None, two_cpus)
    with pytest.raises(UsageError, match="needs 1 GPUs, this machine has 0"):
        check_workers(2, 0.5, None, cpu, None, two_cpus)
    with pytest.raises(UsageError, match="--device cpu contradicts --gpus-per-worker 1"):
        check_workers(2, 1.0, "cpu", cpu, None, two_cpus)
    with pytest.raises(UsageError, match="--gpus-per-worker places Ray Train workers"):
        check_workers(1, 1.0, None, cpu, None, two_cpus)
    check_workers(2, 0.0, "cpu", cpu, None, two_cpus)  # fits
    check_workers(2, 0.5, None, cpu, None, lambda: (2.0, 1.0))  # half a GPU each, one GPU
    check_workers(64, 1.0, None, cpu, "127.0.0.1:6379", two_cpus)  # a cluster may grow: not checked
    monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:6379")
    check_workers(64, 0.0, None, cpu, None, two_cpus)
    monkeypatch.delenv("RAY_ADDRESS")
    monkeypatch.setattr("odolab.learning.cli.local_ray_resources", two_cpus)
    with pytest.raises(UsageError, match="--workers 3: a local Ray instance"):
        _job(tmp_path, "--workers", "3")
    assert not (tmp_path / "work").exists() and not (tmp_path / "reports").exists()


def test_a_dead_ray_address_in_the_environment_is_one_line_not_a_hang(tmp_path, monkeypatch):
    """ray.init() connects to RAY_ADDRESS as to --ray-address: checked alike, and named."""
    monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:1")
    with pytest.raises(UsageError, match=r"RAY_ADDRESS \(environment\) 127.0.0.1:1: no Ray cluster there.*unset it"):
        _job(tmp_path)
    monkeypatch.setenv("RAY_ADDRESS", "not an address")
    with pytest.raises(UsageError, match="RAY_ADDRESS .*'not an address' is not an address"):
        _job(tmp_path)


def test_the_export_is_never_one_of_the_reports_the_run_writes(tmp_path, monkeypatch):
    """--export reports/training.json: found before training, not after it."""
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    for name in ("training.json", "curves.csv", "curves.png"):
        with pytest.raises(UsageError, match=f"found the path of {name} in --reports"):
            _job(tmp_path, "--export", str(tmp_path / "reports" / ".." / "reports" / name))
    assert _job(tmp_path, "--export", str(tmp_path / "reports" / "model.pt")).export.name == "model.pt"


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
    scale = noise.scale_of(framework.load_study("noise_robustness"), "ci")
    unit = noise.units(scale, {o: None for o in scale.odometers})[0]
    out = tmp_path / "n"
    (out / "results").mkdir(parents=True)
    (out / "manifest.txt").write_text("# odolab study noise_robustness\n")
    doc = {"label": unit.label, "key": unit.key, "result": {"value": _noise_row(), "seconds": 10**400}}
    (out / "results" / f"{unit.digest}.json").write_text(json.dumps(doc))
    argv = ["--scale", "ci", "--redraw", "--quiet", "--out", str(out)]
    assert run_cli(noise.main, noise.PROG, argv) == 0  # its seconds damaged: counted as none
    big = json.dumps(doc).replace('"dx": 1.0', '"dx": 1' + "0" * 400, 1)
    for text in (big, '{"a":' * 100_000):
        (out / "results" / f"{unit.digest}.json").write_text(text)
        capsys.readouterr()
        assert run_cli(noise.main, noise.PROG, argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err and "no saved results in" in err, err


def test_the_turns_study_keeps_results_of_other_options_and_damage_apart(tmp_path):
    """Options are part of a unit's key: turns computed with other options are never taken for
    these; a saved scene with a damaged turn is not a result."""
    import studies.turns_by_depth as turns
    from studies import framework

    assert turns.row_ok([1.5, True, 0.3]) and not turns.row_ok([10**400, True, 0.3])
    assert not turns.row_ok([1.5, True, 10**400]) and not turns.row_ok([1.5, False, 0.3])
    scale = turns.Scale("val", 7, 2, 2, ("icp",), {})
    other = turns.Scale("val", 7, 2, 2, ("icp",), {"icp": {"max_iter": 3}})
    store = framework.ResultStore(tmp_path)
    [first, _] = turns.units(other, {"icp": "a"})
    store.put(first, {"value": [[1.0, True, 0.5]] * 2, "seconds": 1.0})
    mine = turns.units(scale, {"icp": "a"})[0]
    assert mine.label == first.label and store.get(mine) is None  # same odometer and scene, other options
    assert turns.valid_result([[1.0, True, 0.5]] * 2, per_scene=2)
    assert not turns.valid_result([[1.0, True, 0.5], [10**400, True, 0.5]], per_scene=2)
    assert not turns.valid_result([[1.0, True, 0.5]] * 3, per_scene=2)


def test_a_manifest_naming_a_users_file_never_deletes_it(tmp_path):
    from odolab.report import ManifestError, OutputFolder

    (tmp_path / "thesis.docx").write_text("years of work")
    (tmp_path / "table.csv").write_text("old")
    (tmp_path / "manifest.txt").write_text("thesis.docx\ntable.csv\n")
    with pytest.raises(ManifestError, match="thesis.docx"):
        OutputFolder.check(tmp_path)
    folder = OutputFolder(tmp_path)  # even called without the check, the cleanup removes only compare's names
    assert (tmp_path / "thesis.docx").read_text() == "years of work"
    assert not (tmp_path / "table.csv").exists() and folder.not_removed == ["thesis.docx"]


def test_one_command_never_takes_over_anothers_folder(tmp_path):
    from odolab.report import ManifestError, OutputFolder
    from odolab.simcard import CARD_NAMES

    folder = OutputFolder(tmp_path)
    folder.path("table.csv").write_text("compare's results")
    folder.finish()
    assert (tmp_path / "manifest.txt").read_text().splitlines()[0] == "# odolab compare"
    with pytest.raises(ManifestError, match="odolab compare"):
        OutputFolder.check(tmp_path, owner="simcard", names=CARD_NAMES)
    OutputFolder.check(tmp_path)  # compare itself may write there again
    assert (tmp_path / "table.csv").read_text() == "compare's results"


def test_a_class_that_is_not_an_odometer_is_refused_at_load(tmp_path):
    from odolab.odometer import IncompleteOdometerError, load_odometer

    source = tmp_path / "notodo.py"
    source.write_text("class NotOdo:\n    def step(self, prev, cur, action):\n        return None\n")
    with pytest.raises(IncompleteOdometerError, match="not an Odometer"):
        load_odometer(f"{source}:NotOdo")


def test_evaluate_refuses_a_device_at_once(tmp_path):
    from odolab.evaluate import main

    (tmp_path / "zero.tum").symlink_to("/dev/zero")
    assert run_cli(main, "python -m odolab.evaluate", [str(tmp_path / "zero.tum"), str(tmp_path / "zero.tum")]) == 2


def test_one_trainer_never_replaces_anothers_model(tmp_path):
    torch = pytest.importorskip("torch")
    import dataclasses

    from odolab.learning.checkpoints import CheckpointError, check_export, save_model

    @dataclasses.dataclass
    class R:
        model: dict = dataclasses.field(default_factory=dict)

    model = tmp_path / "model.pt"
    save_model(model, "odolab-robust-vo", R(), {"net": torch.nn.Linear(2, 2)}, {})
    with pytest.raises(ValueError, match="another trainer's"):
        check_export(model, tmp_path / "r.toml", {}, kind="odolab-deepvo")
    with pytest.raises(CheckpointError, match="another trainer's"):
        save_model(model, "odolab-deepvo", R(), {"net": torch.nn.Linear(2, 2)}, {})
    check_export(model, tmp_path / "r.toml", {}, kind="odolab-robust-vo")  # its own trainer may
    save_model(model, "odolab-robust-vo", R(), {"net": torch.nn.Linear(2, 2)}, {})


def test_an_unreadable_manifest_is_refused_not_ignored(tmp_path):
    from odolab.report import ManifestError, OutputFolder

    (tmp_path / "manifest.txt").write_bytes(b"table.csv\n\xff\xfe garbage\n")
    with pytest.raises(ManifestError, match="cannot be read"):
        OutputFolder.check(tmp_path)


@pytest.mark.parametrize(
    "pinhole, words", [((525.0, 525.0, 1e9, 1e9), "principal point"), ((1e-9, 1e-9, 0.0, 0.0), "implausible")]
)
def test_implausible_tum_intrinsics_are_refused(pinhole, words):
    from odolab.io.tum_rgbd import load_tum_sequence

    folder = Path(__file__).parent / "data" / "tum_fr1_xyz_10"
    with pytest.raises(ValueError, match=words):
        load_tum_sequence(folder, intrinsics=pinhole)


def test_an_option_is_named_once_in_its_error():
    from odolab.cli import ArgumentParser, pinhole

    ap = ArgumentParser(prog="x")
    ap.add_argument("--intrinsics", type=pinhole("--intrinsics"))
    with pytest.raises(UsageError) as err:
        ap.parse_args(["--intrinsics", "0,1,2,3"])
    assert str(err.value).count("--intrinsics") == 1


def test_an_export_mistake_leaves_no_folders_behind(tmp_path):
    with pytest.raises(UsageError, match="found the recipe"):
        _job(tmp_path, "--export", str(tmp_path / "recipe.toml"))
    assert not (tmp_path / "work").exists() and not (tmp_path / "reports").exists()


def test_a_dangling_output_folder_is_named_as_a_link(tmp_path):
    from odolab.cli import check_output_dir

    (tmp_path / "out").symlink_to(tmp_path / "nowhere")
    with pytest.raises(UsageError, match="link to nothing"):
        check_output_dir(tmp_path / "out", "--out")


def test_a_negative_delta_is_told_to_be_positive(tmp_path, capsys):
    from odolab.evaluate import main

    path = tmp_path / "a.tum"
    path.write_text("0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n2 2 0 0 0 0 0 1\n")
    assert run_cli(main, "python -m odolab.evaluate", [str(path), str(path), "--delta", "-1"]) == 2
    assert "--delta must be positive" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [["--samples", "-1"], ["--samples", str(2**63)], ["--seconds", "nan"]])
def test_the_derotation_probe_bounds_its_options_before_work(argv, capsys):
    from studies.robust_vo.derotation_probe import main

    assert run_cli(main, "python -m studies.robust_vo.derotation_probe", argv) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_trainers_and_training_data_refuse_a_folder_of_the_users_files(tmp_path):
    from odolab.cli.training_data import main as make_data

    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "curves.csv").write_text("my own numbers")
    with pytest.raises(UsageError, match="did not write"):
        _job(tmp_path, "--reports", str(mine))
    assert run_cli(make_data, "python -m odolab.training_data", ["--episodes", "1", "--out", str(mine)]) == 2
    assert (mine / "curves.csv").read_text() == "my own numbers" and sorted(p.name for p in mine.iterdir()) == [
        "curves.csv"
    ]


def test_a_meaningless_manifest_line_is_named(tmp_path):
    from odolab.report import ManifestError, OutputFolder

    (tmp_path / "table.csv").write_text("old")
    (tmp_path / "manifest.txt").write_text("table.csv/x\n")
    with pytest.raises(ManifestError, match="lists 'table.csv/x'"):
        OutputFolder.check(tmp_path)


def test_an_export_that_is_a_dangling_link_is_named_as_one(tmp_path):
    from odolab.learning.checkpoints import check_export

    (tmp_path / "model.pt").symlink_to(tmp_path / "nowhere.pt")
    with pytest.raises(ValueError, match="link to nothing"):
        check_export(tmp_path / "model.pt", tmp_path / "r.toml", {})


def test_an_output_file_that_is_a_link_to_nothing_is_refused_before_work(tmp_path, capsys):
    """``action_prior --out dead`` (dead -> /somewhere/new) wrote a file wherever the link pointed."""
    from odolab.cli.action_prior import main

    dead = tmp_path / "dead.json"
    dead.symlink_to(tmp_path / "elsewhere" / "created.json")
    argv = ["--episodes", "1", "--max-steps", "5", "--out", str(dead)]
    assert run_cli(main, "python -m odolab.action_prior", argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "is a link to nothing" in err and "--out" in err
    assert not (tmp_path / "elsewhere").exists()


def test_navigation_diff_given_a_file_names_the_folder_it_expects(tmp_path, capsys):
    from odolab.cli.navigation_diff import main

    (tmp_path / "episodes.csv").write_text("odometer\n")
    argv = [str(tmp_path / "episodes.csv"), str(tmp_path)]
    assert run_cli(main, "python -m odolab.navigation.diff", argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"before {tmp_path}/episodes.csv: is a file" in err
    assert f"({tmp_path})" in err


def test_calibrate_fusion_out_naming_a_folder_says_so(tmp_path, capsys):
    from odolab.cli.calibrate_fusion import main

    argv = ["--episodes", "1", "--max-steps", "100", "--out", str(tmp_path), "--serial"]
    assert run_cli(main, "python -m odolab.fusion.calibrate", argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"--out {tmp_path}: is a folder, not a file" in err


def test_a_study_checks_ray_address_and_redraw_before_making_its_folder(tmp_path, capsys):
    """A dead --ray-address was a traceback after --out was made; with --serial it was ignored; --redraw
    on a new folder made it, empty."""
    from studies.e_table import main

    out = tmp_path / "e"
    for argv, words in [
        (["--ray-address", "127.0.0.1:1"], "--ray-address 127.0.0.1:1: no Ray cluster there"),
        (["--ray-address", "127.0.0.1:1", "--serial"], "exclude each other"),
        (["--redraw"], "--redraw: no saved results in"),
    ]:
        assert run_cli(main, "python -m studies.e_table", ["--scale", "ci", "--out", str(out), *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and words in err, err
        assert not out.exists()


def test_a_study_names_another_commands_folder_once(tmp_path, capsys):
    from studies.e_table import main

    (tmp_path / "manifest.txt").write_text("# odolab compare\ntable.csv\n")
    (tmp_path / "table.csv").write_text("x")
    assert run_cli(main, "python -m studies.e_table", ["--scale", "ci", "--out", str(tmp_path), "--redraw"]) == 2
    err = capsys.readouterr().err.strip()
    assert "holds the results of odolab compare" in err and err.count(str(tmp_path)) == 1, err


def test_a_saved_study_result_of_the_wrong_shape_is_computed_again(tmp_path):
    from studies import e_table, framework

    store = framework.ResultStore(tmp_path)
    unit = framework.Unit("u", {"k": 2})
    store.put(unit, {"value": {"all": "oops"}, "seconds": 1.0})  # a results file edited by hand
    calls = []

    def fn(key):
        calls.append(key)
        return {"all": {c: 1.0 for c in ("dx", "dz", "dyaw", "dx_own", "dz_own", "dyaw_own", "failure_share")}}

    def shaped(value):
        return e_table.valid_result({"all": {**value["all"], "steps": 3}})

    redrawn = framework.run_units(fn, [unit], store, redraw=True, execution=SERIAL, valid=shaped)
    assert redrawn.missing == ["u"] and not calls
    again = framework.run_units(fn, [unit], store, execution=SERIAL, valid=shaped)
    assert again.computed == ["u"] and calls == [{"k": 2}]
    assert not e_table.valid_result({"all": {"dx": 1.0}}) and not e_table.valid_result([1])


_CURVES_HEAD = "epoch,split,stage,pairs,pairs_per_s,action,component,mae,prior_mae\n"


@pytest.mark.parametrize(
    ("curves", "words"),
    [
        ("", "expected a training curves file"),  # an empty file
        (b"\xff\xfe\x00", "not a text file"),
        (_CURVES_HEAD + "1,train,forward,100,10,,,,\n", "no validation rows"),
        (_CURVES_HEAD + "1,train,forward,100,nan,,,,\n1,val,forward,,,move_forward,dz,0.1,0.2\n", "row 2"),
        (_CURVES_HEAD + "1,train,forward,100,10,,,,\n1,val,forward,,,move_forward,dz,inf,0.2\n", "row 3"),
    ],
)
def test_scaling_refuses_unusable_curves_in_one_line_and_makes_nothing(tmp_path, capsys, curves, words):
    """These were tracebacks (ValueError, UnicodeDecodeError) after --out was made, or an empty plot."""
    from studies.robust_vo.scaling import main

    run = tmp_path / "run"
    run.mkdir()
    getattr(run / "curves.csv", "write_bytes" if isinstance(curves, bytes) else "write_text")(curves)
    (tmp_path / "t.csv").write_text("odometer,action,dx,dz,dyaw\nicp,move_forward,1,1,1\n")
    argv = ["--runs", str(run), "--classical", str(tmp_path / "t.csv"), "--out", str(tmp_path / "out")]
    assert run_cli(main, "python -m studies.robust_vo.scaling", argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("python -m studies.robust_vo.scaling: error: --runs: ")
    assert words in err and not (tmp_path / "out").exists()


def test_scaling_names_a_bad_classical_table_and_keeps_same_named_runs_apart(tmp_path, capsys):
    from studies.robust_vo.scaling import main

    curves = _CURVES_HEAD + "1,train,forward,100,10,,,,\n1,val,forward,,,move_forward,dz,0.1,0.2\n"
    for parent in ("a", "b"):
        (tmp_path / parent / "run").mkdir(parents=True)
        (tmp_path / parent / "run" / "curves.csv").write_text(curves)
    table = tmp_path / "t.csv"
    table.write_text("odometer,action,dx,dz,dyaw\nicp,move_forward,x,1,1\n")
    runs = ["--runs", str(tmp_path / "a" / "run"), str(tmp_path / "b" / "run" / "curves.csv")]
    out = ["--out", str(tmp_path / "out")]
    assert run_cli(main, "scaling", [*runs, "--classical", str(table), *out]) == 2
    err = capsys.readouterr().err
    assert f"--classical: {table}: row 2: dx: expected a number" in err and len(err.strip().splitlines()) == 1
    assert run_cli(main, "scaling", [*runs[:2], runs[1] + "/", "--classical", str(table), *out]) == 2
    assert "given twice" in capsys.readouterr().err
    table.write_text("odometer,action,dx,dz,dyaw\nicp,move_forward,1,1,1\n")
    assert run_cli(main, "scaling", [*runs, "--classical", str(table), *out]) == 0
    labels = {line.split(",")[0] for line in (tmp_path / "out" / "scaling.csv").read_text().splitlines()[1:]}
    assert labels == {str(tmp_path / "a" / "run"), str(tmp_path / "b" / "run")}


def test_the_odolab_command_help_version_and_near_names(capsys):
    from odolab.cli.commands import main

    assert main([]) == 2  # a usage error: the list goes to stderr, not into a pipe's data
    got = capsys.readouterr()
    assert not got.out and "commands:" in got.err
    with pytest.raises(SystemExit) as exit_:
        main(["help", "evaluate"])  # = odolab evaluate --help, not the general list
    assert exit_.value.code == 0 and "ground-truth trajectory file" in capsys.readouterr().out
    assert main(["--version"]) == 0 and capsys.readouterr().out.startswith("odolab ")
    assert main(["navigation_diff"]) == 2
    assert "did you mean 'navigation-diff'?" in capsys.readouterr().err


def test_a_reader_that_goes_away_is_no_traceback(capsys):
    """``odolab help | head -1`` ended in a BrokenPipeError traceback."""

    def main(argv):
        raise BrokenPipeError(32, "Broken pipe")

    assert run_cli(main, "python -m odolab.evaluate", []) == 141
    assert capsys.readouterr().err == ""


def test_compare_tum_that_is_not_a_folder_is_said_so_before_the_camera(tmp_path, capsys):
    """A file, a missing path or a dead link given to --tum read 'cannot tell the camera from the
    folder's name', or 'no such folder' for a file."""
    from odolab.cli.compare import main

    (tmp_path / "rgbd_fr1.txt").write_text("x")
    (tmp_path / "dead_fr1").symlink_to(tmp_path / "nowhere")
    for name, words in [
        ("rgbd_fr1.txt", "is a file, not a folder"),
        ("missing", "no such folder"),
        ("dead_fr1", "is a link to nothing"),
    ]:
        argv = ["--tum", str(tmp_path / name), "--out", str(tmp_path / "out")]
        assert run_cli(main, "python -m odolab.compare", argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and f"--tum {tmp_path / name}: {words}" in err, err


@pytest.mark.parametrize("command", ["compare", "navigate"])
def test_an_unusable_options_file_is_named_under_config(tmp_path, capsys, command):
    """'--config DIR' read '/x: is a folder; ...' without the option's name."""
    import importlib

    main = importlib.import_module(f"odolab.cli.{command}").main
    (tmp_path / "bad.toml").write_text("[odometers.icp\n")
    for path, words in [(tmp_path, "is a folder"), (tmp_path / "none.toml", "no such"), (tmp_path / "bad.toml", "")]:
        argv = ["--config", str(path), "--episodes", "1", "--max-steps", "5", "--out", str(tmp_path / "out")]
        assert run_cli(main, f"python -m odolab.{command}", argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and f"error: --config {path}" in err and words in err, err


def test_a_study_stopped_before_its_report_resumes_instead_of_refusing_its_folder(tmp_path, monkeypatch, capsys):
    """Killed after some units, before its report: the rerun read 'holds files odolab did not
    write (no manifest.txt)' and could neither resume nor redraw."""
    from studies import e_table, framework

    out = tmp_path / "e"
    config = framework.load_study("e_table")

    def stopped(fn, units, store, **kw):
        store.put(units[0], {"value": {"all": {}}, "seconds": 0.0})  # one unit saved, then Ctrl-C
        raise KeyboardInterrupt

    monkeypatch.setattr(framework, "run_units", stopped)
    argv = ["--scale", "ci", "--out", str(out), "--serial", "--quiet"]
    assert run_cli(e_table.main, "python -m studies.e_table", argv) == 130
    assert (out / "manifest.txt").read_text() == "# odolab study e_table\n"
    framework.check_out(out, config)  # the rerun may use its folder
    (out / "manifest.txt").unlink()  # a folder left by a run from before the manifest came first
    framework.check_out(out, config)
    assert (out / "manifest.txt").is_file() and len(list((out / "results").iterdir())) == 1


@pytest.mark.parametrize("text", ["1_0", "\uff15", "1\u0660"])
def test_numbers_are_plain_ascii_digits(text):
    """'--rgb-noise 1_0' ran at ten times the noise, '--episodes ５' (a full-width 5) as 5."""
    import argparse

    from odolab.cli import number

    with pytest.raises(argparse.ArgumentTypeError, match="must be a number"):
        number("--rgb-noise", float, 0, 10)(text)
    assert number("--rgb-noise", float, 0, 10)(" 2.5e0 ") == 2.5 and number("--episodes", int, 1)("+3") == 3


def test_an_init_that_is_a_dead_link_or_absolute_is_named_as_such(tmp_path):
    from odolab.learning.checkpoints import load_init

    def never(path):
        raise AssertionError("not to be loaded")

    dead = tmp_path / "model.pt"
    dead.symlink_to(tmp_path / "gone.pt")
    with pytest.raises(ValueError, match=r"is a link to nothing"):
        load_init(str(dead), tmp_path / "export.pt", never)
    with pytest.raises(ValueError) as caught:
        load_init(str(tmp_path / "none.pt"), tmp_path / "export.pt", never)
    assert "no such model file;" in str(caught.value) and "relative to" not in str(caught.value)
    with pytest.raises(ValueError, match=r"relative to"):
        load_init("no/such/model.pt", tmp_path / "export.pt", never)


def test_set_changes_the_recipe_and_its_mistakes_are_one_line(tmp_path):
    job = _job(tmp_path, "--set", "seed=7", "--set", "stages.forward.lr=0.0005", "--set", "model.groups=4")
    assert job.config.seed == 7 and job.config.stages[0].lr == 0.0005 and job.config.model.groups == 4
    assert "--set seed=7" in job.command  # the record says how the run differs from its recipe
    for bad, said in (
        ("seed", "--set 'seed': expected path=value"),
        ("model.width.x=1", "--set 'model.width.x=1': model.width is a value, not a table"),
        ("seed.x=1", "seed: expected an integer"),  # a default, not in the file: the recipe's check refuses it
        ("stages.9.lr=1", "--set 'stages.9.lr=1': stages.9: the list has 1 entries (0 to 0)"),
        ("stages.turns.lr=1", "no entry named 'turns'; give a position from 0 or one of forward"),
        ("stages=1", "stages"),  # the whole list replaced by a number: the recipe's check refuses it
        ("seed=abc", "--set 'seed=abc': seed: expected an integer, got 'abc'"),  # the change, not the file
        ("train_data.noise.rgb=-1", "--set 'train_data.noise.rgb=-1': train_data.noise: noise: rgb must be in [0, 10]"),
        ("train_data.noise.controller=nosuch", "noise.controller: expected one of 'ilqr', 'proportional', 'movebase'"),
        ("data_root=", "--set 'data_root=': recipe: data_root must name a folder, got ''"),
    ):
        with pytest.raises(UsageError) as info:
            _job(tmp_path, "--set", bad)
        assert said in str(info.value), str(info.value)
        assert "\n" not in str(info.value)
    with pytest.raises(UsageError, match="unknown field"):
        _job(tmp_path, "--set", "model.widht=341")


def test_a_link_to_nothing_is_named_as_one(tmp_path, capsys):
    from odolab.cli.evaluate import main as evaluate
    from odolab.io.inputs import check_regular_file

    dead = tmp_path / "est.txt"
    dead.symlink_to(tmp_path / "gone.txt")
    assert run_cli(evaluate, "python -m odolab.evaluate", [str(dead), str(dead)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith(f"{dead}: is a link to nothing ({tmp_path / 'gone.txt'} does not exist)"), err
    with pytest.raises(ValueError, match="is a link to nothing"):
        check_regular_file(dead)
    with pytest.raises(ValueError, match="no such file"):
        check_regular_file(tmp_path / "never.txt")


def test_a_trainer_refuses_the_reports_of_another_training(tmp_path):
    reports = tmp_path / "reports"
    reports.mkdir()
    (reports / "training.json").write_text(
        json.dumps({"command": "python -m baselines.deepvo.train --config studies/deepvo/shipped.toml"})
    )
    with pytest.raises(UsageError, match=r"--reports .*reports: .*training.json is the summary of another training"):
        _job(tmp_path)
    assert not (tmp_path / "work").exists()  # refused before anything was made
    (reports / "training.json").write_text(
        json.dumps({"command": f"python -m odolab.robust_vo.train --config {tmp_path / 'recipe.toml'} --quiet"})
    )
    assert _job(tmp_path, "--set", f"data_root={tmp_path / 'd'}").reports == reports  # the same recipe, elsewhere


def test_sigterm_ends_a_command_after_its_clean_up(tmp_path):
    """SIGTERM (what `kill` and job schedulers send) ends a command like Ctrl-C, exit 143 after its
    `with` blocks ran: the training bench's temporary data folder is removed, not left in the
    system's temporary folder."""
    import os
    import signal
    import subprocess
    import sys
    import time

    recipe = tmp_path / "tiny.toml"
    recipe.write_text(
        'base = "' + str(Path("studies/robust_vo/shipped.toml").resolve()) + '"\n'
        "[model]\nwidth = 48\nheight = 32\n[train_data]\nwidth = 48\nheight = 32\n"
        "[val_data]\nwidth = 48\nheight = 32\nmax_steps = 400\n"
    )
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = {**os.environ, "TMPDIR": str(tmp)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "odolab.bench", "--only", "training", "--recipe", str(recipe)],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 120
    while not list(tmp.glob("odolab-bench-*")) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert list(tmp.glob("odolab-bench-*")), "the bench never made its temporary folder"
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    assert "python -m odolab.bench: terminated" in err
    assert not list(tmp.glob("odolab-bench-*"))


def test_starting_ray_keeps_the_commands_signal_handlers(monkeypatch):
    """ray.init() puts in a SIGTERM handler of its own that exits at once; start_ray puts the
    command's back, so SIGTERM still ends a command that fans out on Ray after its clean-up (143)."""
    import signal

    import ray

    from odolab.parallel import start_ray

    monkeypatch.delenv("RAY_ADDRESS", raising=False)

    def mine(signum, frame):  # pragma: no cover - never called
        raise AssertionError

    previous = signal.signal(signal.SIGTERM, mine)
    try:
        started = start_ray(None, quiet=True)
        try:
            assert started, "Ray was already running in the test process"
            assert signal.getsignal(signal.SIGTERM) is mine
        finally:
            if started:
                ray.shutdown()
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_sigterm_is_reported_as_such_when_a_library_re_raises_it_as_ctrl_c(capsys):
    """Ray turns any exception raised by a signal handler during ray.get/ray.wait into a bare
    KeyboardInterrupt; run_cli still knows SIGTERM came and answers 143, "terminated"."""
    import os
    import signal
    import time

    from odolab.cli import run_cli

    def main(argv):
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(10)  # the handler raises in here
        except KeyboardInterrupt:
            raise KeyboardInterrupt() from None  # what Ray's check_signals does with it

    assert run_cli(main, "prog", []) == 143
    assert "prog: terminated" in capsys.readouterr().err
    assert run_cli(lambda argv: (_ for _ in ()).throw(KeyboardInterrupt()), "prog", []) == 130


def test_a_sigterm_while_ray_starts_reaches_the_commands_handler(monkeypatch):
    """ray.init() puts its own SIGTERM handler (exit 15) in place first thing; a SIGTERM that lands
    before it returns is handed to the command's handler, and what Ray started is shut down."""
    import os
    import signal
    import sys
    import time

    import ray

    from odolab.parallel import start_ray

    class Mine(Exception):
        pass

    def mine(signum, frame):
        raise Mine()

    def init(**kwargs):  # what ray.init does with SIGTERM, then a SIGTERM half-way
        signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(signum))
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(10)

    shut = []
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.setattr(ray, "init", init)
    monkeypatch.setattr(ray, "shutdown", lambda: shut.append(True))
    previous = signal.signal(signal.SIGTERM, mine)
    try:
        with pytest.raises(Mine):
            start_ray(None, quiet=True)
        assert signal.getsignal(signal.SIGTERM) is mine
        assert shut == [True]
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_an_address_where_no_ray_cluster_answers_is_one_line_at_once():
    """A web server at --ray-address takes the connection but is no Ray cluster: refused within
    seconds (Ray itself retries for minutes), naming the address."""
    import http.server
    import threading

    from odolab.parallel import RayAddressError, check_ray_address

    server = http.server.HTTPServer(("127.0.0.1", 0), http.server.BaseHTTPRequestHandler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        address = f"127.0.0.1:{server.server_address[1]}"
        with pytest.raises(RayAddressError, match=f"--ray-address {address}: something answers there, but not as a"):
            check_ray_address(address)
    finally:
        server.shutdown()
        server.server_close()


@pytest.mark.parametrize(("signum", "code", "word"), [("SIGINT", 130, "interrupted"), ("SIGTERM", 143, "terminated")])
@pytest.mark.parametrize("then", ["returns", "fails"])
def test_a_signal_that_a_library_swallowed_still_ends_the_command(capsys, signum, code, word, then):
    """Open3D's import swallows a Ctrl-C that lands while it loads; the command then runs on, but
    its exit code and last line still say it was stopped (a hostile review found exit 0)."""
    import os
    import signal
    import time

    swallowed = []

    def main(argv):
        try:
            os.kill(os.getpid(), getattr(signal, signum))
            time.sleep(1)
        except KeyboardInterrupt as exc:  # swallowed, as a library's import does
            swallowed.append(exc)
        if then == "fails":
            raise RuntimeError("what the swallowed signal left broken")
        return 0

    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    assert run_cli(main, "prog", []) == code
    assert len(swallowed) == 1  # the signal reached the library, which went on
    assert capsys.readouterr().err == f"prog: {word}\n"
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before
