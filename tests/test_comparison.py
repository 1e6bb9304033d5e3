"""compare's orchestration as one library call: what a study, a notebook or navigation would make; a TUM
folder's depth scale and camera, and an odometer that fails every step said so."""

import csv

import pytest

from odolab import api
from odolab.api import register_odometer
from odolab.cli import run_cli
from odolab.compare import main
from odolab.core.parallel import SERIAL, Execution
from tests.helpers import FR1, Never


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
    from odolab.reporting.comparison import odometer_configs

    configs = odometer_configs({"icp": load_odometer("icp", max_depth=3.0), "gt": load_odometer("ground-truth")})
    assert list(configs) == ["icp"] and "depth.max_depth=3.0" in configs["icp"]


def test_collided_forward_steps_get_their_own_row_with_what_each_odometer_saw():
    import numpy as np

    from odolab.running.summary import COLLIDED_FORWARD

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


def test_compare_takes_the_depth_scale_and_the_camera_and_warns_of_a_wrong_scale(millimetre_folder):
    from odolab.reporting.comparison import ComparisonConfig, run_comparison

    def run(scale):
        config = ComparisonConfig(
            odometers=["ground-truth"],
            tum=millimetre_folder,
            tum_depth_scale=scale,
            tum_intrinsics=FR1,
            execution=Execution(progress=False),
        )
        return run_comparison(config)

    assert not any("median" in w for w in run(1000.0).warnings)
    assert any("depth's median is 0.22 m" in w for w in run(None).warnings)


def test_an_odometer_failing_every_step_is_said_on_the_compare_console():
    from odolab.reporting.comparison import ComparisonConfig, run_comparison
    from odolab.running.summary import every_step_failed

    register_odometer("test-never", Never)
    result = run_comparison(
        ComparisonConfig(
            odometers=["test-never", "action-prior"],
            episodes=1,
            max_steps=3,
            cache=None,
            execution=SERIAL,
        )
    )
    assert every_step_failed(result.rows) == [
        "test-never: failed steps: every one of 3; its figures are the action prior's, which stood in for each"
    ]
