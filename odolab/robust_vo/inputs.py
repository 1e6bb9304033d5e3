"""psi(I): the network input of a frame pair, computed on torch batches (facts.md section 3).

Per frame, in this channel order: RGB / 255 (3, if the visual input has RGB), depth / max_depth
clipped to [0, 1] (1, if it has depth), one-hot discretised depth over N equal bins of [0, 1]
(N = ``dd_bins``, holes fall in the first bin), and the soft top-down projection (1, if ``sproj``).
A pair stacks [prev, cur]; with RGB-D, 10 bins and S-proj that is 2 x 15 = 30 channels. With
``depth_residual`` (beyond the paper) one more channel follows: the current depth minus the previous
one, per pixel, over that many metres and clipped to [-1, 1] (0 where either is a hole). After the
nominal warp, the current depth is in the previous camera, so this is the depth change that the
deviation from the command made, e.g. -1 cm where the robot went 1 cm further than commanded
towards a wall it faces.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F

from odolab.api import Intrinsics
from odolab.robust_vo.config import ModelConfig


def box_filter3(x: torch.Tensor) -> torch.Tensor:
    """3x3 mean of (B, C, H, W) with replicated borders (torch's pooling: 6x faster here than
    kornia's ``box_blur``, which convolves)."""
    return F.avg_pool2d(F.pad(x, (1, 1, 1, 1), mode="replicate"), 3, stride=1)


def one_hot_bins(d: torch.Tensor, bins: int) -> torch.Tensor:
    """(B, bins, H, W) float one-hot of (B, H, W) values in [0, 1] over ``bins`` equal bins, the last
    one closed (1.0 falls in it)."""
    index = torch.clamp((d * bins).long(), 0, bins - 1)
    return torch.zeros((d.shape[0], bins, *d.shape[1:]), dtype=torch.float32, device=d.device).scatter_(1, index[:, None], 1.0)


def top_down_projection(depth: torch.Tensor, intrinsics: Intrinsics, max_depth: float, rows: float = 100 / 192,
                        min_depth: float = 0.1) -> torch.Tensor:
    """Soft top-down projection (B, H, W) in [0, 1] of depth images (B, H, W) in metres.

    Valid depth is smoothed by a 3x3 box filter over valid readings only, the central
    ``rows`` share of image rows is unprojected with ``intrinsics`` (camera x right, z forward), and
    the points are counted in an H x W grid spanning x in [-x_max, x_max] (x_max: the image edge at
    ``max_depth``) left to right and z in [min_depth, max_depth] bottom (near) to top (far). Counts
    are divided by each image's largest count.
    """
    b, h, w = depth.shape
    valid = (depth > 0).to(depth.dtype)
    smooth, share = box_filter3(torch.stack([depth * valid, valid], dim=1)).unbind(1)
    z = torch.where(valid > 0, smooth / share.clamp_min(1e-6), torch.zeros_like(depth))
    keep = max(1, int(round(rows * h)))
    top = (h - keep) // 2
    z = z[:, top:top + keep]
    u = torch.arange(w, dtype=depth.dtype, device=depth.device)
    x = (u - intrinsics.cx) / intrinsics.fx * z
    x_max = max_depth * (intrinsics.cx + 0.5) / intrinsics.fx
    col = torch.floor((x + x_max) / (2 * x_max) * w).long()
    row = (h - 1) - torch.floor((z - min_depth) / (max_depth - min_depth) * h).long()
    ok = (z >= min_depth) & (z <= max_depth) & (col >= 0) & (col < w) & (row >= 0) & (row < h)
    image = torch.arange(b, device=depth.device)[:, None, None].expand_as(z)
    flat = (image * h * w + row * w + col)[ok]
    counts = torch.bincount(flat, minlength=b * h * w).reshape(b, h, w).to(depth.dtype)
    return counts / counts.flatten(1).amax(dim=1).clamp_min(1.0)[:, None, None]


def frame_channels(rgb: torch.Tensor, depth: torch.Tensor, intrinsics: Intrinsics, cfg: ModelConfig) -> torch.Tensor:
    """psi of single frames: ``rgb`` (B, H, W, 3) uint8 and ``depth`` (B, H, W) metres -> (B, C, H, W)."""
    parts = []
    if cfg.visual in ("rgb", "rgbd"):
        parts.append(rgb.permute(0, 3, 1, 2).to(torch.float32) / 255.0)
    d = (depth.to(torch.float32) / cfg.max_depth).clamp(0.0, 1.0)
    if cfg.visual in ("depth", "rgbd"):
        parts.append(d[:, None])
    if cfg.dd_bins:
        parts.append(one_hot_bins(d, cfg.dd_bins))
    if cfg.sproj:
        parts.append(top_down_projection(depth.to(torch.float32), intrinsics, cfg.max_depth, cfg.sproj_rows)[:, None])
    return torch.cat(parts, dim=1)


def residual_channel(prev_depth: torch.Tensor, cur_depth: torch.Tensor, scale: float) -> torch.Tensor:
    """(B, 1, H, W) depth change ``(cur - prev) / scale`` clipped to [-1, 1], 0 where either depth
    (B, H, W, metres) is a hole (0)."""
    prev, cur = prev_depth.to(torch.float32), cur_depth.to(torch.float32)
    r = ((cur - prev) / scale).clamp(-1.0, 1.0)
    return torch.where((prev > 0) & (cur > 0), r, torch.zeros_like(r))[:, None]


def pair_channels(rgb: torch.Tensor, depth: torch.Tensor, intrinsics: Intrinsics, cfg: ModelConfig) -> torch.Tensor:
    """psi of pairs: ``rgb`` (B, 2, H, W, 3) uint8, ``depth`` (B, 2, H, W) m -> (B, 2C [+ 1], H, W),
    [prev, cur] and, with ``depth_residual``, the residual channel."""
    b = rgb.shape[0]
    x = frame_channels(rgb.flatten(0, 1), depth.flatten(0, 1), intrinsics, cfg)
    x = x.reshape(b, 2 * x.shape[1], *x.shape[2:])
    if cfg.depth_residual:
        x = torch.cat([x, residual_channel(depth[:, 0], depth[:, 1], cfg.depth_residual)], dim=1)
    return x
