"""The robust VO (odolab/learned/robust_vo): inputs psi, the motion maps behind its augmentations, the GeoInv
loss, training (loss falls, resumes bit for bit), checkpoints and the odometer. Tiny models on tiny
data: 48 x 32 px, 8 base planes."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")  # a declared dependency; skip only where it is truly absent

from odolab.api import Action, Intrinsics, invert, load_odometer, transform_to_planar
from odolab.core.parallel import SERIAL
from odolab.learned.robust_vo import train as trainer
from odolab.learned.robust_vo.batches import Samples, make_batch, stage_samples
from odolab.learned.robust_vo.checkpoint import load_model, save_model
from odolab.learned.robust_vo.config import ModelConfig, StageConfig, TrainConfig, load_train_config
from odolab.learned.robust_vo.inputs import frame_channels, pair_channels, top_down_projection
from odolab.learned.robust_vo.model import build_networks, predict
from odolab.learned.robust_vo.motion import compose, geoinv_loss, inverse, mirror, swap_action
from odolab.learned.robust_vo.odometer import RobustVOOdometer
from odolab.learned.training import CheckpointError, ConfigError, DataConfig, TrainingData, make_training_data
from odolab.learned.training.checkpoints import load_checkpoint
from odolab.learned.training.epochs import STATE_FORMAT, STATE_KIND
from odolab.sim.camera import CameraSpec
from odolab.sim.episodes import EpisodeSpec, NoiseConfig, render_episode

W, H = 48, 32
TINY = ModelConfig(width=W, height=H, base_planes=8, groups=4, hidden=32, compress_channels=8, dropout=0.2)
S = np.diag([-1.0, 1.0, 1.0, 1.0])  # the left-right mirror in camera axes (x right)


def _recipe(root, stages=None, **model) -> TrainConfig:
    data = DataConfig(split="train", episodes=2, max_steps=12, width=W, height=H, episodes_per_shard=1)
    val = dataclasses.replace(data, split="val", episodes=1)
    stages = stages or (
        StageConfig("forward", ("move_forward",), 1, lr=1e-3, batch=8),
        StageConfig("turns", ("turn_left", "turn_right"), 1, lr=1e-3, batch=8, data_aug=True),
        StageConfig("joint", ("turn_left", "turn_right"), 1, lr=5e-4, batch=8, geoinv=True),
    )
    return TrainConfig(
        model=dataclasses.replace(TINY, **model),
        stages=tuple(stages),
        train_data=data,
        val_data=val,
        data_root=str(root),
        val_pairs=20,
        seed=3,
    )


@pytest.fixture(scope="module")
def recipe(tmp_path_factory) -> TrainConfig:
    cfg = _recipe(tmp_path_factory.mktemp("vo-data"))
    for data in (cfg.train_data, cfg.val_data):
        make_training_data(data, cfg.data_folder(data), execution=SERIAL)
    return cfg


@pytest.fixture(scope="module")
def data(recipe) -> TrainingData:
    return TrainingData(recipe.data_folder(recipe.train_data))


@pytest.fixture(scope="module")
def trained(recipe, tmp_path_factory):
    """The tiny recipe trained once, every stage, exported."""
    root = tmp_path_factory.mktemp("vo-run")
    done = trainer.run(
        recipe,
        work=root / "work",
        reports=root / "reports",
        export=root / "model.pt",
        device=torch.device("cpu"),
        hours=None,
        execution=SERIAL,
    )
    assert done
    return root


# --- inputs -----------------------------------------------------------------------------------------


def test_pair_channels_are_the_papers_30_with_one_hot_depth_bins():
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.0, 10.0, (2, 2, H, W)).astype(np.float32)
    depth[0, 0, :3] = 0.0  # holes
    depth[0, 0, 3, :5] = 10.0  # the last bin is closed
    rgb = rng.integers(0, 256, (2, 2, H, W, 3), dtype=np.uint8)
    K = CameraSpec().intrinsics.resized(W, H)
    cfg = ModelConfig(width=W, height=H)
    x = pair_channels(torch.from_numpy(rgb), torch.from_numpy(depth), K, cfg)
    assert x.shape == (2, 30, H, W)
    prev = x[0, :15]
    assert torch.allclose(prev[:3], torch.from_numpy(rgb[0, 0]).permute(2, 0, 1).float() / 255)
    assert torch.allclose(prev[3], torch.from_numpy(depth[0, 0]) / 10)
    bins = prev[4:14]
    assert torch.equal(bins.sum(0), torch.ones(H, W))
    assert bins[0, :3].eq(1).all() and bins[9, 3, :5].eq(1).all()
    k = np.clip((depth[0, 0] / 10 * 10).astype(int), 0, 9)
    assert torch.equal(bins.argmax(0), torch.from_numpy(k))
    # every switch changes the channel count as the config says
    for visual, dd, sproj, n in (("rgb", 0, False, 3), ("depth", 5, False, 6), ("rgbd", 20, True, 25)):
        c = ModelConfig(width=W, height=H, visual=visual, dd_bins=dd, sproj=sproj)
        assert c.channels_per_frame == n
        assert frame_channels(torch.from_numpy(rgb[0]), torch.from_numpy(depth[0]), K, c).shape == (2, n, H, W)


def test_frame_channels_write_the_same_numbers_into_a_slice_of_channels_last_memory():
    g = np.random.default_rng(0)
    rgb = torch.from_numpy(g.integers(0, 256, (2, H, W, 3), dtype=np.uint8))
    depth = torch.from_numpy(g.uniform(0.0, 12.0, (2, H, W)).astype(np.float32))
    K = CameraSpec().intrinsics.resized(W, H)
    cfg = ModelConfig(width=W, height=H)
    x = torch.full((2, H, W, 2 * cfg.channels_per_frame + 1), float("nan")).permute(0, 3, 1, 2)
    c = cfg.channels_per_frame
    frame_channels(rgb, depth, K, cfg, out=x[:, c : 2 * c])
    assert torch.equal(x[:, c : 2 * c], frame_channels(rgb, depth, K, cfg))
    assert x[:, :c].isnan().all() and x[:, 2 * c :].isnan().all()  # nothing written outside the slice
    assert x.is_contiguous(memory_format=torch.channels_last)
    with pytest.raises(ValueError, match="float32"):  # another precision would round psi silently
        frame_channels(rgb, depth, K, cfg, out=x[:, :c].double())


@pytest.mark.parametrize("warp", ["none", "nominal"])
def test_the_odometer_computes_a_shared_frame_once_with_the_numbers_of_fresh_frames(warp, tmp_path):
    """Consecutive pairs share a frame (its psi copied from the last pair, with or without the warp),
    and the answers equal those for new arrays at every step, one pair or four per network pass."""
    torch.manual_seed(0)
    model = dataclasses.replace(TINY, warp=warp)
    nets = build_networks(model)
    with torch.no_grad():  # an untrained head answers the same for every input: weights that depend on it
        for p in nets.parameters():
            p.add_(0.1 * torch.randn_like(p))
    save_model(tmp_path / "m.pt", _recipe(tmp_path, warp=warp), nets, {})
    ep = render_episode(EpisodeSpec(split="val", index=0, seed=0, max_steps=6))
    frames = [ep[i] for i in range(len(ep))]
    shared = [(frames[i], frames[i + 1], ep.action(i)) for i in range(len(ep) - 1)]
    fresh = [(ep[i], ep[i + 1], ep.action(i)) for i in range(len(ep) - 1)]
    answers = []
    for batch_size, pairs in ((1, shared), (4, shared), (1, fresh)):
        odo = RobustVOOdometer(checkpoint=str(tmp_path / "m.pt"), batch_size=batch_size)
        odo.reset(ep.intrinsics)
        answers.append(
            np.array(
                [
                    e.transform
                    for i in range(0, len(pairs), batch_size)
                    for e in odo.step_batch(pairs[i : i + batch_size])
                ]
            )
        )
    assert np.array_equal(answers[0], answers[2])
    assert np.allclose(answers[0], answers[1], atol=1e-5)  # another batch size: oneDNN may sum in another order
    assert len({a.tobytes() for a in answers[0]}) == len(fresh)  # every step differs: its input reached the network


def test_input_ms_times_the_input_and_leaves_the_next_steps_answers_as_they_were(tmp_path):
    """The odometer's input timing (the bench's ``input_ms``) needs a reset, gives a positive time, and
    the steps after it answer exactly as those of an odometer that was never timed."""
    torch.manual_seed(0)
    nets = build_networks(TINY)
    save_model(tmp_path / "m.pt", _recipe(tmp_path), nets, {})
    ep = render_episode(EpisodeSpec(split="val", index=0, seed=0, max_steps=4))
    pairs = [(ep[i], ep[i + 1], ep.action(i)) for i in range(len(ep) - 1)]
    timed, plain = (RobustVOOdometer(checkpoint=str(tmp_path / "m.pt")) for _ in range(2))
    with pytest.raises(RuntimeError, match="reset"):
        timed.input_ms(*pairs[0])
    answers = []
    for odo in (timed, plain):
        odo.reset(ep.intrinsics)
        first = odo.step(*pairs[0])
        if odo is timed:
            ms = odo.input_ms(*pairs[-1], calls=3)  # another pair than the one the next step shares
            assert np.isfinite(ms) and ms > 0
        answers.append(np.array([first.transform] + [odo.step(*p).transform for p in pairs[1:]]))
    assert np.array_equal(answers[0], answers[1])


def test_top_down_projection_puts_a_wall_at_its_distance_and_centre():
    """A fronto-parallel wall at 4 m fills one row of the projection (4 m of 10 up from the bottom),
    centred left-right; a wall only in the image's left half lands left of centre."""
    K = CameraSpec().intrinsics.resized(W, H)
    depth = torch.full((2, H, W), 4.0)
    depth[1, :, W // 2 :] = 0.0
    proj = top_down_projection(depth, K, max_depth=10.0, rows=1.0)
    rows = torch.nonzero(proj[0].sum(1)).flatten()
    expected = (H - 1) - int(np.floor((4.0 - 0.1) / 9.9 * H))
    assert rows.tolist() == [expected]
    cols = torch.nonzero(proj[0, expected]).flatten().float()
    assert abs(cols.mean().item() - (W - 1) / 2) < 1.0
    assert proj[0].max() == 1.0
    assert torch.nonzero(proj[1, expected]).flatten().float().max() < (W - 1) / 2


# --- motion maps, checked against the simulator ---------------------------------------------------


@pytest.fixture(scope="module")
def noiseless_episode():
    spec = EpisodeSpec(
        split="test",
        index=2,
        seed=0,
        max_steps=14,
        camera=CameraSpec(width=160, height=90),
        noise=NoiseConfig(rgb=0.0, depth=0.0, actuation=0.5),
    )
    return render_episode(spec)


def test_frame_swap_and_mirror_map_true_motions_to_the_right_ones(noiseless_episode):
    ep = noiseless_episode
    motions = invert(ep.poses[:-1]) @ ep.poses[1:]
    planar = torch.tensor(np.stack([transform_to_planar(m) for m in motions]))
    swapped = torch.tensor(np.stack([transform_to_planar(invert(m)) for m in motions]))
    mirrored = torch.tensor(np.stack([transform_to_planar(S @ m @ S) for m in motions]))
    assert torch.allclose(inverse(planar), swapped, atol=1e-9)
    assert torch.allclose(mirror(planar), mirrored, atol=1e-9)
    assert torch.allclose(compose(planar, inverse(planar)), torch.zeros_like(planar), atol=1e-12)
    # and the actions they stand for: a reversed or mirrored left turn turns right
    for k, a in enumerate(ep.actions):
        if Action(int(a)) in (Action.TURN_LEFT, Action.TURN_RIGHT):
            sign = 1 if Action(int(a)) is Action.TURN_LEFT else -1
            assert sign * planar[k, 2] > 0.3 and sign * swapped[k, 2] < -0.3 and sign * mirrored[k, 2] < -0.3
    assert swap_action(np.array([1, 2, 3])).tolist() == [1, 3, 2]


def test_mirrored_images_move_by_the_mirrored_motion(noiseless_episode):
    """Depth of frame t flipped left-right, back-projected, moved by S T S (the mirror of the true
    motion T) and projected into frame t+1 flipped agrees with it: flipping the images is exactly the
    motion :func:`mirror` gives (with the pixel convention cx = (W - 1) / 2)."""
    ep = noiseless_episode
    K = ep.intrinsics
    checked = 0
    for t in range(len(ep) - 1):
        if Action(int(ep.actions[t])) is not Action.TURN_LEFT and checked:
            continue
        T = invert(ep.poses[t]) @ ep.poses[t + 1]
        da, db = ep.depth[t][:, ::-1], ep.depth[t + 1][:, ::-1]
        v, u = np.nonzero(da > 0)
        z = da[v, u].astype(np.float64)
        pts = np.stack([(u - K.cx) / K.fx * z, (v - K.cy) / K.fy * z, z, np.ones_like(z)], -1)
        pb = (invert(S @ T @ S) @ pts.T).T
        ub = np.round(K.fx * pb[:, 0] / pb[:, 2] + K.cx).astype(int)
        vb = np.round(K.fy * pb[:, 1] / pb[:, 2] + K.cy).astype(int)
        ok = (ub >= 0) & (ub < K.width) & (vb >= 0) & (vb < K.height) & (pb[:, 2] > 0)
        diff = np.abs(db[vb[ok], ub[ok]] - pb[ok, 2])
        assert np.median(diff) < 0.02  # metres, at the nearest pixel
        # the unmirrored motion does not fit the mirrored images (unless it is straight ahead)
        if abs(transform_to_planar(T)[2]) > 0.3:
            wrong = (invert(T) @ pts.T).T
            uw = np.round(K.fx * wrong[:, 0] / wrong[:, 2] + K.cx).astype(int)
            vw = np.round(K.fy * wrong[:, 1] / wrong[:, 2] + K.cy).astype(int)
            okw = (uw >= 0) & (uw < K.width) & (vw >= 0) & (vw < K.height) & (wrong[:, 2] > 0)
            assert okw.sum() < 0.2 * ok.sum() or np.median(np.abs(db[vw[okw], uw[okw]] - wrong[okw, 2])) > 0.1
        checked += 1
    assert checked >= 2


def test_geoinv_loss_is_zero_exactly_for_consistent_predictions():
    ab = torch.tensor([[0.03, 0.24, 0.02], [0.01, 0.0, 0.52], [-0.02, 0.01, -0.5]], dtype=torch.float64)
    assert geoinv_loss(ab, inverse(ab)).item() < 1e-20
    assert geoinv_loss(ab, inverse(ab) + torch.tensor([0.0, 0.0, 0.01], dtype=torch.float64)).item() > 1e-5
    assert geoinv_loss(ab, inverse(ab) + torch.tensor([0.01, 0.0, 0.0], dtype=torch.float64)).item() > 1e-5


# --- data, samples, batches -----------------------------------------------------------------------


def test_training_data_pairs_carry_the_episodes_true_motions(recipe, data):
    spec = recipe.train_data.specs[1]
    ep = render_episode(spec)
    mine = np.flatnonzero(data.episode[data.pairs] == spec.index)
    assert len(mine) == len(ep.actions)
    truth = invert(ep.poses[:-1]) @ ep.poses[1:]
    assert np.allclose(data.pair_motion[mine], truth)
    assert data.pair_actions[mine].tolist() == ep.actions.astype(int).tolist()
    b = data.pair_batch(mine[:2])
    assert b["rgb"].shape == (2, 2, H, W, 3) and b["depth"].shape == (2, 2, H, W)
    assert np.array_equal(b["rgb"][1, 0], b["rgb"][0, 1])  # consecutive pairs share a frame
    assert data.intrinsics == CameraSpec().intrinsics.resized(W, H)


def test_stage_samples_follow_the_switches(data):
    n = data.counts()
    fwd = stage_samples(data, StageConfig("f", ("move_forward",), 1))
    assert len(fwd) == n["move_forward"] and not fwd.swap.any()
    turns = stage_samples(data, StageConfig("t", ("turn_left", "turn_right"), 1, data_aug=True))
    assert len(turns) == 2 * (n["turn_left"] + n["turn_right"]) and turns.swap.sum() == len(turns) // 2
    left = stage_samples(data, StageConfig("l", ("turn_left",), 1, data_aug=True, mirror=True))
    # left pairs, swapped right pairs, mirrored right pairs, mirrored and swapped left pairs
    assert len(left) == 2 * n["turn_left"] + 2 * n["turn_right"]
    geo = stage_samples(data, StageConfig("g", ("turn_left", "turn_right"), 1, geoinv=True))
    assert len(geo) == n["turn_left"] + n["turn_right"] and not geo.swap.any()


def test_blocked_forward_pairs_are_repeated_and_nothing_else():
    from types import SimpleNamespace

    acts = np.array([Action.MOVE_FORWARD.value] * 4 + [Action.TURN_LEFT.value, Action.TURN_RIGHT.value])
    planar = np.array([[0, 0.25, 0], [0, 0.01, 0], [0, 0.2, 0], [0, 0.1, 0], [0, 0.0, 0.5], [0, 0.0, -0.5]])
    fake = SimpleNamespace(pair_actions=acts, pair_planar=planar)
    once = stage_samples(fake, StageConfig("f", ("move_forward",), 1))
    thrice = stage_samples(fake, StageConfig("f", ("move_forward",), 1, blocked_repeat=3))
    assert sorted(once.pair.tolist()) == [0, 1, 2, 3]
    assert sorted(thrice.pair.tolist()) == [0, 1, 1, 1, 2, 3, 3, 3]  # 0.01 and 0.1 m: under half a step
    mirrored = stage_samples(fake, StageConfig("m", ("move_forward",), 1, mirror=True, blocked_repeat=2))
    assert sorted(zip(mirrored.pair.tolist(), mirrored.flip.tolist())).count((1, True)) == 2
    with pytest.raises(ValueError, match="this stage has no move_forward"):
        StageConfig("t", ("turn_left", "turn_right"), 1, blocked_repeat=5)
    with pytest.raises(ValueError, match="blocked_repeat"):
        StageConfig("f", ("move_forward",), 1, blocked_repeat=0)


def test_a_batch_swaps_and_mirrors_frames_targets_and_actions_together(data):
    k = int(data.select([Action.TURN_LEFT])[0])
    plain = make_batch(data, Samples(np.array([k]), np.array([False]), np.array([False])), TINY, torch.device("cpu"))
    swap = make_batch(data, Samples(np.array([k]), np.array([True]), np.array([False])), TINY, torch.device("cpu"))
    flip = make_batch(data, Samples(np.array([k]), np.array([False]), np.array([True])), TINY, torch.device("cpu"))
    c = TINY.channels_per_frame
    assert torch.equal(swap.x[0, :c], plain.x[0, c:]) and torch.equal(swap.x[0, c:], plain.x[0, :c])
    assert torch.equal(flip.x[0, :3], plain.x[0, :3].flip(-1))  # RGB of the first frame, mirrored
    assert plain.action[0] == Action.TURN_LEFT.value
    assert swap.action[0] == flip.action[0] == Action.TURN_RIGHT.value
    assert torch.allclose(swap.target, inverse(plain.target)) and torch.allclose(flip.target, mirror(plain.target))


# --- training -------------------------------------------------------------------------------------


@pytest.mark.slow
def test_a_tiny_model_learns_its_batch(data):
    torch.manual_seed(0)
    cfg = dataclasses.replace(TINY, dropout=0.0)
    nets = build_networks(cfg)
    idx = data.select([Action.MOVE_FORWARD, Action.TURN_LEFT, Action.TURN_RIGHT])[:8]
    batch = make_batch(data, Samples(idx, np.zeros(len(idx), bool), np.zeros(len(idx), bool)), cfg, torch.device("cpu"))
    opt = torch.optim.Adam(nets.parameters(), lr=2e-3)
    losses = []
    for _ in range(40):
        loss = (predict(nets, cfg, batch.x, batch.action) - batch.target).pow(2).sum(1).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.2 * losses[0]


@pytest.mark.slow
def test_training_writes_curves_and_a_model_that_loads(trained, recipe):
    rows = (trained / "reports" / "curves.csv").read_text().splitlines()
    header = rows[0].split(",")
    assert {"epoch", "split", "stage", "action", "component", "mae", "prior_mae"} <= set(header)
    val = [r for r in rows[1:] if ",val," in r]
    assert len(val) == 1 * 3 + 2 * 3 + 2 * 3  # per stage: its actions x components
    status = json.loads((trained / "reports" / "training.json").read_text())
    assert [s["epochs_done"] for s in status["stages"].values()] == [1, 1, 1]
    assert (trained / "reports" / "curves.png").stat().st_size > 10_000
    cfg, nets, info = load_model(trained / "model.pt")
    assert cfg == recipe.model and set(nets) == {"move_forward", "turn_left", "turn_right"}
    assert info["recipe"]["seed"] == recipe.seed
    # once the model is exported every stage keeps its networks, not Adam's moments
    states = [load_checkpoint(trained / "work" / f"{s.name}.pt", STATE_KIND, STATE_FORMAT) for s in recipe.stages]
    assert ["optimizer" in d for d in states] == [False] * len(states)
    assert all(d["modules"] for d in states)


@pytest.mark.slow
def test_an_interrupted_run_resumes_to_the_same_weights(trained, recipe, tmp_path):
    """Stopped after the first stage (here: a recipe of that stage alone), then the whole recipe
    again: the same weights, bit for bit, as the run that was never stopped."""
    work = tmp_path / "work"
    first = dataclasses.replace(recipe, stages=recipe.stages[:1])
    assert trainer.run(
        first,
        work=work,
        reports=tmp_path / "r",
        export=tmp_path / "first.pt",
        device=torch.device("cpu"),
        hours=None,
        execution=SERIAL,
    )
    stopped = trainer.run(
        recipe,
        work=work,
        reports=tmp_path / "r",
        export=tmp_path / "m.pt",
        device=torch.device("cpu"),
        hours=1e-9,
        execution=SERIAL,
    )
    assert not stopped and not (tmp_path / "m.pt").exists()
    assert trainer.run(
        recipe,
        work=work,
        reports=tmp_path / "r",
        export=tmp_path / "m.pt",
        device=torch.device("cpu"),
        hours=None,
        execution=SERIAL,
    )
    a, b = torch.load(trained / "model.pt", weights_only=True), torch.load(tmp_path / "m.pt", weights_only=True)
    for name in a["networks"]:
        for key, value in a["networks"][name].items():
            assert torch.equal(value, b["networks"][name][key]), (name, key)


@pytest.mark.slow
def test_a_changed_recipe_does_not_continue_an_old_run(trained, recipe):
    changed = dataclasses.replace(recipe, model=dataclasses.replace(recipe.model, dd_bins=5))
    with pytest.raises(ValueError, match="another run"):
        trainer.run(
            changed,
            work=trained / "work",
            reports=trained / "r2",
            export=trained / "x.pt",
            device=torch.device("cpu"),
            hours=None,
            execution=SERIAL,
        )


# --- checkpoints and the odometer -----------------------------------------------------------------


def _pairs(recipe):
    spec = dataclasses.replace(recipe.val_data.specs[0], max_steps=8)
    ep = render_episode(spec)
    frames = [ep[i] for i in range(len(ep))]
    return [(frames[i], frames[i + 1], ep.action(i)) for i in range(len(ep) - 1)], ep


@pytest.mark.slow
def test_the_odometer_is_deterministic_and_reads_weights_only(trained, recipe, monkeypatch):
    calls = []
    real = torch.load
    monkeypatch.setattr(torch, "load", lambda *a, **k: calls.append(k.get("weights_only")) or real(*a, **k))
    odo = load_odometer("odolab.learned.robust_vo.odometer:RobustVOOdometer", checkpoint=str(trained / "model.pt"))
    assert calls == [True]
    pairs, ep = _pairs(recipe)
    odo.reset(ep.intrinsics)
    one = [odo.step(*p).transform for p in pairs]  # consecutive pairs share a frame: psi computed once
    fresh = [(ep[i], ep[i + 1], ep.action(i)) for i in range(len(ep) - 1)]  # new arrays every time
    two = [e.transform for e in odo.step_batch(fresh)]
    assert all(np.allclose(a, b, atol=1e-5) for a, b in zip(one, two))
    assert all(np.array_equal(a, odo.step(*p).transform) for a, p in zip(one, fresh))
    stop = odo.step(pairs[0][0], pairs[0][1], Action.STOP)
    assert np.array_equal(stop.transform, np.eye(4))
    assert not odo.step(pairs[0][0], pairs[0][1], None).valid  # SepAct needs the action


@pytest.mark.slow
def test_mc_dropout_gives_a_covariance_and_mirror_tta_runs(trained, recipe):
    pairs, ep = _pairs(recipe)
    odo = RobustVOOdometer(checkpoint=str(trained / "model.pt"), mc_samples=8, mirror_tta=True)
    odo.reset(ep.intrinsics)
    est = odo.step(*pairs[0])
    cov = est.covariance
    assert cov.shape == (6, 6) and np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > 0)
    assert cov[1, 1] > 1e-8 and cov[5, 5] > 1e-8  # yaw and forward spread from dropout


