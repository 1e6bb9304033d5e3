"""odolab/reporting/comparison.py: a broken entry point left out of the default list with one warning; the step
time limit reaches the runner; frames without depth and one-frame TUM folders said in one line;
a plug-in's attribute that raises read inside a guard."""

from __future__ import annotations

import shutil
import threading
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from odolab import api
from odolab.odometry import odometer
from odolab.reporting import comparison
from odolab.reporting.comparison import ComparisonConfig, ComparisonError, load_odometers
from odolab.running.runner import SequenceResult

TUM = Path(__file__).parent / "data" / "tum_fr1_xyz_10"


@pytest.fixture
def broken_default(monkeypatch):
    """The registry's entry points: only one, whose module is not installed (built-ins stay)."""
    point = SimpleNamespace(name="broken-plugin", value="odolab_test_not_installed:Odo")
    monkeypatch.setattr(odometer, "entry_points", lambda group: [point])


def test_a_broken_entry_point_is_left_out_of_the_default_list_with_one_warning(broken_default):
    said: list[str] = []
    loaded = load_odometers(None, warn=said.append)
    assert sorted(loaded) == ["action-prior", "ground-truth"]
    line = (
        "warning: left out of the default list of odometers: odometer 'broken-plugin': cannot import "
        "'odolab_test_not_installed:Odo' (No module named 'odolab_test_not_installed')"
    )
    assert said == [line]


def test_the_warning_goes_to_stderr_by_default(broken_default, capsys):
    load_odometers(None)
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and "broken-plugin" in err and "left out" in err


def test_a_broken_entry_point_named_or_given_options_is_still_an_error(broken_default):
    with pytest.raises(ComparisonError, match="^odometer 'broken-plugin': cannot import"):
        load_odometers(["broken-plugin", "ground-truth"], warn=pytest.fail)
    with pytest.raises(ComparisonError, match="cannot import"):
        load_odometers(None, {"broken-plugin": {"k": 1}}, warn=pytest.fail)


def test_no_odometer_left_is_an_error(monkeypatch):
    monkeypatch.setattr(comparison, "standalone_odometers", lambda: ["broken-plugin"])
    monkeypatch.setattr(comparison, "unknown_odometer", lambda name: None)
    with pytest.raises(ComparisonError, match="^no odometer could be loaded"):
        load_odometers(None, warn=lambda line: None)


@pytest.mark.parametrize("value", [0, -1.0, float("nan"), "60", True])
def test_a_step_timeout_must_be_a_positive_number(value):
    with pytest.raises(ComparisonError, match=f"step_timeout must be a number of seconds > 0 .*got {value!r}"):
        comparison.check_step_timeout(value)


def test_step_timeouts_kept():
    assert comparison.check_step_timeout(None) is None and comparison.check_step_timeout(float("inf")) is None
    assert comparison.check_step_timeout(2) == 2.0 and ComparisonConfig().step_timeout == 60.0


def _tum_folder(tmp_path: Path, frames: int) -> Path:
    """A copy of the test TUM folder keeping its first ``frames`` colour images."""
    dst = tmp_path / "tum_fr1_short"
    shutil.copytree(TUM, dst)
    lines = (dst / "rgb.txt").read_text().splitlines()
    head = [line for line in lines if line.startswith("#")]
    (dst / "rgb.txt").write_text("\n".join(head + [line for line in lines if not line.startswith("#")][:frames]) + "\n")
    return dst


def test_a_tum_folder_of_one_frame_is_one_line(tmp_path):
    config = ComparisonConfig(odometers=["action-prior"], tum=_tum_folder(tmp_path, 1), cache=None)
    with pytest.raises(ComparisonError) as err:
        comparison.run_comparison(config)
    assert str(err.value) == (
        "1 usable frame (a colour image with a depth image and a ground-truth pose); "
        "a comparison needs at least 2, one step between them"
    )


def test_the_step_timeout_reaches_the_runner(tmp_path):
    release = threading.Event()

    class Stuck(api.Odometer):
        def step(self, prev, cur, action):
            release.wait(10)
            return api.Estimate(np.eye(4))

    config = ComparisonConfig(odometers=["stuck"], tum=_tum_folder(tmp_path, 3), cache=None, step_timeout=0.02)
    try:
        result = comparison.run_comparison(config, odometers={"stuck": Stuck()})
    finally:
        release.set()
    assert comparison.failure_reasons(result.results) == {"stuck": {"timed-out": 2}}


def test_a_needs_action_that_raises_is_one_line(tmp_path):
    class Odd(api.Odometer):
        @property
        def needs_action(self):
            raise RuntimeError("unknown")

    config = ComparisonConfig(odometers=["odd"], tum=_tum_folder(tmp_path, 2), cache=None)
    with pytest.raises(ComparisonError, match="^odometer 'odd': reading needs_action raised RuntimeError: unknown$"):
        comparison.run_comparison(config, odometers={"odd": Odd()})


def test_a_config_property_that_raises_shows_no_settings():
    class Odd(api.Odometer):
        @property
        def config(self):
            raise RuntimeError("no config")

    assert comparison.odometer_configs({"odd": Odd()}) == {}


def _with_empty(sequence: str, odometer: str, empty: int, n: int = 4) -> SequenceResult:
    return SequenceResult(
        odometer=odometer,
        sequence=sequence,
        oracle=False,
        estimates=np.tile(np.eye(4), (n, 1, 1)),
        truth=None,
        poses=np.tile(np.eye(4), (n + 1, 1, 1)),
        gt_poses=None,
        actions=np.zeros(n, np.int8),
        valid=np.ones(n, bool),
        step_seconds=np.zeros(n),
        empty_depth=empty,
    )


def test_frames_without_depth_give_one_warning_per_sequence():
    results = [_with_empty("a", "x", 2), _with_empty("a", "y", 2), _with_empty("b", "x", 0), _with_empty("c", "x", 5)]
    assert comparison.empty_depth_warnings(results) == [
        "a: 2 of 5 frames have no depth at all (every depth pixel is 0); odometers that use depth cannot use them",
        "c: 5 of 5 frames have no depth at all (every depth pixel is 0); odometers that use depth cannot use them",
    ]
