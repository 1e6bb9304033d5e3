"""Runs that would be silently wrong are marked or refused: an oracle inside a composite, an
odometer that implements nothing, depth read at the wrong scale, a damaged training shard, a
trajectory whose KITTI drift cannot be computed; and odometers load from a file's path."""
from __future__ import annotations

import numpy as np
import pytest

from odolab import runner
from odolab.action_prior import ActionPrior
from odolab.api import Action, Estimate, Frame, Intrinsics, Odometer, planar_to_transform, register_odometer
from odolab.odometer import REGISTRY, IncompleteOdometerError, OracleInputError, load_odometer

INTRINSICS = Intrinsics.from_hfov(8, 6, 79.0)


class _Steps:
    """A five-frame sequence moving 0.25 m forward per step, with ground truth and actions."""

    name = "steps"
    collisions = None
    intrinsics = INTRINSICS

    def __len__(self) -> int:
        return 5

    def gt_pose(self, i: int) -> np.ndarray:
        return planar_to_transform(0.0, 0.25 * i, 0.0)

    def __getitem__(self, i: int) -> Frame:
        return Frame(np.zeros((6, 8, 3), np.uint8), np.full((6, 8), 2.0, np.float32), float(i), self.gt_pose(i))

    def action(self, i: int) -> Action:
        return Action.MOVE_FORWARD


class _Truth(Odometer):
    """An oracle that answers the true motion, and fails a step whose frames hide it."""

    oracle = True

    def step(self, prev, cur, action):
        if prev.gt_pose is None or cur.gt_pose is None:
            return Estimate.invalid()
        return Estimate(np.linalg.inv(prev.gt_pose) @ cur.gt_pose)


class _BlindComposite(Odometer):
    """A third-party composite that does not pass its input's oracle nature on."""

    def __init__(self, inputs: str = "") -> None:
        self.inner = load_odometer(inputs)

    def step(self, prev, cur, action):
        return self.inner.step(prev, cur, action)


@pytest.fixture()
def oracle_calibration(tmp_path) -> str:
    from odolab.fusion.calibration import Calibration, InputCalibration

    fixed = {a: [0.01, 0.01, 0.01, 0.02, 0.02, 0.02] for a in ("move_forward", "turn_left", "turn_right")}
    one = InputCalibration(fixed, {a: None for a in fixed}, {a: 100 for a in fixed})
    path = tmp_path / "cal.json"
    Calibration({"action-prior": one, "test-truth": one}).save(path)
    register_odometer("test-truth", _Truth)
    register_odometer("test-blind", _BlindComposite)
    return str(path)


def test_a_fused_oracle_input_answers_and_the_fused_row_is_marked_oracle(oracle_calibration):
    fused = REGISTRY.load("fused(test-truth)", calibration=oracle_calibration)
    assert fused.oracle
    result = runner.run_sequence(fused, _Steps(), "fused(test-truth)", ActionPrior.shipped())
    assert result.oracle and result.failures == 0
    assert np.allclose(result.poses[-1][:3, 3], _Steps().gt_pose(4)[:3, 3], atol=1e-6)  # not the action prior's


def test_manhattan_passes_its_inputs_oracle_on():
    assert load_odometer("manhattan(ground-truth)").oracle


def test_a_composite_that_hides_ground_truth_from_its_oracle_input_is_refused(oracle_calibration):
    with pytest.raises(OracleInputError, match="'test-truth' reads ground truth"):
        REGISTRY.load("test-blind(test-truth)")
    assert not REGISTRY.load("test-blind(action-prior)").oracle  # no oracle inside: loads


def test_the_calibration_command_names_an_oracle_input(tmp_path, capsys, oracle_calibration):
    from odolab.fusion import calibrate

    calibrate.main(["--odometers", "action-prior,test-truth", "--episodes", "1", "--max-steps", "30", "--serial",
                    "--quiet", "--split", "val", "--cache", str(tmp_path / "cache"), "--out", str(tmp_path / "c.json")])
    assert "test-truth (an oracle" in capsys.readouterr().out


# ----------------------------------------------------------------------------- an odometer that implements nothing

class _Abstract(Odometer):
    pass


def test_an_odometer_without_step_is_refused_when_loaded():
    register_odometer("test-abstract", _Abstract)
    with pytest.raises(IncompleteOdometerError, match="overrides neither step"):
        load_odometer("test-abstract")


def test_a_comparison_names_an_odometer_without_step_in_one_line():
    from odolab.comparison import ComparisonError, load_odometers

    register_odometer("test-abstract", _Abstract)
    with pytest.raises(ComparisonError, match=r"^odometer 'test-abstract': class _Abstract overrides neither"):
        load_odometers(["test-abstract"])


# ----------------------------------------------------------------------------- odometers from a file

ODOMETER_FILE = '''
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
'''


def test_an_odometer_loads_from_a_file_path_without_pythonpath(tmp_path, monkeypatch):
    folder = tmp_path / "my odometers"
    folder.mkdir()
    (folder / "forward_vo.py").write_text(ODOMETER_FILE)
    odo = load_odometer(f"{folder / 'forward_vo.py'}:Forward", dz=0.5)
    frame = _Steps()[0]
    assert odo.step(frame, frame, None).planar[1] == pytest.approx(0.5)
    monkeypatch.chdir(folder)  # a relative path, and the same file again: the same class
    again = load_odometer("forward_vo.py:Forward")
    assert type(again) is type(odo) and again.name == "forward_vo.py:Forward"


def test_an_odometer_file_that_is_missing_or_broken_is_named(tmp_path):
    from odolab.comparison import ComparisonError, load_odometers

    with pytest.raises(ComparisonError, match="no such file"):
        load_odometers([f"{tmp_path / 'nothing.py'}:Forward"])
    (tmp_path / "broken.py").write_text("def oops(:\n")
    with pytest.raises(ComparisonError, match="broken.py raised SyntaxError"):
        load_odometers([f"{tmp_path / 'broken.py'}:Forward"])
    (tmp_path / "fine.py").write_text(ODOMETER_FILE)
    with pytest.raises(ComparisonError, match="has no attribute 'Backward'"):
        load_odometers([f"{tmp_path / 'fine.py'}:Backward"])
