"""What a hostile review of the studies' command lines found: every study shares these checks
(studies/framework.py); studies.e_table stands for them."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from odolab.cli import run_cli

PROG = "python -m studies.e_table"
CI = ["--scale", "ci", "--serial", "--quiet"]


@pytest.fixture(scope="module")
def ci_run(tmp_path_factory) -> Path:
    """One finished ci run of studies.e_table (copied by the tests that change it)."""
    from studies.e_table import main

    out = tmp_path_factory.mktemp("e") / "run"
    assert main([*CI, "--out", str(out)]) == 0
    return out


def _run(argv: list[str], capsys) -> tuple[int, str]:
    from studies.e_table import main

    rc = run_cli(main, PROG, argv)
    return rc, capsys.readouterr().err.strip()


def test_ray_address_auto_without_a_cluster_is_one_line_before_any_folder(tmp_path, monkeypatch, capsys):
    from ray._private import services

    def none_found(addr, temp_dir):
        raise ConnectionError("Could not find any running Ray instance.")

    monkeypatch.setattr(services, "get_ray_address_from_environment", none_found)
    out = tmp_path / "e"
    rc, err = _run(["--scale", "ci", "--quiet", "--ray-address", "auto", "--out", str(out)], capsys)
    assert rc == 2 and err.splitlines() == [
        f"{PROG}: error: --ray-address auto: no running Ray cluster found on this machine; start one (ray start --head) or give host:port"
    ]
    assert not out.exists()


def test_a_users_own_reports_index_is_left_alone(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    page = tmp_path / "reports" / "index.html"
    page.parent.mkdir()
    page.write_text("<html>MY OWN PAGE</html>")
    rc, err = _run([*CI, "--out", "reports/e"], capsys)
    assert rc == 0 and page.read_text() == "<html>MY OWN PAGE</html>"
    assert "reports/index.html not refreshed" in err and (tmp_path / "reports" / "e" / "index.html").is_file()


def test_a_users_folder_of_json_files_is_not_taken_for_a_stopped_study(tmp_path, capsys):
    out = tmp_path / "mine"
    (out / "results").mkdir(parents=True)
    (out / "results" / "exp1.json").write_text('{"my": "experiment"}')
    rc, err = _run([*CI, "--out", str(out)], capsys)
    assert rc == 2 and "holds files odolab did not write" in err
    assert sorted(p.name for p in out.rglob("*")) == ["exp1.json", "results"]


def test_a_refused_redraw_writes_nothing(ci_run, tmp_path, capsys):
    out = tmp_path / "e"
    shutil.copytree(ci_run / "results", out / "results")  # a run stopped before its report
    rc, err = _run(["--scale", "cpu", "--redraw", "--quiet", "--out", str(out)], capsys)
    assert rc == 2 and "--redraw: no saved results" in err
    assert sorted(p.name for p in out.iterdir()) == ["results"]
    rc, err = _run(["--scale", "ci", "--redraw", "--quiet", "--out", str(out)], capsys)
    assert rc == 0 and (out / "manifest.txt").read_text().startswith("# odolab study e_table")


def test_a_result_that_could_not_be_saved_is_refused_before_any_work(ci_run, tmp_path, capsys):
    out = tmp_path / "e"
    shutil.copytree(ci_run, out)
    victim = min((out / "results").iterdir())
    victim.unlink()
    victim.mkdir()
    rc, err = _run([*CI, "--out", str(out)], capsys)
    assert rc == 2 and len(err.splitlines()) == 1
    assert f"{victim}: expected a regular file or nothing, found a folder" in err and "remove it" in err


def test_hand_edited_results_are_computed_again_not_drawn():
    from studies.e_table import valid_result

    good = {"dx": 1.0, "dz": 2.0, "dyaw": 0.5, "dx_own": None, "dz_own": 1.0, "dyaw_own": 0.4}
    good |= {"steps": 6, "failure_share": 0.5}
    assert valid_result({"all": good})
    for change in (
        {"dx": float("inf")}, {"dx": float("nan")}, {"dx": None}, {"dx": -5.0}, {"dz_own": -1.0},
        {"steps": True}, {"steps": -5}, {"failure_share": None}, {"failure_share": 5}, {"dyaw": "1"},
    ):  # fmt: skip
        assert not valid_result({"all": {**good, **change}}), change


def test_findings_need_two_of_the_papers_odometers_and_say_a_missing_spread():
    from studies.e_table import findings

    row = {"action": "all", "dx": 4.9, "dz": 3.0, "dyaw": 1.0, "dx_sd": float("nan"), "dz_sd": 0.1, "dyaw_sd": 0.2}
    one = findings([{**row, "odometer": "feature-essential"}])
    assert len(one) == 1 and one[0].startswith("No order to compare") and "holds 1 of them" in one[0]
    two = findings([{**row, "odometer": "feature-essential"}, {**row, "odometer": "robust-vo", "dx": 1.0}])
    assert two[0] == "dx: ours E3 1.00 +- -, E1 4.90 +- - (x 1e-2, lowest first); agrees with the paper's order E3 < E1"


def test_a_scale_key_that_is_no_field_is_refused():
    from studies import e_table, framework

    base = framework.load_study("e_table")
    config = framework.StudyConfig(
        base.name, base.title, {**base.scales, "ci": {**base.at("ci"), "seed": 3}}, base.path
    )
    with pytest.raises(ValueError) as exc:
        framework.scale_params(config, "ci", e_table.scale_of)
    assert str(exc.value).startswith(f"{base.path}: scales.ci.seed: not a field of this study (expected episodes")
    assert json.dumps(framework.scale_params(base, "ci", e_table.scale_of).seeds) == "[0, 1]"


def test_an_out_folder_inside_another_runs_folder_is_refused(ci_run, capsys):
    inner = ci_run / "results" / "mine"
    rc, err = _run([*CI, "--out", str(inner)], capsys)
    assert rc == 2 and err.endswith(
        f"--out {inner}: lies inside the report folder of study e_table (python -m studies.e_table), "
        f"{ci_run}; choose a folder outside it"
    )
    assert not inner.exists()


def test_nesting_is_found_through_links_and_before_a_stopped_run_is_claimed(ci_run, tmp_path, capsys):
    link = tmp_path / "link"
    link.symlink_to(ci_run / "results")
    rc, err = _run([*CI, "--out", str(link / "x")], capsys)
    assert (
        rc == 2 and "lies inside the report folder of study e_table" in err and not (ci_run / "results" / "x").exists()
    )
    stopped = ci_run / "copy"  # what a stopped first run leaves, inside another run's folder
    shutil.copytree(ci_run / "results", stopped / "results")
    try:
        rc, err = _run([*CI, "--out", str(stopped)], capsys)
        assert rc == 2 and "lies inside" in err and not (stopped / "manifest.txt").exists()
    finally:
        shutil.rmtree(stopped)


def test_a_pipe_named_manifest_in_a_parent_does_not_block(tmp_path, capsys):
    import os

    (tmp_path / "p").mkdir()
    os.mkfifo(tmp_path / "p" / "manifest.txt")
    from odolab.report import manifest_owner

    assert manifest_owner(tmp_path / "p") is None  # returns, does not wait for a writer
