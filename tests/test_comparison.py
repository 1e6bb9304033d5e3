"""compare's orchestration as one library call: what a study, a notebook or navigation would make."""

import csv

import pytest

from odolab import api
from odolab.cli import run_cli
from odolab.compare import main
from odolab.parallel import SERIAL


def test_run_comparison_matches_the_command_line(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the library call writes nothing
    config = api.ComparisonConfig(
        odometers=["ground-truth", "action-prior"],
        episodes=2,
        max_steps=8,
        seed=5,
        cache=None,
        execution=SERIAL,
    )
    result = api.run_comparison(config)
    assert list(tmp_path.iterdir()) == []
    assert [r.odometer for r in result.rows] == ["ground-truth", "action-prior"]
    assert len(result.results) == 4 and len(result.plans) == 2
    assert result.rows[0].ate_m < 1e-9 < result.rows[1].ate_m
    assert any("collisions" in n for n in result.notes) and result.action_rows
    out = tmp_path / "cli"
    assert (
        run_cli(
            main,
            "odolab.compare",
            [
                "--odometers",
                "ground-truth,action-prior",
                "--episodes",
                "2",
                "--max-steps",
                "8",
                "--seed",
                "5",
                "--no-cache",
                "--serial",
                "--quiet",
                "--out",
                str(out),
            ],
        )
        == 0
    )
    table = {r["odometer"]: float(r["ate_m"]) for r in csv.DictReader((out / "table.csv").read_text().splitlines())}
    assert table["action-prior"] == pytest.approx(result.rows[1].ate_m, abs=1e-5)  # the CSV keeps 5 decimals


def test_run_comparison_reports_bad_configuration_as_one_line():
    with pytest.raises(api.ComparisonError, match="split 'dev'"):
        api.run_comparison(api.ComparisonConfig(split="dev", cache=None))


def test_each_configurable_odometers_settings_reach_the_result():
    from odolab.api import load_odometer
    from odolab.comparison import odometer_configs

    configs = odometer_configs({"icp": load_odometer("icp", max_depth=3.0), "gt": load_odometer("ground-truth")})
    assert list(configs) == ["icp"] and "depth.max_depth=3.0" in configs["icp"]


def test_collided_forward_steps_get_their_own_row_with_what_each_odometer_saw():
    import numpy as np

    from odolab.summary import COLLIDED_FORWARD

    config = api.ComparisonConfig(
        odometers=["ground-truth", "action-prior"],
        episodes=3,
        max_steps=60,
        seed=1,
        cache=None,
        execution=SERIAL,
    )
    result = api.run_comparison(config)
    prior = [r for r in result.results if r.odometer == "action-prior"]
    blocked = sum(int(((r.actions == api.Action.MOVE_FORWARD.value) & r.collisions).sum()) for r in prior)
    rows = {(r.odometer, r.action): r for r in result.action_rows}
    assert blocked  # these seeded episodes collide
    row, forward = rows[("action-prior", COLLIDED_FORWARD)], rows[("action-prior", "move_forward")]
    assert row.steps == blocked < forward.steps
    assert row.dz > forward.dz  # the prior claims a full step where the robot did not move
    assert rows[("ground-truth", COLLIDED_FORWARD)].dz == 0 and np.isfinite(row.dx)
