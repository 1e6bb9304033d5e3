"""examples/tiny_learned.py: trained through odolab.api, loaded from the command line with a
checkpoint option, read with weights_only=True, and its estimates follow its weights."""

import csv

import numpy as np
import pytest

torch = pytest.importorskip("torch")  # a declared dependency; skip only where it is truly absent

from examples import tiny_learned as tl
from odolab import api
from odolab.cli import run_cli
from odolab.compare import main as compare

NAME = "examples.tiny_learned:TinyLearnedOdometer"


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    root = tmp_path_factory.mktemp("tiny")
    path = root / "tiny.pt"
    args = [
        "--episodes",
        "2",
        "--max-steps",
        "6",
        "--iterations",
        "25",
        "--cache",
        str(root / "cache"),
        "--out",
        str(path),
    ]
    assert tl.main(args) == 0 and path.stat().st_size > 0
    return path


def _pair():
    ep = api.load_episodes(api.episode_specs("test", 1, max_steps=3), None, execution=api.SERIAL)[0]
    return ep[0], ep[1], ep.action(0)


def test_the_network_is_tiny(checkpoint):
    _cfg, net = tl.load_checkpoint(checkpoint)
    assert 1000 < sum(p.numel() for p in net.parameters()) < 10000


def test_compare_runs_it_with_a_checkpoint_option(checkpoint, tmp_path, monkeypatch):
    calls = []
    real_load = torch.load

    def spy(*args, **kw):
        calls.append(kw.get("weights_only"))
        return real_load(*args, **kw)

    monkeypatch.setattr(torch, "load", spy)
    out = tmp_path / "run"
    args = [
        "--odometers",
        f"action-prior,{NAME}",
        "--odometer-option",
        f"{NAME}.checkpoint={checkpoint}",
        "--odometer-option",
        f"{NAME}.batch_size=4",
        "--episodes",
        "1",
        "--max-steps",
        "8",
        "--serial",
        "--quiet",
        "--no-cache",
        "--out",
        str(out),
    ]
    assert run_cli(compare, "odolab.compare", args) == 0
    rows = {r["odometer"]: r for r in csv.DictReader((out / "table.csv").read_text().splitlines())}
    assert int(rows[NAME]["failures"]) == 0 and float(rows[NAME]["dz"]) >= 0
    assert calls == [True]


def test_estimates_follow_the_weights(checkpoint, tmp_path):
    prev, cur, action = _pair()
    base = tl.TinyLearnedOdometer(str(checkpoint)).step(prev, cur, action).planar
    cfg, net = tl.load_checkpoint(checkpoint)
    with torch.no_grad():
        net.head[-1].bias += torch.tensor([0.0, 0.5, 0.0])  # +0.5 output units of dz
    shifted = tmp_path / "shifted.pt"
    tl.save_checkpoint(shifted, cfg, net)
    moved = tl.TinyLearnedOdometer(str(shifted)).step(prev, cur, action).planar
    assert moved - base == pytest.approx([0.0, 0.5 * tl.CORRECTION_SCALE[1], 0.0], abs=1e-5)
    # and training moved the weights away from a fresh network's
    fresh = tl.TinyNet(cfg)
    assert not all(torch.equal(a, b) for a, b in zip(fresh.state_dict().values(), net.state_dict().values()))


def test_batched_and_single_steps_agree(checkpoint):
    prev, cur, action = _pair()
    odo = tl.TinyLearnedOdometer(str(checkpoint))
    one = odo.step(prev, cur, action).planar
    batch = odo.step_batch([(prev, cur, action), (cur, prev, action)])
    assert batch[0].planar == pytest.approx(one, abs=1e-6)


def test_a_checkpoint_with_pickled_code_is_refused(tmp_path):
    import argparse

    bad = tmp_path / "bad.pt"
    # any class beyond tensors and plain containers needs the unsafe unpickler to be rebuilt
    torch.save({"format": tl.CHECKPOINT_FORMAT, "config": argparse.Namespace(height=24), "state_dict": {}}, bad)
    with pytest.raises(Exception, match="could not load odometer") as info:
        compare(
            [
                "--odometers",
                NAME,
                "--odometer-option",
                f"{NAME}.checkpoint={bad}",
                "--episodes",
                "1",
                "--max-steps",
                "3",
                "--serial",
                "--quiet",
                "--no-cache",
                "--out",
                str(tmp_path / "o"),
            ]
        )
    assert "Weights only load failed" in str(info.value) or "weights_only" in str(info.value)


def test_the_runner_applies_an_odometers_torch_threads_and_restores_them():
    from odolab.odometry.action_prior import ActionPrior
    from odolab.running import runner

    class Watcher(api.Odometer):
        threads = 1

        def reset(self, intrinsics):
            super().reset(intrinsics)
            self.seen = {torch.get_num_threads()}

        def step(self, prev, cur, action):
            self.seen.add(torch.get_num_threads())
            return api.Estimate(np.eye(4))

    ep = api.load_episodes(api.episode_specs("test", 1, max_steps=3), None, execution=api.SERIAL)[0]
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        odo = Watcher()
        runner.run_sequence(odo, ep, "watcher", ActionPrior.shipped())
        assert odo.seen == {1} and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


@pytest.mark.parametrize(
    "args,words",
    [
        (["--episodes", str(10**9)], "--episodes must be in [1, 1000]"),
        (["--iterations", str(10**12)], "--iterations must be in [1, 1000000]"),
        (["--seed", "-1"], "--seed must be in [0, 4294967295]"),
    ],
)
def test_the_example_trainer_checks_its_integers_first(args, words, capsys):
    pytest.importorskip("torch")
    from examples import tiny_learned

    with pytest.raises(SystemExit) as info:
        tiny_learned.main(args)
    assert info.value.code == 2 and words in capsys.readouterr().err
