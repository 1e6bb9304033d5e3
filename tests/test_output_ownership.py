"""No command deletes or writes outside the folder it owns, whatever links that folder holds, and
none overwrites a folder, a recipe, a state or data that odolab did not write (issue 42)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from odolab.cli import run_cli
from odolab.cli.study import command
from odolab.io.owned import UnsafeOutputError, check_owned_folder, check_owned_path, owned_path, remove_owned
from tests.helpers import robust_job


def _outside(tmp_path: Path) -> Path:
    """A folder beside the output folder, holding a file no run may touch."""
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "victim.tum").write_text("precious")
    return outside


def _one_line(capsys, *words: str) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    for w in words:
        assert w in err, (w, err)
    return err


def test_owned_paths_never_pass_a_link_a_file_for_a_folder_or_leave_the_root(tmp_path):
    outside = _outside(tmp_path)
    root = tmp_path / "out"
    root.mkdir()
    (root / "sub").symlink_to(outside)
    (root / "file").write_text("x")
    (root / "link.tum").symlink_to(outside / "victim.tum")
    for rel, expected, found in (
        ("sub/victim.tum", "expected a folder", "found a symbolic link to"),
        ("file/a.tum", "expected a folder", "found a file"),
        ("link.tum", "expected a regular file or nothing", "found a symbolic link to"),
    ):
        with pytest.raises(UnsafeOutputError, match=f"{expected}, {found}"):
            owned_path(root, rel)
        assert not remove_owned(root, rel)
    for rel in ("../outside/victim.tum", "a/../../outside/victim.tum", str(outside / "victim.tum"), ""):
        with pytest.raises(UnsafeOutputError):
            check_owned_path(root, rel)
    assert (outside / "victim.tum").read_text() == "precious" and sorted(p.name for p in outside.iterdir()) == [
        "victim.tum"
    ]
    assert owned_path(root, "new/deep/a.tum") == root / "new" / "deep" / "a.tum" and (root / "new" / "deep").is_dir()
    for rel, found in (("sub", "a symbolic link to"), ("file", "a file"), ("sub/x", "a symbolic link to")):
        with pytest.raises(UnsafeOutputError, match=f"expected a folder, found {found}"):
            check_owned_folder(root, rel)
    assert check_owned_folder(root, "new/deep") == root / "new" / "deep"
    with pytest.raises(UnsafeOutputError, match=r"found a path that cannot be read \(file name too long\)"):
        check_owned_path(root, "new/" + "x" * 300 + "/a.tum")  # an error line, not an OSError traceback


def test_a_rerun_removes_nothing_through_a_linked_folder_and_keeps_its_results(tmp_path):
    """A linked ``trajectories/<episode>`` and a crafted manifest line through a linked subfolder:
    nothing outside is deleted, the cleanup never raises, and the folder is refused by check()."""
    from odolab.reporting.report import MANIFEST, OutputFolder

    outside = _outside(tmp_path)
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


def _compare(argv) -> int:
    from odolab.compare import main

    return run_cli(main, "python -m odolab.compare", [str(a) for a in argv])


COMPARE = ["--odometers", "action-prior", "--episodes", "1", "--max-steps", "3", "--no-cache", "--serial", "--quiet"]


def test_compare_refuses_a_linked_or_misplaced_folder_before_any_work(tmp_path, capsys):
    outside = _outside(tmp_path)
    out = tmp_path / "run"
    (out / "trajectories").mkdir(parents=True)
    (out / "manifest.txt").write_text("trajectories/test-0000/victim.tum\n")
    (out / "trajectories" / "test-0000").symlink_to(outside, target_is_directory=True)
    assert _compare(COMPARE + ["--out", out]) == 2
    _one_line(capsys, "trajectories/test-0000", "expected a file or folder", "found a symbolic link to")
    assert (outside / "victim.tum").read_text() == "precious" and not (out / "table.csv").exists()
    (out / "trajectories" / "test-0000").unlink()
    (out / "trajectories").rmdir()
    (out / "trajectories").write_text("a file where compare keeps a folder")
    assert _compare(COMPARE + ["--out", out]) == 2
    _one_line(capsys, "trajectories", "expected a folder, found a file")
    assert not (out / "table.csv").exists()


def test_simcard_keeps_out_of_a_folder_it_did_not_write(tmp_path, capsys):
    from odolab.cli.simcard import main

    out = tmp_path / "mine"
    out.mkdir()
    (out / "card.md").write_text("my own notes")
    argv = ["--episodes", "1", "--rendered", "1", "--frames", "2", "--max-steps", "5", "--serial", "--quiet"]
    assert run_cli(main, "python -m odolab.simcard", argv + ["--out", str(out)]) == 2
    _one_line(capsys, "holds files odolab did not write")
    assert (out / "card.md").read_text() == "my own notes"
    linked = tmp_path / "linked"
    linked.mkdir()
    (linked / "manifest.txt").write_text("card.md\n")
    (linked / "card.md").symlink_to(_outside(tmp_path) / "victim.tum")
    assert run_cli(main, "python -m odolab.simcard", argv + ["--out", str(linked)]) == 2
    _one_line(capsys, "card.md", "found a symbolic link to")
    assert (tmp_path / "outside" / "victim.tum").read_text() == "precious"


def _navigate(argv) -> int:
    from odolab.navigate import main

    return run_cli(main, "python -m odolab.navigate", [str(a) for a in argv])


def test_navigate_writes_nothing_through_a_link_in_its_folder(tmp_path, capsys):
    """One rule for every file navigate writes: nav.md, config.json and a linked episodes folder
    are refused before any episode, as a linked episode file is."""
    args = ["--odometers", "ground-truth", "--episodes", "1", "--max-steps", "3", "--serial", "--quiet"]
    out = tmp_path / "nav"
    assert _navigate(args + ["--out", out]) == 0
    outside = _outside(tmp_path)
    for rel, target in (
        ("nav.md", outside / "victim.tum"),
        ("config.json", outside / "config.json"),
        ("episodes/ground-truth", outside / "episodes"),
    ):
        original = out / rel
        moved = tmp_path / "moved"
        original.rename(moved)
        if moved.is_dir():
            import shutil

            shutil.copytree(moved, target)
        elif rel == "config.json":
            target.write_text(moved.read_text())
        original.symlink_to(target)
        before = {p: p.read_bytes() for p in outside.rglob("*") if p.is_file()}
        assert _navigate(args + ["--out", out]) == 2, rel
        _one_line(capsys, rel, "found a symbolic link to")
        assert {p: p.read_bytes() for p in outside.rglob("*") if p.is_file()} == before, rel
        original.unlink()
        moved.rename(original)
    assert _navigate(args + ["--out", out]) == 0


def test_the_turns_study_keeps_out_of_a_folder_it_did_not_write(tmp_path, capsys):

    out = tmp_path / "t"
    out.mkdir()
    (out / "results.json").write_text(json.dumps({"my": "own results"}))
    (out / "table.md").write_text("my table")
    argv = ["--scale", "ci", "--serial", "--quiet", "--out", str(out)]
    assert command("turns-by-depth", argv) == 2
    _one_line(capsys, "holds files odolab did not write")
    assert (out / "table.md").read_text() == "my table"
    assert json.loads((out / "results.json").read_text()) == {"my": "own results"}
    assert sorted(p.name for p in out.iterdir()) == ["results.json", "table.md"]


# --- the trainers' --export ---------------------------------------------------------------------


def test_an_export_never_replaces_the_recipe_a_state_or_a_file_it_did_not_write(tmp_path):
    pytest.importorskip("torch")
    from odolab.cli import UsageError
    from odolab.learned.training import save_checkpoint

    recipe = tmp_path / "recipe.toml"
    with pytest.raises(
        UsageError, match="--export .*recipe.toml: expected a new file or a model odolab exported, found the recipe"
    ):
        robust_job(tmp_path, "--export", str(recipe))
    assert "[[stages]]" in recipe.read_text()
    with pytest.raises(UsageError, match="found the file where stage 'forward' keeps its training state"):
        robust_job(tmp_path, "--export", str(tmp_path / "work" / "forward.pt"))
    # a stage named "model": its state is where the model goes by default
    with pytest.raises(
        UsageError, match=r"stage 'model' keeps its training state.*default --export is <work>/model.pt"
    ):
        robust_job(tmp_path, stage="model")
    state = tmp_path / "elsewhere.pt"
    save_checkpoint(state, "odolab-training-state", 1, {"epoch": 1})
    data = tmp_path / "shard.npz"
    data.write_bytes(b"PK\x03\x04 not a model")
    for path, found in ((state, "found a training state"), (data, "found a file that is not an odolab model")):
        before = path.read_bytes()
        with pytest.raises(UsageError, match=found):
            robust_job(tmp_path, "--export", str(path))
        assert path.read_bytes() == before
    job = robust_job(tmp_path, "--export", str(tmp_path / "new.pt"))  # a new file is fine
    assert job.export == tmp_path / "new.pt"


def test_the_deepvo_export_never_replaces_its_training_state_and_saving_never_replaces_a_recipe(tmp_path):
    torch = pytest.importorskip("torch")
    from odolab.cli import UsageError
    from odolab.cli.train import parse_training_command, training_parser
    from odolab.learned.deepvo.config import load_training
    from odolab.learned.deepvo.train import state_files
    from odolab.learned.training import CheckpointError
    from odolab.learned.training.checkpoints import save_model

    recipe = tmp_path / "deepvo.toml"
    recipe.write_text("epochs = 1\n")
    ap = training_parser("python -m odolab.learned.deepvo.train", "train", "deepvo")
    with pytest.raises(UsageError, match="found the file where the DeepVO training keeps its training state"):
        parse_training_command(
            ap,
            [
                "--config",
                str(recipe),
                "--work",
                str(tmp_path / "work"),
                "--reports",
                str(tmp_path / "r"),
                "--export",
                str(tmp_path / "work" / "deepvo.pt"),
            ],
            load_training,
            state_files,
        )
    cfg = load_training(str(recipe))
    with pytest.raises(CheckpointError, match="found a file that is not an odolab model"):
        save_model(recipe, "odolab-deepvo", cfg, {"net": torch.nn.Linear(1, 1)}, {})
    assert recipe.read_text() == "epochs = 1\n"
    model = tmp_path / "m.pt"
    save_model(model, "odolab-deepvo", cfg, {"net": torch.nn.Linear(1, 1)}, {})
    save_model(model, "odolab-deepvo", cfg, {"net": torch.nn.Linear(1, 1)}, {})  # a model it exported: replaced


def test_a_training_keeps_its_work_out_of_other_runs_folders_but_may_keep_it_in_its_own_reports(tmp_path):
    """--work inside a study's folder, or a folder another command owns, is refused in one line; the
    states in the training's own --reports folder (the shipped-341 layout) are fine."""
    pytest.importorskip("torch")
    from odolab.cli import UsageError

    study = tmp_path / "study"
    study.mkdir()
    (study / "manifest.txt").write_text("# odolab study ablations\n")
    with pytest.raises(UsageError, match=r"--work .*: lies inside the report folder of study ablations"):
        robust_job(tmp_path, "--work", str(study / "states"))
    (tmp_path / "reports").mkdir()
    same = f"python -m odolab.learned.robust_vo.train --config {tmp_path / 'recipe.toml'}"  # this training's summary
    (tmp_path / "reports" / "training.json").write_text(json.dumps({"command": same, "stages": []}))
    job = robust_job(tmp_path, "--work", str(tmp_path / "reports" / "state"))  # its own reports
    assert job.work == tmp_path / "reports" / "state"
    with pytest.raises(UsageError, match=r"--work .*: is a comparison report folder"):
        compare = tmp_path / "compare"
        compare.mkdir()
        (compare / "manifest.txt").write_text("# odolab compare\n")
        robust_job(tmp_path, "--work", str(compare))


