"""kornia in the robust VO's warp (odolab.learned.robust_vo.warp): its back-projection gives the same bits as
the plain-torch formulas d * ((u - cx) / fx, (v - cy) / fy, 1), on random frames with depth holes,
every action and an off-centre principal point, and the odometer's answers on a tiny episode do not
change by a bit."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from odolab.api import Action, Intrinsics, load_odometer
from odolab.learned.robust_vo import odometer as robust_odometer
from odolab.learned.robust_vo.checkpoint import save_model
from odolab.learned.robust_vo.config import ModelConfig, StageConfig, TrainConfig
from odolab.learned.robust_vo.model import build_networks
from odolab.learned.robust_vo.warp import FALLBACK_DEPTH, nominal_transforms, warp_current
from odolab.learned.training import DataConfig
from odolab.sim.camera import CameraSpec
from odolab.sim.episodes import EpisodeSpec, NoiseConfig, render_episode

W, H = 48, 32


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

    with_kornia = answers()
    monkeypatch.setattr(robust_odometer, "warp_current", plain_warp)
    plain = answers()
    assert len(plain) >= 3 and not np.array_equal(plain[0], plain[1])  # the answers read the frames
    assert all(np.array_equal(a, b) for a, b in zip(with_kornia, plain))
