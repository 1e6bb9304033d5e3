"""studies/robust_vo/derotation_probe.py: its options are bounded before any work."""

from __future__ import annotations

import pytest

from odolab.cli.study import command


@pytest.mark.parametrize("argv", [["--samples", "-1"], ["--samples", str(2**63)], ["--seconds", "nan"]])
def test_the_derotation_probe_bounds_its_options_before_work(argv, capsys):
    assert command("derotation-probe", argv) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
