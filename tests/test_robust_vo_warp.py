"""The nominal-motion warp of the robust VO's input (odolab.learned.robust_vo.warp): geometry against the
simulator, its place in training batches, the same input at inference, and the same bits as the
plain-torch formulas."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from odolab.api import Action, Intrinsics, invert, load_odometer, nominal_motion
from odolab.core.parallel import SERIAL
from odolab.learned.robust_vo import odometer as robust_odometer
from odolab.learned.robust_vo.batches import Samples, make_batch
from odolab.learned.robust_vo.checkpoint import save_model
from odolab.learned.robust_vo.config import ModelConfig, StageConfig, TrainConfig
from odolab.learned.robust_vo.inputs import pair_channels
from odolab.learned.robust_vo.model import build_networks
from odolab.learned.robust_vo.warp import FALLBACK_DEPTH, nominal_transforms, warp_current, warp_pairs
from odolab.learned.training import DataConfig, TrainingData, make_training_data
from odolab.sim.camera import CameraSpec
from odolab.sim.episodes import EpisodeSpec, NoiseConfig, render_episode

W, H = 48, 32
WARPED = ModelConfig(width=W, height=H, base_planes=8, groups=4, hidden=32, compress_channels=8, warp="nominal")


@pytest.fixture(scope="module")
def episode():
    spec = EpisodeSpec(
        split="test",
        index=2,
        seed=0,
        max_steps=20,
        camera=CameraSpec(width=160, height=90),
        noise=NoiseConfig(rgb=0.0, depth=0.0, actuation=0.5),
    )
    return render_episode(spec)


def _warp(ep, t, T):
    rgb, depth = torch.from_numpy(ep.rgb[t + 1][None].copy()), torch.from_numpy(ep.depth[t + 1][None].copy())
    prev = torch.from_numpy(ep.depth[t][None].copy())
    return warp_current(rgb, depth, prev, torch.from_numpy(np.asarray(T, np.float32)[None]), ep.intrinsics)


def test_warping_by_the_true_motion_gives_back_the_previous_frame(episode):
    """Noiseless depth: the current frame warped by the true T_prev_cur lands on the previous frame
    (depth within two centimetres at the median, colours close), which the unwarped frame does not."""
    ep = episode
    turns = 0

    def error(depth):  # median |depth - previous depth| (m) where both are known
        ok = (depth[0] > 0).numpy() & (ep.depth[t] > 0)
        return np.median(np.abs(depth[0].numpy()[ok] - ep.depth[t][ok])), ok

    for t in range(len(ep) - 1):
        T = invert(ep.poses[t]) @ ep.poses[t + 1]
        rgb, depth = _warp(ep, t, T)
        true, ok = error(depth)
        assert ok.mean() > 0.4 and true < 0.02
        assert np.mean(np.abs(rgb[0].numpy()[ok] - ep.rgb[t][ok].astype(np.float32))) < 15
        if Action(int(ep.actions[t])) in (Action.TURN_LEFT, Action.TURN_RIGHT):
            turns += 1
            unwarped, _ = error(_warp(ep, t, np.eye(4))[1])
            nominal, _ = error(_warp(ep, t, nominal_motion(Action(int(ep.actions[t]))))[1])
            assert unwarped > max(5 * true, 0.05) and nominal < unwarped
    assert turns >= 2


def test_a_rotation_warp_does_not_depend_on_the_previous_depth(episode):
    ep = episode
    T = torch.from_numpy(nominal_motion(Action.TURN_LEFT).astype(np.float32)[None])
    rgb, depth = torch.from_numpy(ep.rgb[1][None].copy()), torch.from_numpy(ep.depth[1][None].copy())
    a = warp_current(rgb, depth, torch.from_numpy(ep.depth[0][None].copy()), T, ep.intrinsics)
    b = warp_current(rgb, depth, torch.zeros_like(depth), T, ep.intrinsics)
    assert torch.allclose(a[0], b[0], atol=1e-2) and torch.allclose(a[1], b[1], atol=1e-4)
    assert nominal_transforms(np.array([Action.TURN_RIGHT.value])).shape == (1, 4, 4)


def test_a_bad_warp_name_is_refused():
    with pytest.raises(ValueError, match="warp"):
        ModelConfig(warp="homography")


@pytest.fixture(scope="module")
def recipe(tmp_path_factory) -> TrainConfig:
    data = DataConfig(split="val", episodes=1, max_steps=12, width=W, height=H, episodes_per_shard=1)
    cfg = TrainConfig(
        model=WARPED,
        stages=(StageConfig("all", ("move_forward",), 1),),
        train_data=data,
        val_data=data,
        data_root=str(tmp_path_factory.mktemp("warp-data")),
    )
    make_training_data(data, cfg.data_folder(data), execution=SERIAL)
    return cfg


def test_a_batch_warps_each_sample_by_the_action_it_now_stands_for(recipe):
    data = TrainingData(recipe.data_folder(recipe.train_data))
    k = int(data.select([Action.TURN_LEFT, Action.TURN_RIGHT])[0])
    swapped = make_batch(data, Samples(np.array([k]), np.array([True]), np.array([False])), WARPED, torch.device("cpu"))
    b = data.pair_batch(np.array([k]))
    rgb, depth = torch.from_numpy(b["rgb"][:, ::-1].copy()), torch.from_numpy(b["depth"][:, ::-1].copy())
    expected = pair_channels(*warp_pairs(rgb, depth, swapped.action, data.intrinsics), data.intrinsics, WARPED)
    assert swapped.action[0] != b["action"][0]
    assert torch.allclose(swapped.x, expected)
    plain = make_batch(
        data,
        Samples(np.array([k]), np.array([False]), np.array([False])),
        dataclasses.replace(WARPED, warp="none"),
        torch.device("cpu"),
    )
    c = WARPED.channels_per_frame
    unswapped = make_batch(
        data, Samples(np.array([k]), np.array([False]), np.array([False])), WARPED, torch.device("cpu")
    )
    assert torch.equal(unswapped.x[:, :c], plain.x[:, :c]) and not torch.allclose(unswapped.x[:, c:], plain.x[:, c:])


@pytest.mark.slow
@pytest.mark.parametrize("depth_residual", [0.0, 0.1])
def test_the_odometer_feeds_its_network_what_training_fed_it(recipe, tmp_path, depth_residual):
    """Frames of the data's own episode, given to the odometer at full size, become the same network
    input as the training batch of that pair (resize, warp and psi alike, the residual channel too;
    up to the data's depth rounding)."""
    torch.manual_seed(0)
    model = dataclasses.replace(WARPED, depth_residual=depth_residual)
    save_model(tmp_path / "m.pt", dataclasses.replace(recipe, model=model), build_networks(model), {})
    odo = load_odometer("odolab.learned.robust_vo.odometer:RobustVOOdometer", checkpoint=str(tmp_path / "m.pt"))
    assert odo.needs_action
    data = TrainingData(recipe.data_folder(recipe.train_data))
    ep = render_episode(recipe.train_data.specs[0])
    odo.reset(ep.intrinsics)
    for i in range(len(ep) - 1):
        x = torch.full((model.input_channels, model.height, model.width), float("nan"))
        odo._pair_channels(ep[i], ep[i + 1], ep.action(i), x)
        batch = make_batch(
            data, Samples(np.array([i]), np.array([False]), np.array([False])), model, torch.device("cpu")
        )
        assert x.shape[0] == model.input_channels == 2 * WARPED.channels_per_frame + (depth_residual > 0)
        c = 2 * WARPED.channels_per_frame
        differ = (x[:c] - batch.x[0, :c]).abs() > 1e-3  # stored depth is rounded to 1 mm: a rare bin flips
        assert differ.float().mean() < 1e-3, i
        if depth_residual:  # two depths rounded to 1 mm each: 2 mm / scale at most, but at a depth edge
            assert ((x[c:] - batch.x[0, c:]).abs() > 0.002 / depth_residual + 1e-4).float().mean() < 2e-3, i
    assert not odo.step(ep[0], ep[1], None).valid


# --- depth_residual: the warped depth change as a channel of its own ---------------------------


def test_the_residual_channel_is_the_depth_change_scaled_clipped_and_zero_on_holes():
    from odolab.learned.robust_vo.inputs import residual_channel

    prev = torch.tensor([[[2.0, 2.0, 0.0, 3.0]]])
    cur = torch.tensor([[[1.99, 2.5, 1.0, 0.0]]])
    r = residual_channel(prev, cur, 0.1)
    assert r.shape == (1, 1, 1, 4)
    assert torch.allclose(r[0, 0, 0], torch.tensor([-0.1, 1.0, 0.0, 0.0]), atol=1e-5)


def test_the_residual_sees_a_longer_step_as_a_nearer_scene(episode):
    """A forward step 2 cm longer than the true one, undone by warping with the true motion plus
    2 cm: the residual channel's median is then +2 cm / scale (the warp expected the scene 2 cm
    nearer than it is), and about 0 with the true motion."""
    from odolab.learned.robust_vo.inputs import residual_channel

    ep = episode
    t = next(i for i in range(len(ep) - 1) if Action(int(ep.actions[i])) is Action.MOVE_FORWARD)
    T = invert(ep.poses[t]) @ ep.poses[t + 1]
    longer = T.copy()
    longer[:3, 3] += 0.02 * T[:3, 2]  # 2 cm further along the camera's forward axis
    prev = torch.from_numpy(ep.depth[t][None].copy())
    medians = []
    for motion in (T, longer):
        _, depth = _warp(ep, t, motion)
        r = residual_channel(prev, depth, 0.1)[0, 0]
        medians.append(float(r[(prev[0] > 0) & (depth[0] > 0)].median()))
    assert abs(medians[0]) < 0.03 and 0.15 < medians[1] < 0.25


def test_the_residual_needs_the_warp_and_a_sane_scale():
    with pytest.raises(ValueError, match="depth_residual needs warp"):
        ModelConfig(depth_residual=0.1)
    for bad in (-0.1, 11.0):
        with pytest.raises(ValueError, match="depth_residual must be"):
            dataclasses.replace(WARPED, depth_residual=bad)


def test_a_start_from_a_model_without_the_residual_answers_as_that_model(recipe, tmp_path):
    """``init``: the exported model's weights, with a zero stem and an identity normaliser for the
    channel it lacks, so the grown network answers exactly as the old one whatever the new channel
    holds; another model (here, other widths) is refused by name."""
    from odolab.learned.robust_vo.checkpoint import apply_start, load_start
    from odolab.learned.robust_vo.model import predict

    torch.manual_seed(0)
    old_nets = build_networks(WARPED)
    for p in old_nets.parameters():
        torch.nn.init.normal_(p, std=0.05)
    for net in old_nets.values():
        net.norm.mean.normal_()
        net.norm.var.uniform_(0.5, 2.0)
    save_model(tmp_path / "old.pt", recipe, old_nets, {})
    grown_cfg = dataclasses.replace(
        recipe, model=dataclasses.replace(WARPED, depth_residual=0.1), init=str(tmp_path / "old.pt")
    )
    start, digest = load_start(grown_cfg.init, grown_cfg, tmp_path / "new.pt")
    assert len(digest) == 64
    grown = build_networks(grown_cfg.model)
    apply_start(grown, start)
    x = torch.rand(2, WARPED.input_channels, H, W)
    extra = torch.rand(2, 1, H, W) * 2 - 1
    acts = np.array([Action.MOVE_FORWARD.value, Action.TURN_LEFT.value])
    with torch.no_grad():
        old_out = predict(old_nets.eval(), WARPED, x, acts)
        new_out = predict(grown.eval(), grown_cfg.model, torch.cat([x, extra], dim=1), acts)
    assert torch.allclose(old_out, new_out, atol=1e-5) and old_out.abs().max() > 1e-3
    other = dataclasses.replace(grown_cfg, model=dataclasses.replace(grown_cfg.model, hidden=16))
    with pytest.raises(ValueError, match="differs from this recipe's in hidden"):
        load_start(other.init, other, tmp_path / "new.pt")
    with pytest.raises(ValueError, match="would overwrite"):
        load_start(grown_cfg.init, grown_cfg, tmp_path / "old.pt")
    with pytest.raises(ValueError, match="no such model file"):
        load_start(str(tmp_path / "none.pt"), grown_cfg, tmp_path / "new.pt")
    save_model(tmp_path / "grown.pt", grown_cfg, grown, {})  # a residual of 0.1 m cannot start one of 0.5 m
    rescaled = dataclasses.replace(
        grown_cfg, model=dataclasses.replace(grown_cfg.model, depth_residual=0.5), init=str(tmp_path / "grown.pt")
    )
    with pytest.raises(ValueError, match="may only add the residual channel"):
        load_start(rescaled.init, rescaled, tmp_path / "new.pt")


# --- mirror_turns: one turn network for both turns ----------------------------------------------


def test_mirror_turns_answers_a_right_turn_with_the_mirrored_left_network():
    from odolab.learned.robust_vo.model import predict
    from odolab.learned.robust_vo.motion import mirror

    cfg = dataclasses.replace(WARPED, mirror_turns=True, dropout=0.0)
    assert cfg.model_names() == ("move_forward", "turn_left")
    assert cfg.model_for(Action.TURN_RIGHT) == "turn_left" and cfg.mirrored(Action.TURN_RIGHT)
    torch.manual_seed(0)
    nets = build_networks(cfg).eval()
    for p in nets.parameters():  # a network with non-zero outputs (the head starts at zero)
        torch.nn.init.normal_(p, std=0.05)
    x = torch.rand(3, 2 * cfg.channels_per_frame, H, W)
    acts = np.array([Action.TURN_RIGHT.value, Action.TURN_LEFT.value, Action.MOVE_FORWARD.value])
    with torch.no_grad():
        out = predict(nets, cfg, x, acts)
        left = nets["turn_left"](x.flip(-1)[:1], torch.tensor([2]))
    assert torch.allclose(out[0], mirror(left)[0], atol=1e-6)
    with torch.no_grad():
        assert torch.allclose(out[1], nets["turn_left"](x[1:2], torch.tensor([1]))[0], atol=1e-6)
    with pytest.raises(ValueError, match="mirror_turns needs kind"):
        ModelConfig(kind="unified", mirror_turns=True)


def test_mirror_turns_leaves_the_forward_stage_resumable():
    from odolab.learned.robust_vo.train import _identity

    stages = (StageConfig("forward", ("move_forward",), 1), StageConfig("turns", ("turn_left", "turn_right"), 1))
    data = DataConfig(split="train", episodes=1, width=W, height=H)
    a = TrainConfig(model=WARPED, stages=stages, train_data=data, val_data=dataclasses.replace(data, split="val"))
    b = dataclasses.replace(a, model=dataclasses.replace(WARPED, mirror_turns=True))
    assert _identity(a, a.stages[0]) == _identity(b, b.stages[0])
    assert _identity(a, a.stages[1]) != _identity(b, b.stages[1])


def test_batches_made_in_the_loader_or_on_the_device_are_the_same(recipe):
    """A GPU trainer's loader reads only the frames and the device makes the inputs (warp, psi);
    a CPU trainer's loader makes them whole: the same batch either way (swapped GeoInv half too)."""
    from odolab.learned.robust_vo.batches import Pairs
    from odolab.learned.robust_vo.train import StepBatches

    data = TrainingData(recipe.data_folder(recipe.train_data))
    model = dataclasses.replace(WARPED, dd_bins=4, sproj=True)
    samples = Samples(np.arange(6), np.array([0, 1, 0, 1, 0, 0], bool), np.array([0, 0, 1, 1, 0, 0], bool))
    cpu = torch.device("cpu")
    whole = StepBatches(data, model, True, cpu)
    later = StepBatches(data, model, True, cpu, inputs_in_loader=False)
    made = later(samples)
    assert all(isinstance(m, Pairs) and m.rgb.dtype == torch.uint8 for m in made)
    for a, b in zip(whole.finish(whole(samples)), later.finish(made)):
        assert torch.equal(a.x, b.x) and torch.equal(a.target, b.target) and np.array_equal(a.action, b.action)
    assert not torch.equal(whole(samples)[0].x, whole(samples)[1].x)  # the GeoInv half is swapped


def plain_warp(
    rgb: torch.Tensor,
    depth: torch.Tensor,
    prev_depth: torch.Tensor,
    T_prev_cur: torch.Tensor,
    K: Intrinsics,
    fallback_depth: float = FALLBACK_DEPTH,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The warp in plain torch (same contract as :func:`warp_current`): rays of integer pixel
    centres times depth (m, previous camera), R^T (P - t) and the pinhole projection by hand."""
    _b, h, w = depth.shape
    v, u = torch.meshgrid(torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32), indexing="ij")
    ray = torch.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, torch.ones_like(u)], dim=-1)
    d = prev_depth.to(torch.float32)
    d = torch.where(d > 0, d, torch.full_like(d, fallback_depth))
    points = d[..., None] * ray
    R, t = T_prev_cur[:, :3, :3].to(torch.float32), T_prev_cur[:, :3, 3].to(torch.float32)
    in_cur = torch.einsum("bji,bhwj->bhwi", R, points - t[:, None, None, :])
    z = in_cur[..., 2]
    ahead = z > 1e-3
    zs = torch.where(ahead, z, torch.ones_like(z))
    uc = K.fx * in_cur[..., 0] / zs + K.cx
    vc = K.fy * in_cur[..., 1] / zs + K.cy
    inside = ahead & (uc >= -0.5) & (uc <= w - 0.5) & (vc >= -0.5) & (vc <= h - 0.5)
    grid = torch.stack([(uc + 0.5) / w * 2 - 1, (vc + 0.5) / h * 2 - 1], dim=-1)
    colour = F.grid_sample(
        rgb.to(torch.float32).permute(0, 3, 1, 2), grid, mode="bilinear", padding_mode="border", align_corners=False
    ).permute(0, 2, 3, 1)
    sampled = F.grid_sample(
        depth.to(torch.float32)[:, None], grid, mode="nearest", padding_mode="zeros", align_corners=False
    )[:, 0]
    ok = inside & (sampled > 0)
    q = sampled[..., None] * torch.stack([(uc - K.cx) / K.fx, (vc - K.cy) / K.fy, torch.ones_like(uc)], dim=-1)
    z_prev = torch.einsum("bj,bhwj->bhw", R[:, 2, :], q) + t[:, 2, None, None]
    ok = ok & (z_prev > 0)
    return torch.where(ok[..., None], colour, torch.zeros_like(colour)), torch.where(
        ok, z_prev, torch.zeros_like(z_prev)
    )


def _frames(g: torch.Generator, b: int, h: int, w: int, uint8: bool) -> tuple[torch.Tensor, ...]:
    """Random RGB (0-255) and depths (m, 0.2-10) with 15 % single-pixel holes and a hole row."""

    def depth() -> torch.Tensor:
        d = 0.2 + 9.8 * torch.rand(b, h, w, generator=g)
        d[torch.rand(b, h, w, generator=g) < 0.15] = 0.0
        d[:, h // 3] = 0.0
        return d

    rgb = torch.randint(0, 256, (b, h, w, 3), generator=g, dtype=torch.uint8)
    return (rgb if uint8 else rgb.to(torch.float32) + torch.rand(b, h, w, 3, generator=g)), depth(), depth()


@pytest.mark.parametrize(
    "intrinsics",
    [Intrinsics.from_hfov(64, 36, 79.0), Intrinsics(fx=41.3, fy=37.9, cx=30.2, cy=19.7, width=61, height=37)],
    ids=["centred", "off-centre"],
)
@pytest.mark.parametrize("uint8", [True, False], ids=["uint8", "float"])
def test_the_warp_gives_the_bits_of_the_plain_formulas(intrinsics: Intrinsics, uint8: bool) -> None:
    """Every action's nominal motion and that motion perturbed (a generic rotation and translation),
    holes in both depths: RGB and depth equal to the bit (tolerance 0)."""
    g = torch.Generator().manual_seed(7)
    actions = np.array([a.value for a in Action] * 2)
    T = nominal_transforms(actions)
    turn = torch.linalg.matrix_exp(torch.tensor([[0.0, -0.05, 0.02], [0.05, 0.0, -0.03], [-0.02, 0.03, 0.0]]))
    T[len(Action) :, :3, :3] = turn @ T[len(Action) :, :3, :3]
    T[len(Action) :, :3, 3] += torch.tensor([0.04, -0.02, 0.07])
    rgb, depth, prev = _frames(g, len(actions), intrinsics.height, intrinsics.width, uint8)
    got, want = warp_current(rgb, depth, prev, T, intrinsics), plain_warp(rgb, depth, prev, T, intrinsics)
    assert torch.equal(got[0], want[0]) and torch.equal(got[1], want[1])
    assert 0.2 < (got[1] > 0).float().mean() < 0.95  # both kept pixels and holes are compared


@pytest.mark.slow
def test_the_odometer_answers_the_same_bits_with_the_plain_warp(tmp_path, monkeypatch) -> None:
    """A warped robust-VO model (random weights) on a tiny episode: the same transforms, to the bit,
    whether its warp is :func:`warp_current` or the plain formulas."""
    torch.manual_seed(0)
    model = ModelConfig(width=W, height=H, base_planes=8, groups=4, hidden=32, compress_channels=8, warp="nominal")
    data = DataConfig(split="val", episodes=1, max_steps=6, width=W, height=H, episodes_per_shard=1)
    recipe = TrainConfig(
        model=model, stages=(StageConfig("all", ("move_forward",), 1),), train_data=data, val_data=data
    )
    nets = build_networks(model)
    for net in nets.values():  # the last layer starts at zero: make the answer depend on the input
        torch.nn.init.normal_(net.head[-1].weight, std=0.1)
    save_model(tmp_path / "m.pt", recipe, nets, {})
    spec = EpisodeSpec(
        split="test", index=2, seed=0, max_steps=6, camera=CameraSpec(width=96, height=54), noise=NoiseConfig()
    )
    ep = render_episode(spec)

    def answers() -> list[np.ndarray]:
        odo = load_odometer("odolab.learned.robust_vo.odometer:RobustVOOdometer", checkpoint=str(tmp_path / "m.pt"))
        odo.reset(ep.intrinsics)
        return [odo.step(ep[i], ep[i + 1], ep.action(i)).transform for i in range(len(ep) - 1)]

    fast = answers()
    monkeypatch.setattr(robust_odometer, "warp_current", plain_warp)
    plain = answers()
    assert len(plain) >= 3 and not np.array_equal(plain[0], plain[1])  # the answers read the frames
    assert all(np.array_equal(a, b) for a, b in zip(fast, plain))