def test_a_training_report_folder_is_a_run_folder_for_nesting(tmp_path, capsys):
    """A compare --out inside a training's --reports folder is refused: the training owns it."""
    from odolab.cli.compare import main

    reports = tmp_path / "training"
    reports.mkdir()
    (reports / "training.json").write_text(
        json.dumps({"command": "python -m odolab.learned.robust_vo.train", "stages": []})
    )
    assert run_cli(main, "compare", ["--out", str(reports / "cmp"), "--episodes", "1"]) == 2
    assert "lies inside a training's report folder" in capsys.readouterr().err
    assert not (reports / "cmp").exists()


def test_dotdot_after_a_link_is_refused_before_anything_is_made(tmp_path):
    """``a/link/../z`` would be made beside the link's target, not in ``a``: refused in one line."""
    from odolab.cli import UsageError, check_output_dir, check_output_file

    (tmp_path / "far" / "target").mkdir(parents=True)
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "link").symlink_to(tmp_path / "far" / "target")
    odd = tmp_path / "a" / "link" / ".." / "z"
    with pytest.raises(UsageError, match=r"found '\.\.' after the link .*link, which leads to .*far.z"):
        check_output_dir(odd, "--out")
    with pytest.raises(UsageError, match=r"'\.\.' after the link"):
        check_output_file(odd / ".." / "f.json", "--json")
    assert not (tmp_path / "far" / "z").exists() and not (tmp_path / "a" / "z").exists()
    check_output_dir(tmp_path / "a" / ".." / "b", "--out")  # '..' after a real folder is fine
    assert (tmp_path / "b").is_dir()


