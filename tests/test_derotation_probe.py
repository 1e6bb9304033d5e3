"""studies/robust_vo/derotation_probe.py: its options are bounded before any work."""

from __future__ import annotations

from pathlib import Path

import pytest

from odolab.cli.study import command


@pytest.mark.parametrize("argv", [["--samples", "-1"], ["--samples", str(2**63)], ["--seconds", "nan"]])
def test_the_derotation_probe_bounds_its_options_before_work(argv, capsys):
    assert command("derotation-probe", argv) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_a_recipe_whose_data_is_not_made_is_one_line(tmp_path, monkeypatch, capsys):
    """The probe reads the recipe's made data: missing data is named with --config, no traceback."""
    monkeypatch.chdir(tmp_path)  # data_root "data" is relative: nothing made here
    recipe = tmp_path / "r.toml"
    recipe.write_text((Path(__file__).parents[1] / "studies/robust_vo/shipped.toml").read_text())
    assert command("derotation-probe", ["--config", str(recipe), "--samples", "32"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--config" in err[0] and "make the data first" in err[0], err
