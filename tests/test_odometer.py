"""odolab/odometry/odometer.py: an entry point whose module cannot be imported, whatever it raises, is named
in one line; the list of every odometer still forms. Odometers load from a file's path; a class that
is no Odometer or overrides no step, a composite hiding an oracle input and an empty name are refused.
The Odometer contract, the registry and the reference odometers too."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from odolab import api
from odolab.api import Odometer, register_odometer
from odolab.core.parallel import SERIAL
from odolab.odometry import odometer
from odolab.odometry.action_prior import ActionPrior, fit_action_prior
from odolab.odometry.odometer import REGISTRY, IncompleteOdometerError, OracleInputError, load_odometer
from odolab.running import runner, summary
from odolab.sim.camera import CameraSpec
from odolab.sim.episodes import EpisodeSpec, load_episodes
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
    from odolab.reporting.pipeline import ComparisonError, load_odometers

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
    from odolab.reporting.pipeline import ComparisonError, load_odometers

    with pytest.raises(ComparisonError, match="no such file"):
        load_odometers([f"{tmp_path / 'nothing.py'}:Forward"])
    (tmp_path / "broken.py").write_text("def oops(:\n")
    with pytest.raises(ComparisonError, match="broken.py raised SyntaxError"):
        load_odometers([f"{tmp_path / 'broken.py'}:Forward"])
    (tmp_path / "fine.py").write_text(ODOMETER_FILE)
    with pytest.raises(ComparisonError, match="has no attribute 'Backward'"):
        load_odometers([f"{tmp_path / 'fine.py'}:Backward"])


@pytest.fixture(scope="module")
def episodes():
    camera = CameraSpec(width=96, height=54)
    specs = [EpisodeSpec(split="test", index=i, max_steps=40, camera=camera) for i in range(3)]
    return load_episodes(specs, None, execution=SERIAL)


class ConstantForward(api.Odometer):
    """The README's example of a third-party odometer: always 0.2 m forward."""

    def step(self, prev, cur, action):
        return api.Estimate.from_planar(0.0, 0.2, 0.0)


class Flaky(api.Odometer):
    """Raises on even steps, says invalid on every third, else answers identity."""

    def reset(self, intrinsics):
        super().reset(intrinsics)
        self.k = 0

    def step(self, prev, cur, action):
        self.k += 1
        assert prev.gt_pose is None and cur.gt_pose is None  # non-oracles never see ground truth
        if self.k % 2 == 0:
            raise RuntimeError("boom")
        if self.k % 3 == 0:
            return api.Estimate.invalid()
        return api.Estimate(np.eye(4))


def test_register_and_load_a_new_odometer():
    api.register_odometer("constant-forward", ConstantForward)
    assert "constant-forward" in api.available_odometers()
    odo = api.load_odometer("constant-forward")
    assert odo.name == "constant-forward"
    est = odo.step(None, None, api.Action.TURN_LEFT)
    assert est.planar == pytest.approx([0.0, 0.2, 0.0]) and est.valid


def test_unknown_odometer_lists_the_choices():
    with pytest.raises(api.UnknownOdometerError) as info:
        api.load_odometer("no-such-odometer")
    assert "ground-truth" in str(info.value) and "action-prior" in str(info.value)


def test_entry_point_odometers_are_listed():
    names = api.available_odometers()
    assert {"ground-truth", "action-prior", "icp", "feature-essential"} <= set(names)


def test_ground_truth_has_zero_error(episodes):
    res = runner.run({"ground-truth": api.load_odometer("ground-truth")}, episodes)
    row = summary.summarize(res)[0]
    assert row.oracle and row.failures == 0
    assert max(row.dx, row.dz, row.dyaw, row.ate_m, row.drift_m) < 1e-9


def test_action_prior_error_has_the_size_the_noise_implies(episodes):
    res = runner.run({"action-prior": api.load_odometer("action-prior")}, episodes)
    per_action = {r.action: r for r in summary.summarize_actions(res)}
    # Turns: yaw noise 0.5 * N(0.043, 0.017) truncated -> E|e| = 0.5 * sqrt(0.017) * sqrt(2/pi) ~ 0.052 rad
    turns = [per_action[a] for a in ("turn_left", "turn_right") if a in per_action]
    steps = sum(t.steps for t in turns)
    assert steps >= 8  # enough turns to judge (the episodes are fixed by their specs)
    assert 2.5 < sum(t.dyaw * t.steps for t in turns) / steps < 9.0  # x 1e-2 rad, pooled over both turns
    fwd = per_action["move_forward"]
    # Forward yaw noise 0.5 * sqrt(0.026) * sqrt(2/pi) ~ 0.064 rad; lateral 0.5 * sqrt(0.023) * 0.8 ~ 0.06 m
    assert 3.0 < fwd.dyaw < 10.0 and 2.0 < fwd.dx < 10.0
    row = summary.summarize(res)[0]
    assert row.failures == 0 and row.ate_m > 0.01


@pytest.mark.slow
def test_shipped_action_prior_matches_a_fresh_fit():
    shipped = ActionPrior.shipped()
    fresh = fit_action_prior(n_episodes=40, max_steps=200, seed=123)
    for a in api.MOTION_ACTIONS:
        assert np.allclose(shipped.motion(a), fresh.motion(a), atol=0.02)
    assert shipped.motion(api.Action.MOVE_FORWARD)[1] == pytest.approx(0.25 + 0.0085, abs=0.03)
    assert shipped.motion(None) == pytest.approx([0, 0, 0])


