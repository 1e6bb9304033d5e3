"""The shipped learned models: small, registered, and right about known simulator motions."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch")  # a declared dependency; skip only where it is truly absent

from odolab.api import Action, available_odometers, load_odometer
from odolab.learned.robust_vo.checkpoint import SHIPPED
from odolab.sim.episodes import EpisodeSpec, render_episode


@pytest.fixture(scope="module")
def episode():
    return render_episode(EpisodeSpec(split="test", index=3, seed=0, max_steps=40))


def test_the_shipped_robust_vo_is_small_and_registered():
    assert SHIPPED.is_file() and SHIPPED.stat().st_size < 20e6  # the three SepAct networks together
    assert "robust-vo" in available_odometers()


@pytest.mark.slow
def test_the_shipped_robust_vo_gets_known_motions_right(episode):
    """Every motion of a test episode (scenes never trained on) comes out with the right sign and
    about the right size: turns of 30 +- 4 degrees, forward steps of 0.25 m unless blocked."""
    odo = load_odometer("robust-vo")
    odo.reset(episode.intrinsics)
    truth = np.stack([odo_planar for odo_planar in _true_planar(episode)])
    est = np.stack([odo.step(episode[i], episode[i + 1], episode.action(i)).planar for i in range(len(episode) - 1)])
    actions = np.array([episode.action(i) for i in range(len(episode) - 1)])
    left, right = actions == Action.TURN_LEFT, actions == Action.TURN_RIGHT
    forward = (actions == Action.MOVE_FORWARD) & ~episode.collisions[: len(actions)]
    assert left.any() and right.any() and forward.any()
    assert np.all(est[left, 2] > 0.3) and np.all(est[right, 2] < -0.3)
    assert np.all(est[forward, 1] > 0.12)
    # and closer to the truth than the commanded motion on average
    nominal = np.array([load_odometer("action-prior").step(None, None, a).planar for a in actions])
    assert np.abs(est - truth).mean() < np.abs(nominal - truth).mean()


def _true_planar(ep):
    from odolab.api import invert, transform_to_planar

    return [transform_to_planar(invert(ep.poses[i]) @ ep.poses[i + 1]) for i in range(len(ep) - 1)]


def test_the_odometer_bench_sets_a_learned_odometer_beside_its_network_alone():
    """``--only odometers`` reports the robust VO's network pass alone (its limit) and the ratio."""
    from odolab.benchmarks.speed import bench_odometers

    (row,) = bench_odometers(["robust-vo"], episodes=1, max_steps=4)
    assert row["steps"] > 0 and row["failures"] == 0
    assert row["network_steps_per_s"] > 0
    assert row["over_network"] == row["steps_per_s"] / row["network_steps_per_s"]
    (classical,) = bench_odometers(["action-prior"], episodes=1, max_steps=4)
    assert "network_steps_per_s" not in classical


def test_a_model_file_with_non_finite_weights_is_refused_naming_the_entry(tmp_path):
    import torch

    from odolab.learned.robust_vo.checkpoint import load_model
    from odolab.learned.training import CheckpointError

    doc = torch.load(SHIPPED, weights_only=True)
    name = next(iter(doc["networks"]))
    weights = doc["networks"][name]["encoder.stem.0.weight"].clone()
    weights.view(-1)[3] = float("nan")
    doc["networks"][name]["encoder.stem.0.weight"] = weights
    torch.save(doc, tmp_path / "nan.pt")
    with pytest.raises(CheckpointError, match=rf"nan.pt: network {name}: encoder.stem.0.weight holds NaN"):
        load_model(tmp_path / "nan.pt")
