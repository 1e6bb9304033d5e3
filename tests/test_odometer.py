"""odolab/odometer.py: an entry point whose module cannot be imported, whatever it raises, is named
in one line; the list of every odometer still forms."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from odolab import odometer


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