@pytest.mark.slow
def test_checkpoint_errors_name_the_file(trained, tmp_path):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="bad.pt: not a readable torch checkpoint"):
        load_model(bad)
    with pytest.raises(CheckpointError, match="no such checkpoint"):
        load_model(tmp_path / "missing.pt")
    other = tmp_path / "other.pt"
    torch.save({"kind": "something-else", "format": 1}, other)
    with pytest.raises(CheckpointError, match="expected a checkpoint of kind 'odolab-robust-vo'"):
        load_model(other)
    doc = torch.load(trained / "model.pt", weights_only=True)
    doc["model"]["base_planes"] = 16
    torch.save(doc, tmp_path / "mismatch.pt")
    with pytest.raises(CheckpointError, match="do not fit the odolab-robust-vo config"):
        load_model(tmp_path / "mismatch.pt")


def test_save_and_load_round_trip(recipe, tmp_path):
    torch.manual_seed(1)
    nets = build_networks(recipe.model).eval()
    save_model(tmp_path / "m.pt", recipe, nets, {"note": "test"})
    cfg, loaded, info = load_model(tmp_path / "m.pt")
    x = torch.randn(2, 2 * cfg.channels_per_frame, H, W)
    acts = np.array([Action.TURN_LEFT.value, Action.MOVE_FORWARD.value])
    with torch.inference_mode():
        assert torch.equal(predict(nets, cfg, x, acts), predict(loaded, cfg, x, acts))
    assert info["training"] == {"note": "test"}


