"""odolab/odometry/odometer.py: an entry point whose module cannot be imported, whatever it raises, is named
in one line; the list of every odometer still forms. Odometers load from a file's path; a class that
is no Odometer or overrides no step, a composite hiding an oracle input and an empty name are refused."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from odolab.api import Odometer, register_odometer
from odolab.odometry import odometer
from odolab.odometry.odometer import REGISTRY, IncompleteOdometerError, OracleInputError, load_odometer
from tests.helpers import Steps, one_line_error


@pytest.fixture
def broken_entry_points(tmp_path, monkeypatch):
    """Installed entry points: one module that raises at import, one that does not exist."""
    (tmp_path / "odolab_test_raises_on_import.py").write_text("raise RuntimeError('needs a GPU driver')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    points = [
        SimpleNamespace(name="raises-on-import", value="odolab_test_raises_on_import:Odo"),
        SimpleNamespace(name="not-installed", value="odolab_test_not_installed:Odo"),
    ]
    monkeypatch.setattr(odometer, "entry_points", lambda group: points)


def test_a_module_raising_at_import_is_an_unknown_odometer_naming_it(broken_entry_points):
    with pytest.raises(odometer.UnknownOdometerError) as err:
        odometer.REGISTRY.resolve("raises-on-import")
    assert str(err.value) == (
        "odometer 'raises-on-import': cannot import 'odolab_test_raises_on_import:Odo' "
        "(RuntimeError while imported: needs a GPU driver)"
    )
    with pytest.raises(odometer.UnknownOdometerError, match="cannot import 'odolab_test_not_installed:Odo'"):
        odometer.REGISTRY.resolve("not-installed")


def test_every_odometer_lists_broken_entry_points_without_raising(broken_entry_points):
    names = odometer.standalone_odometers()
    assert {"raises-on-import", "not-installed", "ground-truth", "action-prior"} <= set(names)


@pytest.mark.parametrize("module", ["odolab.compare", "odolab.navigate"])
def test_an_odometer_list_with_an_empty_name_is_refused(tmp_path, module):
    one_line_error(module, "--odometers", "icp,", "--out", tmp_path / "o", words="'icp,' has an empty name")


def test_a_class_that_is_not_an_odometer_is_refused_at_load(tmp_path):
    from odolab.odometry.odometer import IncompleteOdometerError, load_odometer

    source = tmp_path / "plain_class.py"
    source.write_text("class PlainClass:\n    def step(self, prev, cur, action):\n        return None\n")
    with pytest.raises(IncompleteOdometerError, match="not an Odometer"):
        load_odometer(f"{source}:PlainClass")


def test_a_composite_that_hides_ground_truth_from_its_oracle_input_is_refused(oracle_calibration):
    with pytest.raises(OracleInputError, match="'test-truth' reads ground truth"):
        REGISTRY.load("test-blind(test-truth)")
    assert not REGISTRY.load("test-blind(action-prior)").oracle  # no oracle inside: loads


class _Abstract(Odometer):
    pass


def test_an_odometer_without_step_is_refused_when_loaded():
    register_odometer("test-abstract", _Abstract)
    with pytest.raises(IncompleteOdometerError, match="overrides neither step"):
        load_odometer("test-abstract")


def test_a_comparison_names_an_odometer_without_step_in_one_line():
    from odolab.reporting.comparison import ComparisonError, load_odometers

    register_odometer("test-abstract", _Abstract)
    with pytest.raises(ComparisonError, match=r"^odometer 'test-abstract': class _Abstract overrides neither"):
        load_odometers(["test-abstract"])


ODOMETER_FILE = """
from dataclasses import dataclass
from odolab.api import Estimate, Odometer

@dataclass
class Settings:
    dz: float = 0.25

class Forward(Odometer):
    def __init__(self, dz: float = 0.25):
        self.settings = Settings(dz)

    def step(self, prev, cur, action):
        return Estimate.from_planar(0.0, self.settings.dz, 0.0)
"""


def test_an_odometer_loads_from_a_file_path_without_pythonpath(tmp_path, monkeypatch):
    folder = tmp_path / "my odometers"
    folder.mkdir()
    (folder / "forward_vo.py").write_text(ODOMETER_FILE)
    odo = load_odometer(f"{folder / 'forward_vo.py'}:Forward", dz=0.5)
    frame = Steps()[0]
    assert odo.step(frame, frame, None).planar[1] == pytest.approx(0.5)
    monkeypatch.chdir(folder)  # a relative path, and the same file again: the same class
    again = load_odometer("forward_vo.py:Forward")
    assert type(again) is type(odo) and again.name == "forward_vo.py:Forward"


def test_an_odometer_file_that_is_missing_or_broken_is_named(tmp_path):
    from odolab.reporting.comparison import ComparisonError, load_odometers

    with pytest.raises(ComparisonError, match="no such file"):
        load_odometers([f"{tmp_path / 'nothing.py'}:Forward"])
    (tmp_path / "broken.py").write_text("def oops(:\n")
    with pytest.raises(ComparisonError, match="broken.py raised SyntaxError"):
        load_odometers([f"{tmp_path / 'broken.py'}:Forward"])
    (tmp_path / "fine.py").write_text(ODOMETER_FILE)
    with pytest.raises(ComparisonError, match="has no attribute 'Backward'"):
        load_odometers([f"{tmp_path / 'fine.py'}:Backward"])
