"""The README's code must keep working as written."""
import re
from pathlib import Path

import numpy as np
import pytest

from odolab import api

README = Path(__file__).resolve().parents[1] / "README.md"


def test_add_an_odometer_snippet_runs():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    snippet = next(b for b in blocks if "register_odometer(" in b)
    exec(compile(snippet, "README.md", "exec"), {"__name__": "readme_snippet"})
    odo = api.load_odometer("nominal")
    frame = api.Frame(np.zeros((2, 2, 3), np.uint8), np.zeros((2, 2), np.float32))
    assert odo.step(frame, frame, api.Action.MOVE_FORWARD).planar == pytest.approx([0.0, 0.25, 0.0])
    assert not odo.step(frame, frame, None).valid


def test_readme_names_the_two_commands():
    text = README.read_text()
    assert "pip install torch==2.13.0" in text and 'pip install -e ".[test]"' in text
    assert "python -m odolab.compare" in text and "\npytest\n" in text