# --- recipes --------------------------------------------------------------------------------------


def test_recipe_errors_name_the_file_and_field(tmp_path):
    path = tmp_path / "r.toml"
    path.write_text('[model]\ndd_bins = "ten"\n[[stages]]\nname = "f"\nactions = ["move_forward"]\nepochs = 1\n')
    with pytest.raises(ConfigError, match=r"r.toml: model.dd_bins: expected an integer, got 'ten'"):
        load_train_config(str(path))
    path.write_text('[[stages]]\nname = "f"\nactions = ["jump"]\nepochs = 1\n')
    with pytest.raises(ConfigError, match="actions must be some of"):
        load_train_config(str(path))
    path.write_text('[model]\nwidth = 64\n[[stages]]\nname = "f"\nactions = ["move_forward"]\nepochs = 1\n')
    with pytest.raises(ConfigError, match="170 x 96 px but the model takes 64 x 96"):
        load_train_config(str(path))
    path.write_text('colour = 3\n[[stages]]\nname = "f"\nactions = ["move_forward"]\nepochs = 1\n')
    with pytest.raises(ConfigError, match="unknown field"):
        load_train_config(str(path))


def test_the_shipped_recipe_is_the_papers_row_18_with_the_nominal_warp():
    cfg = load_train_config("studies/robust_vo/shipped.toml")
    m = cfg.model
    assert (m.kind, m.visual, m.dd_bins, m.sproj, m.warp) == ("sepact", "rgbd", 10, True, "nominal")
    assert load_train_config("studies/robust_vo/ablations/no-warp.toml").model == dataclasses.replace(m, warp="none")
    assert [s.name for s in cfg.stages] == [
        "forward",
        "turns",
        "joint",
        "forward-decay",
        "forward-long",
        "forward-final",
    ]
    assert cfg.stages[1].data_aug and cfg.stages[2].geoinv and not cfg.stages[0].data_aug
    forward = [s for s in cfg.stages if s.actions == ("move_forward",)]
    assert [s.lr for s in forward] == sorted((s.lr for s in forward), reverse=True)  # step decays
    assert forward[-1].blocked_repeat > 1 and all(s.blocked_repeat == 1 for s in forward[:-1])
    assert all(not s.mirror for s in cfg.stages)


