"""odolab/learned/deepvo: targets by SE(3) composition, a tiny DeepVO that learns, an LSTM state that
carries across steps and resets between sequences, resumable training, the odometer in compare."""

from __future__ import annotations

import dataclasses
import shutil

import numpy as np
import pytest

torch = pytest.importorskip("torch")  # a declared dependency; skip only where it is truly absent


from odolab.api import Action, integrate, invert, planar_to_transform
from odolab.core.parallel import SERIAL, Execution
from odolab.learned.deepvo import train as trainer
from odolab.learned.deepvo.config import DeepVOModel, DeepVOTraining, load_training
from odolab.learned.deepvo.model import DeepVONet
from odolab.learned.deepvo.odometer import DeepVOOdometer, load_model
from odolab.learned.training import CheckpointError, DataConfig, TrainingData, make_training_data

W, H = 48, 32
NAME = "odolab.learned.deepvo.odometer:DeepVOOdometer"


def _recipe(root, **kw) -> DeepVOTraining:
    data = DataConfig(split="train", episodes=2, max_steps=12, width=W, height=H, episodes_per_shard=1)
    model = DeepVOModel(width=W, height=H, width_scale=1 / 16, hidden=16)
    return DeepVOTraining(
        **{
            "model": model,
            "train_data": data,
            "val_data": dataclasses.replace(data, split="val", episodes=1),
            "data_root": str(root),
            "window": 4,
            "batch": 4,
            "epochs": 2,
            "lr": 2e-3,
            "val_windows": 8,
            "seed": 5,
            **kw,
        }
    )


@pytest.fixture(scope="module")
def recipe(tmp_path_factory) -> DeepVOTraining:
    cfg = _recipe(tmp_path_factory.mktemp("deepvo-data"))
    for dc in (cfg.train_data, cfg.val_data):
        make_training_data(dc, cfg.data_folder(dc), execution=SERIAL)
    return cfg


@pytest.fixture(scope="module")
def trained(recipe, tmp_path_factory):
    root = tmp_path_factory.mktemp("deepvo-run")
    assert trainer.run(
        recipe,
        work=root / "work",
        reports=root / "reports",
        export=root / "model.pt",
        device=torch.device("cpu"),
        hours=None,
        execution=SERIAL,
    )
    return root


def test_targets_reintegrate_to_the_true_poses(recipe):
    """The planar targets come from inv(T_prev) @ T_cur; composed again they give back every true
    camera pose relative to the episode's first (the agent moves in the floor plane), turns included."""
    data = TrainingData(recipe.data_folder(recipe.train_data))
    for episode in np.unique(data.episode):
        k = np.flatnonzero(data.episode[data.pairs] == episode)
        first = data.pairs[k[0]]
        truth = invert(data.poses[first]) @ data.poses[first : first + len(k) + 1]
        rebuilt = integrate(np.stack([planar_to_transform(*p) for p in data.pair_planar[k]]))
        assert np.allclose(rebuilt, truth, atol=1e-6)
        assert np.any(np.abs(data.pair_planar[k, 2]) > 0.4)  # there are 30 degree turns in it


@pytest.mark.slow
def test_a_tiny_deepvo_learns_its_batch(recipe):
    torch.manual_seed(0)
    data = TrainingData(recipe.data_folder(recipe.train_data))
    cfg = dataclasses.replace(recipe.model, dropout=0.0)
    net = DeepVONet(cfg)
    x, target, _ = trainer.window_batch(data, data.windows(4)[:6], 4, cfg)
    target = torch.from_numpy(target).float()
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    losses = []
    for _ in range(60):
        loss = trainer.loss_fn(net(x)[0], target, 100.0)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.2 * losses[0]