def test_a_training_work_folder_of_other_files_is_refused_and_a_refusal_makes_no_folder(tmp_path):
    """--work holding a user's files is refused (its states would be written among them), and a run
    refused for its --reports or --export leaves no --work folder behind."""
    pytest.importorskip("torch")
    from odolab.cli import UsageError

    user = tmp_path / "user"
    user.mkdir()
    (user / "notes.txt").write_text("mine")
    with pytest.raises(
        UsageError, match=r"--work .*user: expected a new folder or one of training states .*'notes.txt'"
    ):
        robust_job(tmp_path, "--work", str(user))
    with pytest.raises(UsageError, match=r"--reports .*user: holds files odolab did not write"):
        robust_job(tmp_path, "--work", str(tmp_path / "w" / "deep"), "--reports", str(user))
    with pytest.raises(UsageError, match=r"--export .*: folder .*nodir does not exist"):
        robust_job(tmp_path, "--work", str(tmp_path / "w2"), "--export", str(tmp_path / "nodir" / "m.pt"))
    assert not (tmp_path / "w").exists() and not (tmp_path / "w2").exists() and not (tmp_path / "reports").exists()
    states = tmp_path / "states"
    states.mkdir()
    (states / "forward.pt").write_bytes(b"")  # a folder of states (and an atomic write's leftover) is fine
    (states / ".forward.pt.x.tmp").write_bytes(b"")
    assert robust_job(tmp_path, "--work", str(states)).work == states


def test_an_output_file_of_another_kind_is_never_replaced(tmp_path, capsys):
    """bench --json replaces only a bench JSON; the forward-dz probe's --out only its own report;
    both refuse before any work."""
    pytest.importorskip("torch")
    from odolab.cli.bench import main as bench_main

    summary = tmp_path / "training.json"
    summary.write_text(json.dumps({"command": "x", "stages": {}}))
    assert run_cli(bench_main, "bench", ["--only", "evaluate", "--json", str(summary)]) == 2
    assert "expected a new file or a bench JSON file" in _one_line(capsys)
    assert json.loads(summary.read_text()) == {"command": "x", "stages": {}}
    model = tmp_path / "model.pt"
    model.write_bytes(b"\x80weights")
    assert command("forward-dz-probe", ["--out", str(model)]) == 2
    assert "expected a new file or an earlier report of this probe" in _one_line(capsys)
    assert model.read_bytes() == b"\x80weights"
    assert command("forward-dz-probe", ["--out", "/dev/null"]) == 2
    assert "is not a regular file" in _one_line(capsys)