def test_train_cli_errors_are_one_line(tmp_path, capsys):
    from odolab.cli.train import command

    bad = tmp_path / "bad.toml"
    bad.write_text("[model\n")
    code = command("robust-vo", ["--config", str(bad), "--work", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2 and "bad.toml: not valid TOML" in err and "Traceback" not in err


def test_resized_intrinsics_map_pixel_edges_to_pixel_edges():
    K = Intrinsics.from_hfov(341, 192, 70.0)
    k = K.resized(170, 96)
    p = np.array([0.4, -0.2, 3.0])
    u, v = K.fx * p[0] / p[2] + K.cx, K.fy * p[1] / p[2] + K.cy
    u2, v2 = k.fx * p[0] / p[2] + k.cx, k.fy * p[1] / p[2] + k.cy
    assert np.isclose(u2, (u + 0.5) * 170 / 341 - 0.5) and np.isclose(v2, (v + 0.5) * 96 / 192 - 0.5)
    assert np.isclose(k.cx, (170 - 1) / 2) and np.isclose(k.cy, (96 - 1) / 2)


def test_a_variant_states_only_what_it_changes(tmp_path):
    (tmp_path / "base.toml").write_text(
        "seed = 4\n[model]\ndd_bins = 5\nsproj = false\n"
        '[[stages]]\nname = "f"\nactions = ["move_forward"]\nepochs = 1\n'
    )
    (tmp_path / "v.toml").write_text('base = "base.toml"\n[model]\ndd_bins = 20\n')
    cfg = load_train_config(str(tmp_path / "v.toml"))
    assert (cfg.seed, cfg.model.dd_bins, cfg.model.sproj, len(cfg.stages)) == (4, 20, False, 1)
    (tmp_path / "loop.toml").write_text('base = "loop2.toml"\n')
    (tmp_path / "loop2.toml").write_text('base = "loop.toml"\n')
    with pytest.raises(ConfigError, match="leads back to itself"):
        load_train_config(str(tmp_path / "loop.toml"))
    (tmp_path / "bad.toml").write_text('base = "missing.toml"\n')
    with pytest.raises(ConfigError, match="bad.toml: its base 'missing.toml' is not a file"):
        load_train_config(str(tmp_path / "bad.toml"))


def test_every_ablation_recipe_changes_one_switch_of_the_shipped_one():
    import glob

    shipped = load_train_config("studies/robust_vo/shipped.toml")
    paths = sorted(glob.glob("studies/robust_vo/ablations/*.toml"))
    assert len(paths) >= 8
    for path in paths:
        cfg = load_train_config(path)
        changed = [k for k in ("model", "stages", "train_data", "val_data") if getattr(cfg, k) != getattr(shipped, k)]
        assert changed, path


def test_hostile_recipe_values_are_refused_with_their_field(tmp_path):
    head = '[[stages]]\nactions = ["move_forward"]\nepochs = 1\n'
    for body, match in (
        ('name = "../evil"\n', "stage name must be letters"),
        ('name = "f"\nlr = inf\n', r"lr must be in \[1e-12, 1\], got inf"),
        ('name = "f"\nbatch = 0\n', r"batch must be in \[1, 65536\], got 0"),
    ):
        path = tmp_path / "r.toml"
        path.write_text(head + body)
        with pytest.raises(ConfigError, match=match):
            load_train_config(str(path))
    for model, match in (
        ("groups = 0", "groups must be in"),
        ("compress_channels = 0", "compress_channels must be in"),
        ("hidden = 0", "hidden must be in"),
    ):
        path = tmp_path / "m.toml"
        path.write_text(f"[model]\n{model}\n" + head + 'name = "f"\n')
        with pytest.raises(ConfigError, match=match):
            load_train_config(str(path))


def test_a_non_finite_loss_stops_training_with_a_message():
    from odolab.learned.training import require_finite

    require_finite(torch.tensor(1.0), 1)
    with pytest.raises(ValueError, match="loss became nan in epoch 3"):
        require_finite(torch.tensor(float("nan")), 3)


@pytest.mark.slow
def test_bf16_precision_answers_near_fp32_and_other_precisions_are_refused(trained, recipe):
    pairs, ep = _pairs(recipe)
    answers = {}
    for precision in ("fp32", "bf16"):
        odo = RobustVOOdometer(checkpoint=str(trained / "model.pt"), precision=precision)
        odo.reset(ep.intrinsics)
        answers[precision] = np.stack([odo.step(*p).transform for p in pairs[:4]])
        assert odo.network_steps_per_s(calls=2) > 0
    assert not np.array_equal(answers["bf16"], answers["fp32"])
    assert np.abs(answers["bf16"] - answers["fp32"]).max() < 0.02  # bf16 keeps 2-3 digits
    with pytest.raises(ValueError, match="precision"):
        RobustVOOdometer(checkpoint=str(trained / "model.pt"), precision="fp16")


@pytest.mark.slow
def test_mc_dropout_draws_are_the_same_for_the_same_seed(trained, recipe):
    pairs, ep = _pairs(recipe)
    runs = []
    for seed in (0, 0, 1):
        odo = RobustVOOdometer(checkpoint=str(trained / "model.pt"), mc_samples=4, seed=seed)
        odo.reset(ep.intrinsics)
        runs.append(np.stack([odo.step(*p).covariance for p in pairs[:3]]))
    assert np.array_equal(runs[0], runs[1]) and not np.array_equal(runs[0], runs[2])


@pytest.mark.slow
def test_a_resumed_state_names_what_changed(trained, recipe):
    from odolab.learned.training.epochs import differences

    assert differences({"m": {"a": 1, "b": [1, 2]}}, {"m": {"a": 2, "b": [1, 2]}}) == ["m.a (saved 1, now 2)"]
    assert differences({"s": {"blocked_repeat": 4}}, {"s": {}}) == ["s.blocked_repeat (saved 4, now unset)"]
    changed = dataclasses.replace(recipe, model=dataclasses.replace(recipe.model, dd_bins=5))
    with pytest.raises(ValueError, match=r"model.dd_bins \(saved 10, now 5\)"):
        trainer.run(
            changed,
            work=trained / "work",
            reports=trained / "r3",
            export=trained / "y.pt",
            device=torch.device("cpu"),
            hours=None,
            execution=SERIAL,
        )


def test_the_identity_holds_every_recipe_key_and_a_changed_one_is_another_run(recipe):
    k = next(i for i, s in enumerate(recipe.stages) if "move_forward" in s.actions)
    stage = recipe.stages[k]
    identity = trainer._identity(recipe, recipe.stages[-1])
    assert identity["stage"]["blocked_repeat"] == recipe.stages[-1].blocked_repeat
    assert all("blocked_repeat" in s for s in identity["before"])
    assert identity["model"]["depth_residual"] == recipe.model.depth_residual
    more = dataclasses.replace(stage, blocked_repeat=stage.blocked_repeat + 3)
    changed = dataclasses.replace(recipe, stages=(*recipe.stages[:k], more, *recipe.stages[k + 1 :]))
    assert trainer._identity(changed, more)["stage"]["blocked_repeat"] == stage.blocked_repeat + 3
    assert trainer._identity(changed, more) != trainer._identity(recipe, stage)


def test_text_or_corrupt_checkpoints_are_refused_without_unsafe_advice(tmp_path):
    text = tmp_path / "t.pt"
    text.write_text("hello world")
    with pytest.raises(CheckpointError, match="corrupt or not a torch file") as info:
        load_model(text)
    assert "weights_only=False" not in str(info.value)
    with pytest.raises(CheckpointError, match="is a folder"):
        load_model(tmp_path)


def test_real_data_without_actions_is_refused_for_an_action_model_and_bad_seeds_named():
    from odolab.api import ComparisonConfig, ComparisonError, run_comparison

    with pytest.raises(ComparisonError, match="robust-vo needs the action of every step"):
        run_comparison(
            ComparisonConfig(odometers=["robust-vo"], tum=__import__("pathlib").Path("tests/data/tum_fr1_xyz_10"))
        )
    with pytest.raises(ValueError, match=r"seed must be in \[0, 4294967295\], got -1"):
        RobustVOOdometer(seed=-1)


def _train_in(cfg, folder) -> bool:
    """Every stage of ``cfg``, serially, with work, reports and export under ``folder`` (w, r, m.pt)."""
    return trainer.run(
        cfg,
        work=folder / "w",
        reports=folder / "r",
        export=folder / "m.pt",
        device=torch.device("cpu"),
        hours=None,
        execution=SERIAL,
    )


@pytest.mark.slow
def test_a_mirror_turns_recipe_trains_one_turn_network_and_runs(recipe, tmp_path):
    tied = dataclasses.replace(recipe, model=dataclasses.replace(recipe.model, mirror_turns=True))
    assert _train_in(tied, tmp_path)
    cfg, nets, _ = load_model(tmp_path / "m.pt")
    assert cfg.mirror_turns and set(nets) == {"move_forward", "turn_left"}
    odo = RobustVOOdometer(checkpoint=str(tmp_path / "m.pt"))
    pairs, ep = _pairs(recipe)
    odo.reset(ep.intrinsics)
    assert all(np.isfinite(odo.step(*p).transform).all() for p in pairs)
    rows = (tmp_path / "r" / "curves.csv").read_text()
    assert "turn_right" in rows  # right turns are still validated, through the mirrored network


@pytest.mark.slow
def test_a_run_from_an_init_records_the_start_and_its_training(recipe, trained, tmp_path):
    """training.json names the model a run started from and that model's own stages, which the
    scaling study adds to the run's samples seen and hours."""
    started = dataclasses.replace(recipe, init=str(trained / "model.pt"))
    assert _train_in(started, tmp_path)
    status = json.loads((tmp_path / "r" / "training.json").read_text())
    before = json.loads((trained / "reports" / "training.json").read_text())["stages"]
    assert status["init"]["path"] == started.init and len(status["init"]["sha256"]) == 64
    assert status["init"]["stages"] == before and before["forward"]["pairs_seen"] > 0


@pytest.mark.slow
def test_a_start_from_another_input_size_keeps_the_convolutions_and_a_fresh_head(recipe, trained, tmp_path):
    from odolab.learned.robust_vo.checkpoint import apply_start, load_model, load_start, resized_start
    from odolab.learned.robust_vo.model import build_networks

    _, small, _ = load_model(trained / "model.pt")
    size = {"width": 64, "height": 40}
    bigger = dataclasses.replace(
        recipe,
        model=dataclasses.replace(recipe.model, **size),
        train_data=dataclasses.replace(recipe.train_data, **size),
        val_data=dataclasses.replace(recipe.val_data, **size),
        init=str(trained / "model.pt"),
    )
    start, _ = load_start(bigger.init, bigger, tmp_path / "export.pt")
    assert resized_start(start)
    nets = build_networks(bigger.model)
    apply_start(nets, start)
    for name, net in nets.items():
        old = small[name].state_dict()
        for key, value in net.state_dict().items():
            if key.startswith("head."):
                assert key == "head.1.weight" or value.shape == old[key].shape
            else:
                assert torch.equal(value, old[key]), key
        assert not net.head[-1].weight.any()  # a fresh head: the last layer at zero, as a new network's
    same, _ = load_start(str(trained / "model.pt"), dataclasses.replace(recipe, init="x"), tmp_path / "e.pt")
    assert not resized_start(same)


def test_the_input_normaliser_keeps_the_running_moments_of_every_batch():
    """RunningNorm's batch moments (float32 sums combined in float64) against float64 moments of
    all the batches together, for channels far from zero mean and one constant channel."""
    from odolab.learned.robust_vo.model import RunningNorm, batch_moments

    gen = torch.Generator().manual_seed(0)
    batches = [torch.rand(4, 3, 24, 40, generator=gen) * torch.tensor([1.0, 0.1, 0.0])[:, None, None] for _ in range(3)]
    batches = [b + torch.tensor([0.0, 50.0, 7.0])[:, None, None] for b in batches]
    norm = RunningNorm(3).train()
    for b in batches:
        norm(b)
    every = torch.cat(batches).double()
    want_mean, want_var = every.mean(dim=(0, 2, 3)), every.var(dim=(0, 2, 3), unbiased=False)
    assert torch.allclose(norm.mean.double(), want_mean, rtol=1e-6)
    assert torch.allclose(norm.var.double(), want_var, rtol=1e-5, atol=1e-9)
    mean, var = batch_moments(batches[0])
    assert var[2] == 0.0 and var[1] > 0 and abs(mean[1].item() - 50.05) < 0.01