def test_a_model_smaller_than_its_data_trains_on_frames_resized_as_the_odometer_resizes(recipe):
    """A recipe may take data larger than its model: the windows' frames are the stored frames
    through resize_frame (what the odometer applies to the camera's frames); a smaller data set, or
    any other size for the robust VO's exact-size check, is refused with both sizes named."""
    from odolab.learned.training import resize_frame

    data = TrainingData(recipe.data_folder(recipe.train_data))
    small = dataclasses.replace(recipe.model, width=W // 2, height=H // 2)
    starts = data.windows(4)[:3]
    x, _, _ = trainer.window_batch(data, starts, 4, small)
    frames = data.pairs[starts][:, None] + np.arange(4)[None]
    rgb, depth = data.frames(frames.ravel())
    want = np.stack([resize_frame(c, d, W // 2, H // 2)[0] for c, d in zip(rgb, depth)])
    assert x.shape == (3, 4, 3, H // 2, W // 2)
    assert torch.equal(x.reshape(-1, 3, H // 2, W // 2), torch.from_numpy(want).movedim(-1, 1) / 255.0 - 0.5)
    assert dataclasses.replace(recipe, model=small).model.width == W // 2  # accepted
    with pytest.raises(ValueError, match=f"train data is {W} x {H} px but the model takes at least {2 * W} x"):
        dataclasses.replace(recipe, model=dataclasses.replace(recipe.model, width=2 * W))
    with pytest.raises(ValueError, match=f"data is {W} x {H} px but the model takes {W // 2} x {H // 2}$"):
        recipe.train_data.require_size(W // 2, H // 2)


@pytest.mark.slow
def test_the_lstm_state_carries_across_steps_and_reset_clears_it(trained, recipe):
    from odolab.sim.episodes import render_episode

    ep = render_episode(dataclasses.replace(recipe.val_data.specs[0], max_steps=6))
    odo = DeepVOOdometer(checkpoint=str(trained / "model.pt"))
    pairs = [(ep[i], ep[i + 1], ep.action(i)) for i in range(len(ep) - 1)]

    def run_once():
        odo.reset(ep.intrinsics)
        return np.stack([odo.step(*p).transform for p in pairs])

    first, second = run_once(), run_once()
    assert np.array_equal(first, second)  # reset: the same sequence gives the same outputs
    odo.reset(ep.intrinsics)
    odo.step(*pairs[2])  # a state left by another step ...
    carried = odo.step(*pairs[0]).transform
    assert not np.allclose(carried, first[0], atol=1e-7)  # ... changes the next answer
    assert np.all(np.isfinite(first))
    assert np.array_equal(odo.step(ep[0], ep[1], Action.STOP).transform, np.eye(4))


@pytest.mark.slow
def test_training_resumes_to_the_same_weights(trained, recipe, tmp_path):
    one = dataclasses.replace(recipe, epochs=1)
    assert trainer.run(
        one,
        work=tmp_path / "w",
        reports=tmp_path / "r",
        export=tmp_path / "one.pt",
        device=torch.device("cpu"),
        hours=None,
        execution=SERIAL,
    )
    moved = tmp_path / "moved-data"  # the data moved (a study's folder moved): the run resumes all the same
    shutil.copytree(recipe.data_root, moved)
    assert trainer.run(
        dataclasses.replace(recipe, data_root=str(moved)),
        work=tmp_path / "w",
        reports=tmp_path / "r",
        export=tmp_path / "two.pt",
        device=torch.device("cpu"),
        hours=None,
        execution=SERIAL,
    )
    a = torch.load(trained / "model.pt", weights_only=True)["networks"]["deepvo"]
    b = torch.load(tmp_path / "two.pt", weights_only=True)["networks"]["deepvo"]
    assert all(torch.equal(a[k], b[k]) for k in a)
    rows = (tmp_path / "r" / "curves.csv").read_text().splitlines()
    assert sum(",val," in r for r in rows) == 2 * 9  # 2 epochs x 3 actions x 3 components
    assert (tmp_path / "r" / "curves.png").stat().st_size > 10_000


@pytest.mark.slow
def test_compare_runs_deepvo_with_finite_errors(trained, tmp_path):
    from odolab.api import ComparisonConfig, run_comparison

    result = run_comparison(
        ComparisonConfig(
            odometers=["action-prior", NAME],
            episodes=1,
            max_steps=6,
            cache=None,
            options={NAME: {"checkpoint": str(trained / "model.pt")}},
            execution=SERIAL,
        )
    )
    row = next(r for r in result.rows if r.odometer == NAME)
    assert np.all(np.isfinite([row.dx, row.dz, row.dyaw, row.ate_m])) and row.failures == 0


@pytest.mark.slow
def test_bad_checkpoints_and_recipes_are_named(trained, tmp_path):
    with pytest.raises(CheckpointError, match="no such checkpoint"):
        load_model(tmp_path / "none.pt")
    robust_like = tmp_path / "x.pt"
    torch.save({"kind": "odolab-robust-vo", "format": 1}, robust_like)
    with pytest.raises(CheckpointError, match="expected a checkpoint of kind 'odolab-deepvo'"):
        load_model(robust_like)
    bad = tmp_path / "r.toml"
    bad.write_text("window = 1\n")
    with pytest.raises(ValueError, match="window must be in"):
        load_training(str(bad))
    assert load_training("studies/deepvo/shipped.toml").model.width_scale == 0.125


@pytest.mark.slow
def test_a_second_stage_starts_from_the_first_stages_model(trained, recipe, tmp_path):
    first = trained / "model.pt"
    _, first_net, info = load_model(first)
    second = dataclasses.replace(recipe, init=str(first), rotation_weight=1.0, epochs=1, lr=1e-12)
    assert trainer.run(
        second,
        work=tmp_path / "w",
        reports=tmp_path / "r",
        export=tmp_path / "m.pt",
        device=torch.device("cpu"),
        hours=None,
        execution=SERIAL,
    )
    _, net, _ = load_model(tmp_path / "m.pt")
    for a, b in zip(first_net.parameters(), net.parameters()):  # lr 1e-12: barely moved (BatchNorm's
        assert torch.allclose(a, b, atol=1e-6)  # running statistics do move)
    state = torch.load(tmp_path / "w" / "deepvo.pt", weights_only=True)
    assert state["identity"]["init_sha256"] == info["sha256"]
    with pytest.raises(ValueError, match="no such model file"):
        trainer.run(
            dataclasses.replace(second, init=str(tmp_path / "none.pt")),
            work=tmp_path / "w2",
            reports=tmp_path / "r2",
            export=tmp_path / "m2.pt",
            device=torch.device("cpu"),
            hours=None,
            execution=SERIAL,
        )
    with pytest.raises(ValueError, match="is this run's --export, which would overwrite it"):
        trainer.run(
            second,
            work=tmp_path / "w4",
            reports=tmp_path / "r4",
            export=first,
            device=torch.device("cpu"),
            hours=None,
            execution=SERIAL,
        )
    with pytest.raises(ValueError, match="is a folder"):
        trainer.run(
            dataclasses.replace(second, init=str(tmp_path)),
            work=tmp_path / "w5",
            reports=tmp_path / "r5",
            export=tmp_path / "m5.pt",
            device=torch.device("cpu"),
            hours=None,
            execution=SERIAL,
        )
    wider = dataclasses.replace(second, model=dataclasses.replace(recipe.model, hidden=8))
    with pytest.raises(ValueError, match="differs from this recipe's in hidden"):
        trainer.run(
            wider,
            work=tmp_path / "w3",
            reports=tmp_path / "r3",
            export=tmp_path / "m3.pt",
            device=torch.device("cpu"),
            hours=None,
            execution=SERIAL,
        )


@pytest.mark.slow
def test_the_command_refuses_a_start_of_another_shape_before_making_its_folders(trained, tmp_path):
    """A recipe whose ``init`` cannot start it is refused by the command in one line naming both
    values, before its --work and --reports are made."""
    from odolab.cli import UsageError
    from odolab.cli.train import train

    work, reports = tmp_path / "w", tmp_path / "r"
    argv = ["--config", "studies/deepvo/shipped.toml", "--set", f"init={trained / 'model.pt'}"]
    with pytest.raises(UsageError, match=r"differs from this recipe's in width \(48 there, 170 here\)"):
        train(
            "deepvo",
            [*argv, "--work", str(work), "--reports", str(reports), "--quiet"],
            "python -m odolab.learned.deepvo.train",
        )
    assert not work.exists() and not reports.exists()


@pytest.mark.slow
@pytest.mark.parametrize("gain", ["depth", "actions"])
def test_a_model_gains_an_input_and_answers_alike(trained, recipe, tmp_path, gain):
    """``init`` may gain the depth input or the action input (zero weights on the new inputs: the
    same answers whatever they hold), never lose one."""
    first = trained / "model.pt"
    _, first_net, _ = load_model(first)
    grown = dataclasses.replace(recipe, init=str(first), model=dataclasses.replace(recipe.model, **{gain: True}))
    state, _ = trainer.first_stage(grown, tmp_path / "m.pt")
    net = DeepVONet(grown.model)
    net.load_state_dict(state)
    first_net.eval(), net.eval()
    torch.manual_seed(1)
    rgb = torch.rand(2, 4, 3, H, W) - 0.5
    depth = torch.rand(2, 4, 1, H, W) - 0.5
    actions = torch.tensor([[1, 2, 3], [3, 1, 1]])
    with torch.no_grad():
        a, _ = first_net(rgb)
        b, _ = net(torch.cat([rgb, depth], dim=2) if gain == "depth" else rgb, actions=actions)
    assert torch.allclose(a, b, atol=1e-6) and a.abs().max() > 1e-3
    trainer.run(
        dataclasses.replace(grown, epochs=1),
        work=tmp_path / "w",
        reports=tmp_path / "r",
        export=tmp_path / "grown.pt",
        device=torch.device("cpu"),
        hours=None,
        execution=SERIAL,
    )
    back = dataclasses.replace(recipe, init=str(tmp_path / "grown.pt"))
    with pytest.raises(ValueError, match="not lose it"):
        trainer.first_stage(back, tmp_path / "m2.pt")


@pytest.mark.slow
def test_a_deepvo_with_actions_needs_them(trained, recipe, tmp_path):
    """A model trained with ``actions`` answers each step by the action given (another action,
    another answer), refuses a step without one, and its network names a missing action input."""
    from odolab.api import load_odometer
    from odolab.sim.episodes import EpisodeSpec, render_episode

    first = trained / "model.pt"
    grown = dataclasses.replace(
        recipe, init=str(first), model=dataclasses.replace(recipe.model, actions=True), epochs=1
    )
    trainer.run(
        grown,
        work=tmp_path / "w",
        reports=tmp_path / "r",
        export=tmp_path / "a.pt",
        device=torch.device("cpu"),
        hours=None,
        execution=SERIAL,
    )
    _, net, _ = load_model(tmp_path / "a.pt")
    with pytest.raises(ValueError, match="takes the action of each pair"):
        net(torch.zeros(1, 2, 3, H, W))
    ep = render_episode(EpisodeSpec(split="test", index=0, seed=0, max_steps=4))
    answers = {}
    for action in (Action.MOVE_FORWARD, Action.TURN_LEFT):
        odo = load_odometer(NAME, checkpoint=str(tmp_path / "a.pt"))
        odo.reset(ep.intrinsics)
        answers[action] = odo.step(ep[0], ep[1], action).planar
    assert odo.needs_action and not odo.step(ep[0], ep[1], None).valid
    assert not np.allclose(answers[Action.MOVE_FORWARD], answers[Action.TURN_LEFT])


def test_validation_windows_do_not_share_pairs():
    starts = np.array([0, 1, 2, 3, 4, 5, 9, 10, 20])
    assert trainer.disjoint(starts, 3).tolist() == [0, 3, 9, 20]


def test_the_shipped_deepvo_is_registered_and_runs_in_a_comparison():
    from odolab.api import ComparisonConfig, load_odometer, run_comparison

    odo = load_odometer("deepvo")
    assert odo.identity_digest and odo.cfg.width == 170  # the shipped file, reduced resolution
    result = run_comparison(
        ComparisonConfig(odometers=["deepvo"], episodes=1, max_steps=6, execution=Execution(parallel=False))
    )
    row = next(r for r in result.rows if r.odometer == "deepvo")
    assert row.steps == 6 and row.failure_share == 0.0
    assert all(np.isfinite(getattr(row, c)) for c in ("dx", "dz", "dyaw"))


@pytest.mark.slow
def test_a_model_too_large_for_float32_is_stored_in_float16_and_answers_alike(trained, recipe, tmp_path, monkeypatch):
    from odolab.learned.deepvo.odometer import save_model
    from odolab.learned.training import checkpoints

    model, net, info = load_model(trained / "model.pt")
    assert torch.load(trained / "model.pt", weights_only=True)["weights_dtype"] == "float32"
    monkeypatch.setattr(checkpoints, "MAX_MODEL_BYTES", 1000)  # this tiny model counts as too large
    save_model(tmp_path / "half.pt", recipe, net, info["training"])
    doc = torch.load(tmp_path / "half.pt", weights_only=True)
    assert doc["weights_dtype"] == "float16"
    assert {v.dtype for v in doc["networks"]["deepvo"].values() if v.is_floating_point()} == {torch.float16}
    _, half, _ = load_model(tmp_path / "half.pt")
    assert {p.dtype for p in half.parameters()} == {torch.float32}  # cast back on loading
    x = torch.rand(1, 3, model.frame_channels, H, W)
    with torch.no_grad():
        a, b = net(x)[0], half(x)[0]
    assert torch.allclose(a, b, rtol=1e-2, atol=1e-3) and not torch.equal(a, b)


def test_the_deepvo_export_never_replaces_its_training_state_and_saving_never_replaces_a_recipe(tmp_path):
    torch = pytest.importorskip("torch")
    from odolab.cli import UsageError
    from odolab.cli.train import parse_training_command, training_parser
    from odolab.learned.deepvo.config import load_training
    from odolab.learned.deepvo.train import state_files
    from odolab.learned.training import CheckpointError
    from odolab.learned.training.checkpoints import save_model

    recipe = tmp_path / "deepvo.toml"
    recipe.write_text("epochs = 1\n")
    ap = training_parser("python -m odolab.learned.deepvo.train", "train", "deepvo")
    with pytest.raises(UsageError, match="found the file where the DeepVO training keeps its training state"):
        parse_training_command(
            ap,
            [
                "--config",
                str(recipe),
                "--work",
                str(tmp_path / "work"),
                "--reports",
                str(tmp_path / "r"),
                "--export",
                str(tmp_path / "work" / "deepvo.pt"),
            ],
            load_training,
            state_files,
        )
    cfg = load_training(str(recipe))
    with pytest.raises(CheckpointError, match="found a file that is not an odolab model"):
        save_model(recipe, "odolab-deepvo", cfg, {"net": torch.nn.Linear(1, 1)}, {})
    assert recipe.read_text() == "epochs = 1\n"
    model = tmp_path / "m.pt"
    save_model(model, "odolab-deepvo", cfg, {"net": torch.nn.Linear(1, 1)}, {})
    save_model(model, "odolab-deepvo", cfg, {"net": torch.nn.Linear(1, 1)}, {})  # a model it exported: replaced