def test_runner_counts_failures_and_falls_back_to_the_prior(episodes):
    ep = episodes[0]
    prior = ActionPrior.shipped()
    res = runner.run_sequence(Flaky(), ep, "flaky", prior)
    n = len(ep) - 1
    k = np.arange(1, n + 1)
    expect_fail = (k % 2 == 0) | (k % 3 == 0)
    assert np.array_equal(~res.valid, expect_fail)
    assert res.failures == expect_fail.sum()
    assert res.errors and "boom" in res.errors[0]
    assert res.failure_reasons == {
        "raised": int((k % 2 == 0).sum()),
        "not-valid": int(((k % 2 != 0) & (k % 3 == 0)).sum()),
    }
    i = int(np.argmax(expect_fail))
    assert api.transform_to_planar(res.estimates[i]) == pytest.approx(prior.motion(ep.action(i)))
    assert np.allclose(res.poses[0], ep.poses[0])
    assert res.step_seconds.shape == (n,) and np.all(res.step_seconds >= 0)


def test_estimate_helpers():
    e = api.Estimate.from_planar(0.1, 0.2, -0.3)
    assert e.planar == pytest.approx([0.1, 0.2, -0.3]) and e.covariance is None
    assert not api.Estimate.invalid().valid
    K = api.Intrinsics.from_hfov(341, 192, 70.0)
    assert K.fx == pytest.approx(243.5, abs=0.05) and K.cx == 170.0 and K.cy == 95.5  # pixel centres at integers


def test_step_before_reset_says_so():
    class NeedsCamera(api.Odometer):
        def step(self, prev, cur, action):
            return api.Estimate.from_planar(0, self.intrinsics.fx * 0, 0)

    with pytest.raises(RuntimeError, match="reset"):
        NeedsCamera().step(None, None, None)


def test_runner_survives_a_malformed_estimate(episodes):
    class Malformed(api.Odometer):
        def step(self, prev, cur, action):
            return api.Estimate(np.eye(4)[:3])

    res = runner.run_sequence(Malformed(), episodes[0], "malformed", ActionPrior.shipped())
    assert res.failures == len(episodes[0]) - 1
    assert res.failure_reasons == {"bad-shape": len(episodes[0]) - 1}


def test_a_frame_that_cannot_be_rgbd_is_refused_naming_the_field():
    import numpy as np
    import pytest

    from odolab.api import Frame

    rgb, depth = np.zeros((6, 8, 3), np.uint8), np.ones((6, 8), np.float32)
    Frame(rgb, depth)
    for bad_rgb, bad_depth, said in (
        (rgb, depth[..., None], "Frame.depth"),
        (rgb, depth.tolist(), "Frame.depth"),
        (rgb[..., 0], depth, "Frame.rgb"),
        (None, depth, "Frame.rgb"),
        (rgb, depth.T, "rgb is 6x8 pixels but depth 8x6"),
    ):
        with pytest.raises(ValueError, match=said):
            Frame(bad_rgb, bad_depth)


def test_an_integer_action_is_read_as_its_action_and_a_bad_one_refused():
    import numpy as np
    import pytest

    from odolab.api import Action, Estimate, Odometer

    seen = []

    class Recorder(Odometer):
        def step(self, prev, cur, action):
            seen.append(action)
            return Estimate(np.eye(4))

    odo = Recorder()
    odo.step(None, None, 1)
    odo.step(None, None, np.int8(2))
    odo.step(None, None, None)
    odo.step_batch([(None, None, 3)])
    assert seen == [Action.MOVE_FORWARD, Action.TURN_LEFT, None, Action.TURN_RIGHT]
    for bad in (7, True, "forward", 1.0):
        with pytest.raises(TypeError, match="expected an Action"):
            odo.step(None, None, bad)


def test_the_action_check_keeps_each_step_signature():
    import numpy as np
    import pytest

    from odolab.api import Action, Estimate, Odometer

    class Renamed(Odometer):
        def step(self, previous, current, act=None):
            return act

    class NoAction(Odometer):
        def step(self, prev, cur):
            return "ran"

    class Static(Odometer):
        @staticmethod
        def step(prev, cur, action):
            return action

    class Plain(Odometer):
        def step(self, prev, cur, action):
            return Estimate(np.eye(4))

    assert Renamed().step(previous=0, current=0, act=2) is Action.TURN_LEFT
    assert Renamed().step(0, 0, act=3) is Action.TURN_RIGHT
    assert NoAction().step(0, 0) == "ran"
    assert Static().step(0, 0, 1) == 1  # left alone
    with pytest.raises(TypeError, match="action"):  # a forgotten action is still an error
        Plain().step(0, 0)
    with pytest.raises(ValueError, match=r"pair 0 must be \(prev, cur, action\), got 2 items"):
        Plain().step_batch([(0, 0)])


def _nested(depth: int, inner: str = "icp") -> str:
    name = inner
    for _ in range(depth):
        name = f"manhattan({name})"
    return name


@pytest.mark.parametrize("depth", [9, 400, 1000, 5000])
def test_composites_nested_too_deep_are_one_line_in_every_entry_point(depth):
    from odolab.odometry.odometer import inner_names, load_odometer, parse_odometer_list, unknown_odometer
    from odolab.reporting.pipeline import ComparisonError, load_odometers, odometer_names

    name = _nested(depth)
    for call in (parse_odometer_list, load_odometer, inner_names, unknown_odometer):
        with pytest.raises(ValueError, match=f"nests composites {depth} deep; at most 8"):
            call(name)
    for call in (odometer_names, load_odometers):
        with pytest.raises(ComparisonError, match="at most 8"):
            call([name])


def test_a_deep_name_on_the_command_line_is_one_short_line(tmp_path):
    one_line_error(
        "odolab.compare",
        "--odometers",
        _nested(1000),
        "--episodes",
        "1",
        "--max-steps",
        "2",
        "--no-cache",
        "--out",
        tmp_path / "o",
        words="nests composites 1000 deep",
    )
